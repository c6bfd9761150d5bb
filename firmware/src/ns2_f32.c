/*
 * ns2_f32.c - float32 inference of the heterogeneous deep set.
 *
 * Bit-reproducible by construction: every dot product starts from the bias and
 * accumulates inputs in index order, the latent sum runs environment first and
 * then neighbours in array order, and the library is built with
 * -ffp-contract=off (no fused multiply-add) and without -ffast-math.  The Python
 * reference (ns2codegen.reference) performs the same float32 operations in the
 * same order, so both agree bit for bit.
 *
 * Speed (Cortex-M4F): four output rows are computed together so that each input
 * is loaded once per block; the generated weights are laid out [block][input][4]
 * so the weights of two inputs are eight adjacent floats (one VLDM in the
 * inline-assembly kernel; portable C elsewhere, same operations, same order).  Rows are padded to
 * a multiple of four with zero weights; the padded outputs are never read.
 */
#include <math.h>
#include <stddef.h>

#include "ns2_internal.h"
#include "ns2_model_float.h"

#define NS2_F32_BUF NS2_PAD4(NS2_MAX_WIDTH)

/* Accumulate n inputs into four rows: acc[r] += w[r] * x_i, i ascending (C). */
static void rows4_c(uint16_t n, const float *x, const float **wp, float acc[4])
{
    const float *w = *wp;
    for (uint16_t i = 0; i < n; ++i) {
        const float xi = x[i];
        acc[0] += w[0] * xi;
        acc[1] += w[1] * xi;
        acc[2] += w[2] * xi;
        acc[3] += w[3] * xi;
        w += 4;
    }
    *wp = w;
}

#if defined(__ARM_FP) && (__ARM_FP & 4) && defined(__thumb2__) && !defined(NS2_NO_ASM)
/* Cortex-M4F: two inputs per iteration, one VLDM for two inputs and one for their
 * eight weights, then VMUL and VADD (two roundings each, as in C with
 * -ffp-contract=off), per row in ascending input order; odd tail in C. */
static void rows4(uint16_t n, const float *x, const float **wp, float acc[4])
{
    uint32_t pairs = n / 2u;
    const float *w = *wp;
    if (pairs) {
        __asm__ volatile("vldmia %[acc], {s0-s3}\n\t"
                         "1:\n\t"
                         "vldmia %[x]!, {s4-s5}\n\t"
                         "vldmia %[w]!, {s8-s15}\n\t"
                         "vmul.f32 s8, s8, s4\n\t"
                         "vmul.f32 s9, s9, s4\n\t"
                         "vmul.f32 s10, s10, s4\n\t"
                         "vmul.f32 s11, s11, s4\n\t"
                         "vadd.f32 s0, s0, s8\n\t"
                         "vadd.f32 s1, s1, s9\n\t"
                         "vadd.f32 s2, s2, s10\n\t"
                         "vadd.f32 s3, s3, s11\n\t"
                         "vmul.f32 s12, s12, s5\n\t"
                         "vmul.f32 s13, s13, s5\n\t"
                         "vmul.f32 s14, s14, s5\n\t"
                         "vmul.f32 s15, s15, s5\n\t"
                         "vadd.f32 s0, s0, s12\n\t"
                         "vadd.f32 s1, s1, s13\n\t"
                         "vadd.f32 s2, s2, s14\n\t"
                         "vadd.f32 s3, s3, s15\n\t"
                         "subs %[n], %[n], #1\n\t"
                         "bne 1b\n\t"
                         "vstmia %[acc], {s0-s3}"
                         : [x] "+r"(x), [w] "+r"(w), [n] "+r"(pairs)
                         : [acc] "r"(acc)
                         : "s0", "s1", "s2", "s3", "s4", "s5", "s8", "s9", "s10", "s11", "s12", "s13",
                           "s14", "s15", "cc", "memory");
    }
    *wp = w;
    rows4_c((uint16_t)(n & 1u), x, wp, acc);
}
#else
#define rows4 rows4_c
#endif

/* y = W x + b, optional ReLU (NaN -> 0).  Per row: acc = b; acc += w_i * x_i, i ascending. */
static void dense_f32(const ns2_f32_layer_t *layer, const float *x, float *y, int relu)
{
    const float *w = layer->w;
    for (uint16_t o = 0; o < layer->n_out; o = (uint16_t)(o + 4u)) {
        float acc[4] = {layer->b[o], layer->b[o + 1u], layer->b[o + 2u], layer->b[o + 3u]};
        rows4(layer->n_in, x, &w, acc);
        for (int r = 0; r < 4; ++r) {
            y[o + r] = (relu && !(acc[r] > 0.0f)) ? 0.0f : acc[r];
        }
    }
}

/* Evaluate an MLP; returns a pointer to its output (inside buf). */
static const float *net_f32(const ns2_f32_net_t *net, const float *x, float buf[2][NS2_F32_BUF])
{
    const float *in = x;
    for (uint8_t l = 0; l < net->n_layers; ++l) {
        float *out = buf[l & 1u];
        dense_f32(&net->layers[l], in, out, l + 1u < net->n_layers);
        in = out;
    }
    return in;
}

float ns2_predict_f32(uint8_t robot_type, const float p[3], const float v[3],
                      const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    ns2_info_t local;
    ns2_info_t *inf = info != NULL ? info : &local;
    float x[6];
    float buf[2][NS2_F32_BUF];
    float h[NS2_HIDDEN];
    uint16_t idx[NS2_MAX_NEIGHBORS];
    uint16_t n_used;

    if (ns2_prepare(robot_type, p, v, neighbors, n_neighbors, x, idx, &n_used, inf) != NS2_OK) {
        return 0.0f;
    }
    const float *phi = net_f32(&ns2_f32_phi[NS2_ENV_TYPE], x, buf);
    for (int k = 0; k < NS2_HIDDEN; ++k) {
        h[k] = phi[k];
    }
    for (uint16_t j = 0; j < n_used; ++j) {
        const ns2_neighbor_t *nb = &neighbors[idx[j]];
        ns2_clamp_input(nb->type, nb->rel, x);
        phi = net_f32(&ns2_f32_phi[nb->type], x, buf);
        for (int k = 0; k < NS2_HIDDEN; ++k) {
            h[k] += phi[k];
        }
    }
    return net_f32(&ns2_f32_rho[robot_type], h, buf)[0];
}
