/* ns2_lib.c - the ns2 library as one translation unit of the app (the firmware's
 * Kbuild compiles the app folder only).  Same sources as every other build.
 * NS2_APP_FIXED / NS2_APP_FLOAT (the Makefile's NS2_INFER) select the inference
 * paths compiled in: fixed point only by default (the flash budget, docs/app.md). */
#include "ns2_app_config.h"

#include "../../src/ns2_select.c"
#if NS2_APP_FLOAT
#include "../../src/ns2_f32.c"
#endif
#if NS2_APP_FIXED
#include "../../src/ns2_q15.c"
#endif
#include "../../src/ns2_peers.c"
#include "../../src/ns2_controller.c"
#include "../../src/ns2_pilot.c"
#include "../../src/ns2_label.c"
#include "../../src/ns2_adapt.c"
