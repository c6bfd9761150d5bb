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

#if defined(__ARM_FP) && (__ARM_FP & 4) && defined(__thumb2__) && !defined(NS2_NO_ASM)
/* Cortex-M4F layer kernel: per block one VLDM of the biases; per four inputs
 * one VLDM of the inputs and one of their sixteen weights, then per input VMUL
 * and VADD (two roundings each, exactly C's a += w * x under -ffp-contract=off),
 * per row in ascending input order (2 + 32 instructions per 16 MACs plus the loop
 * branch); the last two and the last single input alone.  s16-s23 are
 * callee-saved (AAPCS): the compiler saves them around the kernel.  ReLU on the bit patterns,
 * BIC r, r, r, ASR #31, which maps every negative value and -0 to +0 and keeps
 * positive values: the same as the C ReLU for all non-NaN values, and the
 * exporter proves that no activation can overflow to Inf or NaN. */
/* acc s0..s3 += W (in registers W0..W3, overwritten) * input X: VMUL then VADD per row */
#define NS2_F32_MAC4(X, W0, W1, W2, W3)                                                       \
    "vmul.f32 " W0 ", " W0 ", " X "\n\t"                                                     \
    "vmul.f32 " W1 ", " W1 ", " X "\n\t"                                                     \
    "vmul.f32 " W2 ", " W2 ", " X "\n\t"                                                     \
    "vmul.f32 " W3 ", " W3 ", " X "\n\t"                                                     \
    "vadd.f32 s0, s0, " W0 "\n\t"                                                            \
    "vadd.f32 s1, s1, " W1 "\n\t"                                                            \
    "vadd.f32 s2, s2, " W2 "\n\t"                                                            \
    "vadd.f32 s3, s3, " W3 "\n\t"
#define NS2_F32_KERNEL(NAME, RELU_STORE)                                                      \
    __attribute__((noinline)) static void dense_f32_##NAME(const float *x, const float *w,     \
                                                           float *y, uint32_t n_blocks,        \
                                                           uint32_t n_in)                      \
    {                                                                                         \
        const uint32_t quads = n_in / 4u, rest = n_in & 3u, back = 4u * n_in;                  \
        uint32_t cnt, t0, t1, t2, t3;                                                         \
        const float *xp = x;                                                                  \
        __asm__ volatile("1:\n\t"                                                             \
                         "vldmia %[wp]!, {s0-s3}\n\t"                                         \
                         "movs %[cnt], %[quads]\n\t"                                          \
                         "beq 3f\n\t"                                                         \
                         "2:\n\t"                                                             \
                         "vldmia %[xp]!, {s4-s7}\n\t"                                         \
                         "vldmia %[wp]!, {s8-s23}\n\t"                                        \
                         NS2_F32_MAC4("s4", "s8", "s9", "s10", "s11")                         \
                         NS2_F32_MAC4("s5", "s12", "s13", "s14", "s15")                       \
                         NS2_F32_MAC4("s6", "s16", "s17", "s18", "s19")                       \
                         NS2_F32_MAC4("s7", "s20", "s21", "s22", "s23")                       \
                         "subs %[cnt], %[cnt], #1\n\t"                                        \
                         "bne 2b\n\t"                                                         \
                         "3:\n\t"                                                             \
                         "tst %[rest], #2\n\t"                                                \
                         "beq 4f\n\t"                                                         \
                         "vldmia %[xp]!, {s4-s5}\n\t"                                         \
                         "vldmia %[wp]!, {s8-s15}\n\t"                                        \
                         NS2_F32_MAC4("s4", "s8", "s9", "s10", "s11")                         \
                         NS2_F32_MAC4("s5", "s12", "s13", "s14", "s15")                       \
                         "4:\n\t"                                                             \
                         "tst %[rest], #1\n\t"                                                \
                         "beq 5f\n\t"                                                         \
                         "vldmia %[xp]!, {s4}\n\t"                                            \
                         "vldmia %[wp]!, {s8-s11}\n\t"                                        \
                         NS2_F32_MAC4("s4", "s8", "s9", "s10", "s11")                         \
                         "5:\n\t"                                                             \
                         "sub %[xp], %[xp], %[back]\n\t"                                      \
                         RELU_STORE                                                           \
                         "subs %[n], %[n], #1\n\t"                                            \
                         "bne 1b"                                                             \
                         : [xp] "+r"(xp), [wp] "+r"(w), [y] "+r"(y), [n] "+r"(n_blocks),       \
                           [cnt] "=&r"(cnt), [t0] "=&r"(t0), [t1] "=&r"(t1), [t2] "=&r"(t2),   \
                           [t3] "=&r"(t3)                                                     \
                         : [quads] "r"(quads), [rest] "r"(rest), [back] "r"(back)             \
                         : "s0", "s1", "s2", "s3", "s4", "s5", "s6", "s7", "s8", "s9", "s10",   \
                           "s11", "s12", "s13", "s14", "s15", "s16", "s17", "s18", "s19",      \
                           "s20", "s21", "s22", "s23", "cc", "memory");                        \
        (void)t0, (void)t1, (void)t2, (void)t3;                                               \
    }
NS2_F32_KERNEL(lin, "vstmia %[y]!, {s0-s3}\n\t")
NS2_F32_KERNEL(relu, "vmov %[t0], %[t1], s0, s1\n\t"
                     "vmov %[t2], %[t3], s2, s3\n\t"
                     "bic %[t0], %[t0], %[t0], asr #31\n\t"
                     "bic %[t1], %[t1], %[t1], asr #31\n\t"
                     "bic %[t2], %[t2], %[t2], asr #31\n\t"
                     "bic %[t3], %[t3], %[t3], asr #31\n\t"
                     "strd %[t0], %[t1], [%[y]], #8\n\t"
                     "strd %[t2], %[t3], [%[y]], #8\n\t")

/* Two inputs of the same net through one layer, each loaded weight serving both.
 * Activations in pair blocks: per group of four values the four of the first
 * input, then the four of the second (x and y alike; the last group of x is read
 * whole, its unused values are multiplied by nothing).  Accumulators s0-s3 (first
 * input) and s4-s7 (second); per group one VLDM of the eight inputs and two VLDM of
 * eight weights; per input and row VMUL into s24-s31 and VADD, the same operations
 * in the same order as dense_f32 on each input alone. */
#define NS2_F32_MAC2(A, B, W0, W1, W2, W3)                                                    \
    "vmul.f32 s24, " W0 ", " A "\n\t"                                                        \
    "vmul.f32 s25, " W1 ", " A "\n\t"                                                        \
    "vmul.f32 s26, " W2 ", " A "\n\t"                                                        \
    "vmul.f32 s27, " W3 ", " A "\n\t"                                                        \
    "vmul.f32 s28, " W0 ", " B "\n\t"                                                        \
    "vmul.f32 s29, " W1 ", " B "\n\t"                                                        \
    "vmul.f32 s30, " W2 ", " B "\n\t"                                                        \
    "vmul.f32 s31, " W3 ", " B "\n\t"                                                        \
    "vadd.f32 s0, s0, s24\n\t"                                                               \
    "vadd.f32 s1, s1, s25\n\t"                                                               \
    "vadd.f32 s2, s2, s26\n\t"                                                               \
    "vadd.f32 s3, s3, s27\n\t"                                                               \
    "vadd.f32 s4, s4, s28\n\t"                                                               \
    "vadd.f32 s5, s5, s29\n\t"                                                               \
    "vadd.f32 s6, s6, s30\n\t"                                                               \
    "vadd.f32 s7, s7, s31\n\t"
#define NS2_F32_RELU_STORE4(R0, R1, R2, R3)                                                   \
    "vmov %[t0], %[t1], " R0 ", " R1 "\n\t"                                                  \
    "vmov %[t2], %[t3], " R2 ", " R3 "\n\t"                                                  \
    "bic %[t0], %[t0], %[t0], asr #31\n\t"                                                   \
    "bic %[t1], %[t1], %[t1], asr #31\n\t"                                                   \
    "bic %[t2], %[t2], %[t2], asr #31\n\t"                                                   \
    "bic %[t3], %[t3], %[t3], asr #31\n\t"                                                   \
    "strd %[t0], %[t1], [%[y]], #8\n\t"                                                      \
    "strd %[t2], %[t3], [%[y]], #8\n\t"
#define NS2_F32_PAIR_KERNEL(NAME, STORE)                                                      \
    __attribute__((noinline)) static void dense2_f32_##NAME(const float *x, const float *w,    \
                                                            float *y, uint32_t n_blocks,       \
                                                            uint32_t n_in)                     \
    {                                                                                         \
        const uint32_t groups = n_in / 4u, rest = n_in & 3u;                                   \
        const uint32_t back = 32u * ((n_in + 3u) / 4u);                                        \
        uint32_t cnt, t0, t1, t2, t3;                                                         \
        const float *xp = x;                                                                  \
        __asm__ volatile("1:\n\t"                                                             \
                         "vldmia %[wp]!, {s0-s3}\n\t"                                         \
                         "vmov.f32 s4, s0\n\t"                                                \
                         "vmov.f32 s5, s1\n\t"                                                \
                         "vmov.f32 s6, s2\n\t"                                                \
                         "vmov.f32 s7, s3\n\t"                                                \
                         "movs %[cnt], %[groups]\n\t"                                         \
                         "beq 3f\n\t"                                                         \
                         "2:\n\t"                                                             \
                         "vldmia %[xp]!, {s8-s15}\n\t"                                        \
                         "vldmia %[wp]!, {s16-s23}\n\t"                                       \
                         NS2_F32_MAC2("s8", "s12", "s16", "s17", "s18", "s19")                \
                         NS2_F32_MAC2("s9", "s13", "s20", "s21", "s22", "s23")                \
                         "vldmia %[wp]!, {s16-s23}\n\t"                                       \
                         NS2_F32_MAC2("s10", "s14", "s16", "s17", "s18", "s19")               \
                         NS2_F32_MAC2("s11", "s15", "s20", "s21", "s22", "s23")               \
                         "subs %[cnt], %[cnt], #1\n\t"                                        \
                         "bne 2b\n\t"                                                         \
                         "3:\n\t"                                                             \
                         "cmp %[rest], #0\n\t"                                                \
                         "beq 4f\n\t"                                                         \
                         "vldmia %[xp]!, {s8-s15}\n\t"                                        \
                         "vldmia %[wp]!, {s16-s19}\n\t"                                       \
                         NS2_F32_MAC2("s8", "s12", "s16", "s17", "s18", "s19")                \
                         "cmp %[rest], #2\n\t"                                                \
                         "blo 4f\n\t"                                                         \
                         "vldmia %[wp]!, {s16-s19}\n\t"                                       \
                         NS2_F32_MAC2("s9", "s13", "s16", "s17", "s18", "s19")                \
                         "cmp %[rest], #3\n\t"                                                \
                         "blo 4f\n\t"                                                         \
                         "vldmia %[wp]!, {s16-s19}\n\t"                                       \
                         NS2_F32_MAC2("s10", "s14", "s16", "s17", "s18", "s19")               \
                         "4:\n\t"                                                             \
                         "sub %[xp], %[xp], %[back]\n\t"                                      \
                         STORE                                                                \
                         "subs %[n], %[n], #1\n\t"                                            \
                         "bne 1b"                                                             \
                         : [xp] "+r"(xp), [wp] "+r"(w), [y] "+r"(y), [n] "+r"(n_blocks),       \
                           [cnt] "=&r"(cnt), [t0] "=&r"(t0), [t1] "=&r"(t1), [t2] "=&r"(t2),   \
                           [t3] "=&r"(t3)                                                     \
                         : [groups] "r"(groups), [rest] "r"(rest), [back] "r"(back)           \
                         : "s0", "s1", "s2", "s3", "s4", "s5", "s6", "s7", "s8", "s9", "s10",   \
                           "s11", "s12", "s13", "s14", "s15", "s16", "s17", "s18", "s19",      \
                           "s20", "s21", "s22", "s23", "s24", "s25", "s26", "s27", "s28",      \
                           "s29", "s30", "s31", "cc", "memory");                               \
        (void)t0, (void)t1, (void)t2, (void)t3;                                               \
    }
NS2_F32_PAIR_KERNEL(lin, "vstmia %[y]!, {s0-s7}\n\t")
NS2_F32_PAIR_KERNEL(relu, NS2_F32_RELU_STORE4("s0", "s1", "s2", "s3") NS2_F32_RELU_STORE4("s4", "s5", "s6", "s7"))
#define NS2_F32_PAIRS 1

static void dense_f32(const ns2_f32_layer_t *layer, const float *x, float *y, int relu)
{
    if (layer->n_blocks == 0u) {
        return;
    }
    if (relu) {
        dense_f32_relu(x, layer->wb, y, layer->n_blocks, layer->n_in);
    } else {
        dense_f32_lin(x, layer->wb, y, layer->n_blocks, layer->n_in);
    }
}
#else
/* One layer, portable C.  Per block of four rows: acc = bias; acc += w_i * x_i for
 * i ascending; ReLU as (acc > 0 ? acc : 0). */
static void dense_f32(const ns2_f32_layer_t *layer, const float *x, float *y, int relu)
{
    const float *w = layer->wb;
    for (uint16_t blk = 0; blk < layer->n_blocks; ++blk) {
        float a0 = w[0], a1 = w[1], a2 = w[2], a3 = w[3];
        w += 4;
        for (uint16_t i = 0; i < layer->n_in; ++i) {
            const float xi = x[i];
            a0 += w[0] * xi;
            a1 += w[1] * xi;
            a2 += w[2] * xi;
            a3 += w[3] * xi;
            w += 4;
        }
        if (relu) {
            a0 = a0 > 0.0f ? a0 : 0.0f;
            a1 = a1 > 0.0f ? a1 : 0.0f;
            a2 = a2 > 0.0f ? a2 : 0.0f;
            a3 = a3 > 0.0f ? a3 : 0.0f;
        }
        y[0] = a0;
        y[1] = a1;
        y[2] = a2;
        y[3] = a3;
        y += 4;
    }
}
#endif

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

/* h = phi_t(x) (first input) or h += phi_t(x) */
static void phi_add_f32(float h[NS2_HIDDEN], uint8_t t, const float x[NS2_INPUT_DIM], int first)
{
    float buf[2][NS2_F32_BUF];
    const float *phi = net_f32(&ns2_f32_phi[t], x, buf);
    for (int k = 0; k < NS2_HIDDEN; ++k) {
        h[k] = first ? phi[k] : h[k] + phi[k];
    }
}

/* h += phi_t(xa), then h += phi_t(xb): two inputs of the same type that are
 * consecutive in the summation order, so the float sums are the ones of two
 * phi_add_f32 calls.  On Cortex-M4F both go through each layer together (pair
 * blocks, see dense2_f32_*); elsewhere one after the other. */
static void phi2_add_f32(float h[NS2_HIDDEN], uint8_t t, const float xa[NS2_INPUT_DIM],
                         const float xb[NS2_INPUT_DIM])
{
#ifdef NS2_F32_PAIRS
    /* pair blocks: per group of four inputs the four of xa, then the four of xb
     * (the last group zero-padded) */
    float xab[2 * NS2_PAD4(NS2_INPUT_DIM)];
#define NS2_XAB(i) (xab[8 * ((i) / 4) + (i) % 4] = xa[i], xab[8 * ((i) / 4) + 4 + (i) % 4] = xb[i])
    for (int k = 0; k < NS2_INPUT_DIM; k += 6) { /* six at a time: NS2_INPUT_DIM = 6 (1 + lags) */
        NS2_XAB(k);
        NS2_XAB(k + 1);
        NS2_XAB(k + 2);
        NS2_XAB(k + 3);
        NS2_XAB(k + 4);
        NS2_XAB(k + 5);
    }
#undef NS2_XAB
#if NS2_INPUT_DIM % 4 != 0 /* the last group's two padding inputs */
    xab[2 * NS2_PAD4(NS2_INPUT_DIM) - 6] = xab[2 * NS2_PAD4(NS2_INPUT_DIM) - 5] = 0.0f;
    xab[2 * NS2_PAD4(NS2_INPUT_DIM) - 2] = xab[2 * NS2_PAD4(NS2_INPUT_DIM) - 1] = 0.0f;
#endif
    float buf[2][2 * NS2_F32_BUF];
    const ns2_f32_net_t *net = &ns2_f32_phi[t];
    const float *in = xab;
    for (uint8_t l = 0; l < net->n_layers; ++l) {
        const ns2_f32_layer_t *layer = &net->layers[l];
        float *out = buf[l & 1u];
        if (layer->n_blocks > 0u) {
            if (l + 1u < net->n_layers) {
                dense2_f32_relu(in, layer->wb, out, layer->n_blocks, layer->n_in);
            } else {
                dense2_f32_lin(in, layer->wb, out, layer->n_blocks, layer->n_in);
            }
        }
        in = out;
    }
    for (int k = 0; k < NS2_HIDDEN; ++k) {
        h[k] = h[k] + in[8 * (k / 4) + k % 4];
    }
    for (int k = 0; k < NS2_HIDDEN; ++k) {
        h[k] = h[k] + in[8 * (k / 4) + 4 + k % 4];
    }
#else
    phi_add_f32(h, t, xa, 0);
    phi_add_f32(h, t, xb, 0);
#endif
}

static float rho_f32(uint8_t robot_type, const float h[NS2_HIDDEN])
{
    float buf[2][NS2_F32_BUF];
    return net_f32(&ns2_f32_rho[robot_type], h, buf)[0];
}

float ns2_predict_f32(uint8_t robot_type, const float p[3], const float v[3],
                      const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    return ns2_predict_f32_hist(robot_type, p, v, NULL, neighbors, n_neighbors, info);
}

float ns2_predict_f32_hist(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                           const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    ns2_info_t local;
    ns2_info_t *inf = info != NULL ? info : &local;
    float x[NS2_INPUT_DIM];
    float h[NS2_HIDDEN];
    uint16_t idx[NS2_MAX_NEIGHBORS];
    uint16_t n_used;

    if (ns2_prepare(robot_type, p, v, own_past, neighbors, n_neighbors, x, idx, &n_used, inf) != NS2_OK) {
        return 0.0f;
    }
    phi_add_f32(h, NS2_ENV_TYPE, x, 1);
    /* in array order; two consecutive neighbours of the same type together */
    for (uint16_t j = 0; j < n_used;) {
        const ns2_neighbor_t *nb = &neighbors[idx[j]];
        ns2_clamp_input(nb->type, nb->rel, x);
        if (j + 1u < n_used && neighbors[idx[j + 1u]].type == nb->type) {
            float xb[NS2_INPUT_DIM];
            ns2_clamp_input(nb->type, neighbors[idx[j + 1u]].rel, xb);
            phi2_add_f32(h, nb->type, x, xb);
            j = (uint16_t)(j + 2u);
        } else {
            phi_add_f32(h, nb->type, x, 0);
            j++;
        }
    }
    return rho_f32(robot_type, h);
}

uint16_t ns2_job_step_f32(ns2_job_t *job, uint16_t max_phi)
{
    if (!ns2_job_claim(job, NS2_JOB_F32)) {
        return 0;
    }
    for (uint16_t k = 0; k < max_phi && job->next < job->n_inputs;) {
        const uint16_t i = job->next;
        if (i > 0u && k + 2u <= max_phi && i + 1u < job->n_inputs && job->type[i + 1u] == job->type[i]) {
            phi2_add_f32(job->h_f32, job->type[i], job->x[i], job->x[i + 1u]);
            job->next = (uint16_t)(i + 2u);
            k = (uint16_t)(k + 2u);
        } else {
            phi_add_f32(job->h_f32, job->type[i], job->x[i], i == 0u);
            job->next++;
            k++;
        }
    }
    return (uint16_t)(job->n_inputs - job->next);
}

float ns2_job_finish_f32(ns2_job_t *job, ns2_info_t *info)
{
    float r = 0.0f;
    const int claimed = ns2_job_claim(job, NS2_JOB_F32);
    if (claimed) {
        (void)ns2_job_step_f32(job, job->n_inputs);
        r = rho_f32(job->robot_type, job->h_f32);
    }
    ns2_job_info(job, claimed, info);
    return r;
}
