/* ns2_lib.c - the ns2 library as one translation unit of the app (the firmware's
 * Kbuild compiles the app folder only).  Same sources as every other build. */
#include "../../src/ns2_select.c"
#include "../../src/ns2_f32.c"
#include "../../src/ns2_q15.c"
#include "../../src/ns2_peers.c"
#include "../../src/ns2_controller.c"
