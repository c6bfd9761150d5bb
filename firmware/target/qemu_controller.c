/*
 * qemu_controller.c - test image: controller steps on the (emulated) STM32F405.
 * ns2_in.bin: "NS2C", u32 count, ns2_vehicle_t, ns2_gains_t, count x ns2_step_in_t;
 * ns2_out.bin: count x ns2_step_out_t (semihosting file I/O).
 */
#include "ns2_ctrl_vectors.h"
#include "qemu_io.h"

int main(void)
{
    FILE *in, *out;
    uint32_t count = 0;
    ns2_vehicle_t veh;
    ns2_gains_t gains;
    static ns2_ctrl_t ctrl;
    if (qemu_open_vectors("NS2C", &in, &out, &count) || fread(&veh, sizeof veh, 1, in) != 1 ||
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
