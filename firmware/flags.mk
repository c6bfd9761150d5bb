# Compiler flags of the ns2 firmware library: the single source for the
# Makefile, the host (cffi) build and the Cortex-M4F cross build.
# -ffp-contract=off: no fused multiply-add, so the float path is bit-exact
# across the host, the STM32 and the Python reference.  Never -ffast-math.
NS2_STD_FLAGS := -std=c99 -ffp-contract=off -fno-strict-aliasing
NS2_WARN_FLAGS := -Wall -Wextra -Werror -Wconversion -Wdouble-promotion -Wshadow -Wstrict-prototypes -pedantic
NS2_OPT_FLAGS := -O2
NS2_ARM_FLAGS := -mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard
NS2_SOURCES := firmware/src/ns2_select.c firmware/src/ns2_f32.c firmware/src/ns2_q15.c firmware/src/ns2_peers.c firmware/src/ns2_controller.c firmware/src/ns2_pilot.c firmware/src/ns2_label.c firmware/src/ns2_adapt.c
NS2_INCLUDES := firmware/include firmware/src firmware/hil
NS2_HIL_SOURCES := firmware/hil/ns2_hil.c
