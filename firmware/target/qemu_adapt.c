/*
 * qemu_adapt.c - test image: on-board label and adaptation steps on the (emulated)
 * STM32F405.  ns2_in.bin: "NS2A", u32 count, ns2_label_cfg_t, ns2_adapt_cfg_t (the
 * reset's), count x ns2_adapt_in_t; ns2_out.bin: count x ns2_adapt_out_t
 * (semihosting file I/O).
 */
#include "ns2_adapt_vectors.h"
#include "qemu_io.h"

int main(void)
{
    FILE *in, *out;
    uint32_t count = 0;
    ns2_label_cfg_t lcfg;
    ns2_adapt_cfg_t acfg;
    static ns2_label_t label;
    static ns2_adapt_t adapt;
    if (qemu_open_vectors("NS2A", &in, &out, &count) || fread(&lcfg, sizeof lcfg, 1, in) != 1 ||
        fread(&acfg, sizeof acfg, 1, in) != 1) {
        return 2;
    }
    ns2_label_init(&label, &lcfg);
    ns2_adapt_reset(&adapt, &acfg);
    for (uint32_t k = 0; k < count; ++k) {
        ns2_adapt_in_t step;
        ns2_adapt_out_t res;
        if (fread(&step, sizeof step, 1, in) != 1) {
            return 4;
        }
        ns2_adapt_run_steps(&label, &adapt, &step, &res, 1u);
        if (fwrite(&res, sizeof res, 1, out) != 1) {
            return 5;
        }
    }
    fclose(out);
    fclose(in);
    return 0;
}
