/*
 * qemu_controller.c - test image: controller steps on the (emulated) STM32F405.
 * ns2_in.bin: "NS2C", u32 count, ns2_vehicle_t, ns2_gains_t, count x ns2_step_in_t;
 * ns2_out.bin: count x ns2_step_out_t (semihosting file I/O).
 */
#include <stdio.h>
#include <string.h>

#include "ns2_ctrl_vectors.h"

int main(void)
{
    FILE *in = fopen("ns2_in.bin", "rb");
    FILE *out = fopen("ns2_out.bin", "wb");
    char magic[4];
    uint32_t count = 0;
    ns2_vehicle_t veh;
    ns2_gains_t gains;
    static ns2_ctrl_t ctrl;
    if (in == NULL || out == NULL || fread(magic, 1, 4, in) != 4 || memcmp(magic, "NS2C", 4) != 0 ||
        fread(&count, sizeof count, 1, in) != 1 || fread(&veh, sizeof veh, 1, in) != 1 ||
        fread(&gains, sizeof gains, 1, in) != 1) {
        return 2;
    }
    ns2_ctrl_init(&ctrl, &veh, &gains);
    for (uint32_t k = 0; k < count; ++k) {
        ns2_step_in_t step;
        ns2_step_out_t res;
        if (fread(&step, sizeof step, 1, in) != 1) {
            return 4;
        }
        ns2_ctrl_run_steps(&ctrl, &step, &res, 1u);
        if (fwrite(&res, sizeof res, 1, out) != 1) {
            return 5;
        }
    }
    fclose(out);
    fclose(in);
    return 0;
}
