/*
 * ns2_q15.c - fixed-point inference of the heterogeneous deep set.
 *
 * int16 weights and activations, int32 accumulators, one power-of-two scale
 * per layer (ns2codegen.quantize chooses them and proves that no accumulator,
 * partial sums included, can overflow for inputs in the box).
 *
 * A value a with fractional bits f stands for a * 2^-f.  Layer l computes
 *   acc = b + sum_i w_i x_i                 (int32, frac = f_in + f_w)
 *   y   = sat16( floor((acc + 2^(s-1)) / 2^s) ),  s = shift  (round half up)
 * then ReLU on hidden layers.  Inputs: x -> sat16(round_half_up(x * 2^f_in)).
 * The latent sum h is an int32 sum of phi outputs, brought to the rho input
 * format by the same rounding shift (NS2_Q_SUM_SHIFT) and saturation.
 * Integer sums are exact, so the result does not depend on the summation order.
 *
 * Speed: int16 pairs are packed in int32 words (low half = even index) and
 * multiplied-accumulated two at a time with SMLAD on Cortex-M4 (inline assembly,
 * fully unrolled over the input quads); other targets use a portable C SMLAD
 * with the same result (integer sums are exact).  The bias tables already
 * contain the rounding offset 2^(shift-1).  Four output
 * rows share each loaded input quad; the generated weights are laid out
 * [row block][input quad][row][2 words].  Inputs and rows are zero-padded to
 * multiples of four.  Right shifts of negative numbers are written so that they
 * are defined C.
 */
#include <stddef.h>

#include "ns2_internal.h"
#include "ns2_model_fixed.h"

/* Signed low and high halves of a packed word (sign extension without
 * implementation-defined conversions or shifts). */
static int32_t lo16(int32_t w)
{
    return ((w & 0xFFFF) ^ 0x8000) - 0x8000;
}

static int32_t hi16(int32_t w)
{
    return (int32_t)((((uint32_t)w) >> 16) ^ 0x8000u) - 0x8000;
}

/* Portable SMLAD: acc + lo(a) lo(b) + hi(a) hi(b) (no overflow: see the proof). */
static int32_t ns2_smlad_c(int32_t a, int32_t b, int32_t acc)
{
    return acc + lo16(a) * lo16(b) + hi16(a) * hi16(b);
}

#define NS2_Q_WORDS (NS2_PAD4(NS2_MAX_WIDTH) / 2) /* int16 pairs per activation buffer */
#define NS2_HIDDEN_PAD4 NS2_PAD4(NS2_HIDDEN)      /* latent sum incl. the padded rows */

/* floor(a / 2^s) for any sign, without implementation-defined shifts. */
static int32_t floor_shift(int32_t a, uint8_t s)
{
    return a >= 0 ? (int32_t)(a >> s) : (int32_t)~((~a) >> s);
}

static int32_t sat16(int32_t a)
{
    return a > INT16_MAX ? INT16_MAX : (a < INT16_MIN ? INT16_MIN : a);
}

/* Round half up by s bits, saturate to int16.  |a| + 2^(s-1) <= INT32_MAX is
 * part of the exporter's overflow proof. */
static int32_t round_shift_sat(int32_t a, uint8_t s)
{
    if (s == 0u) {
        return sat16(a);
    }
    return sat16(floor_shift(a + (int32_t)(1L << (s - 1u)), s));
}

/* Two int16 values (as int32 in range) packed into one word, y0 in the low half. */
static int32_t pack16(int32_t y0, int32_t y1)
{
    return y1 * 0x10000 + (y0 & 0xFFFF);
}

/* x -> sat16(round_half_up(x * scale)), scale = 2^f_in; x is already clamped. */
static int32_t quantize(float x, float scale)
{
    const float v = x * scale;  /* exact: scale is a power of two; |v| < 2^16 */
    int32_t q = (int32_t)v;     /* truncation toward zero */
    float fl = (float)q;        /* exact */
    if (fl > v) {               /* negative non-integer: floor = trunc - 1 */
        q -= 1;
        fl -= 1.0f;
    }
    if (v - fl >= 0.5f) {       /* v - floor(v), the same float operation as the reference */
        q += 1;
    }
    return sat16(q);
}

/* Rounding offset 2^(shift-1) is already in the bias: y = sat16(floor(acc / 2^shift)). */
static int32_t finish(int32_t acc, uint8_t shift, int relu)
{
    const int32_t r = sat16(floor_shift(acc, shift));
    return (relu && r < 0) ? 0 : r;
}

/* Output of a layer: packed int16 pairs with ReLU (hidden layers), packed int16
 * pairs (rho's last layer), or int16 outputs written to (set) or added to (acc)
 * int32 sums (phi's last layer, straight into the latent sum h). */
enum { NS2_OUT_RELU, NS2_OUT_LIN, NS2_OUT_SET, NS2_OUT_ACC };

/* One layer, portable C: per block the four biases, then n_quads input quads.
 * Not inlined into dense_q15: the Cortex-M4 dispatch stays a thin switch. */
__attribute__((noinline)) static void dense_q15_c(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int out)
{
    const int32_t *w = layer->wb;
    const int relu = out == NS2_OUT_RELU;
    for (uint16_t blk = 0; blk < layer->n_blocks; ++blk) {
        int32_t acc[4] = {w[0], w[1], w[2], w[3]};
        const int32_t *xp = x;
        w += 4;
        for (uint16_t q = 0; q < layer->n_quads; ++q) {
            const int32_t x01 = xp[0];
            const int32_t x23 = xp[1];
            xp += 2;
            for (int r = 0; r < 4; ++r) {
                acc[r] = ns2_smlad_c(w[2 * r], x01, acc[r]);
                acc[r] = ns2_smlad_c(w[2 * r + 1], x23, acc[r]);
            }
            w += 8;
        }
        if (out == NS2_OUT_SET || out == NS2_OUT_ACC) {
            for (uint16_t r = 0; r < 4u; ++r) {
                const int32_t v = finish(acc[r], layer->shift, 0);
                y[4u * blk + r] = out == NS2_OUT_SET ? v : y[4u * blk + r] + v;
            }
        } else {
            y[2u * blk] = pack16(finish(acc[0], layer->shift, relu), finish(acc[1], layer->shift, relu));
            y[2u * blk + 1u] = pack16(finish(acc[2], layer->shift, relu), finish(acc[3], layer->shift, relu));
        }
    }
}

#if defined(__ARM_FEATURE_DSP) && __ARM_FEATURE_DSP && defined(__thumb2__) && !defined(NS2_NO_ASM)
/* Cortex-M4 kernels, one per input-quad count NQ of the model and per output
 * kind (USAT #15 = ReLU + saturation for hidden layers, SSAT #16 for the last).
 * Per block: two LDRD of the biases; per quad (unrolled NQ times by the
 * assembler) one LDRD of the two input words, two LDM of four weight words and
 * eight SMLAD; then ASR (the floor shift), saturation, and the store: two
 * PKHBT and one STRD, or (set) two STRD of int32 values, or (acc) twice LDRD,
 * two ADD and STRD into the int32 sums.
 * Same arithmetic as dense_q15_c: integer sums are exact, SMLAD is
 * acc + lo*lo + hi*hi, ASR is floor division by 2^shift. */
#define NS2_Q15_KERNEL(NQ, NAME, SAT, STORE)                                                     \
    __attribute__((noinline)) static void dense_q15_##NQ##_##NAME(                              \
        const int32_t *x, const int32_t *w, int32_t *y, uint32_t n_blocks, int32_t s)           \
    {                                                                                           \
        int32_t a0, a1, a2, a3, x0, x1;                                                         \
        const int32_t *xp = x;                                                                  \
        __asm__ volatile("1:\n\t"                                                               \
                         "ldrd %[a0], %[a1], [%[wp]], #8\n\t"                                   \
                         "ldrd %[a2], %[a3], [%[wp]], #8\n\t"                                   \
                         ".rept %c[nq]\n\t"                                                     \
                         "ldrd %[x0], %[x1], [%[xp]], #8\n\t"                                   \
                         "ldmia %[wp]!, {r8, r9, r10, r11}\n\t"                                 \
                         "smlad %[a0], r8, %[x0], %[a0]\n\t"                                    \
                         "smlad %[a0], r9, %[x1], %[a0]\n\t"                                    \
                         "smlad %[a1], r10, %[x0], %[a1]\n\t"                                   \
                         "smlad %[a1], r11, %[x1], %[a1]\n\t"                                   \
                         "ldmia %[wp]!, {r8, r9, r10, r11}\n\t"                                 \
                         "smlad %[a2], r8, %[x0], %[a2]\n\t"                                    \
                         "smlad %[a2], r9, %[x1], %[a2]\n\t"                                    \
                         "smlad %[a3], r10, %[x0], %[a3]\n\t"                                   \
                         "smlad %[a3], r11, %[x1], %[a3]\n\t"                                   \
                         ".endr\n\t"                                                            \
                         "sub %[xp], %[xp], #%c[back]\n\t"                                      \
                         "ldr %[x0], %[smem]\n\t"                                               \
                         "asr %[a0], %[a0], %[x0]\n\t"                                          \
                         "asr %[a1], %[a1], %[x0]\n\t"                                          \
                         "asr %[a2], %[a2], %[x0]\n\t"                                          \
                         "asr %[a3], %[a3], %[x0]\n\t"                                          \
                         SAT " %[a0], " SAT_BITS_##NAME ", %[a0]\n\t"                           \
                         SAT " %[a1], " SAT_BITS_##NAME ", %[a1]\n\t"                           \
                         SAT " %[a2], " SAT_BITS_##NAME ", %[a2]\n\t"                           \
                         SAT " %[a3], " SAT_BITS_##NAME ", %[a3]\n\t"                           \
                         STORE                                                                  \
                         "subs %[n], %[n], #1\n\t"                                              \
                         "bne 1b"                                                               \
                         : [a0] "=&r"(a0), [a1] "=&r"(a1), [a2] "=&r"(a2), [a3] "=&r"(a3),       \
                           [x0] "=&r"(x0), [x1] "=&r"(x1), [xp] "+r"(xp), [wp] "+r"(w),          \
                           [y] "+r"(y), [n] "+r"(n_blocks)                                      \
                         : [nq] "i"(NQ), [back] "i"(8 * (NQ)), [smem] "m"(s)                    \
                         : "r8", "r9", "r10", "r11", "cc", "memory");                           \
    }
#define SAT_BITS_relu "#15"
#define SAT_BITS_lin "#16"
#define SAT_BITS_set "#16"
#define SAT_BITS_acc "#16"
#define NS2_Q15_STORE_SET                     \
    "strd %[a0], %[a1], [%[y]], #8\n\t"      \
    "strd %[a2], %[a3], [%[y]], #8\n\t"
#define NS2_Q15_STORE_PACKED                  \
    "pkhbt %[a0], %[a0], %[a1], lsl #16\n\t" \
    "pkhbt %[a2], %[a2], %[a3], lsl #16\n\t" \
    "strd %[a0], %[a2], [%[y]], #8\n\t"
#define NS2_Q15_STORE_ADD                     \
    "ldrd %[x0], %[x1], [%[y]]\n\t"          \
    "add %[x0], %[x0], %[a0]\n\t"            \
    "add %[x1], %[x1], %[a1]\n\t"            \
    "strd %[x0], %[x1], [%[y]], #8\n\t"      \
    "ldrd %[x0], %[x1], [%[y]]\n\t"          \
    "add %[x0], %[x0], %[a2]\n\t"            \
    "add %[x1], %[x1], %[a3]\n\t"            \
    "strd %[x0], %[x1], [%[y]], #8\n\t"
#define NS2_Q15_KERNELS(NQ)                                \
    NS2_Q15_KERNEL(NQ, relu, "usat", NS2_Q15_STORE_PACKED) \
    NS2_Q15_KERNEL(NQ, lin, "ssat", NS2_Q15_STORE_PACKED)  \
    NS2_Q15_KERNEL(NQ, set, "ssat", NS2_Q15_STORE_SET)     \
    NS2_Q15_KERNEL(NQ, acc, "ssat", NS2_Q15_STORE_ADD)
NS2_Q15_FOR_EACH_QUAD_COUNT(NS2_Q15_KERNELS)

#define NS2_Q15_CASE(NQ)                                                                  \
    case NQ:                                                                              \
        if (out == NS2_OUT_RELU) {                                                        \
            dense_q15_##NQ##_relu(x, layer->wb, y, layer->n_blocks, (int32_t)layer->shift); \
        } else if (out == NS2_OUT_LIN) {                                                  \
            dense_q15_##NQ##_lin(x, layer->wb, y, layer->n_blocks, (int32_t)layer->shift);  \
        } else if (out == NS2_OUT_SET) {                                                  \
            dense_q15_##NQ##_set(x, layer->wb, y, layer->n_blocks, (int32_t)layer->shift);  \
        } else {                                                                          \
            dense_q15_##NQ##_acc(x, layer->wb, y, layer->n_blocks, (int32_t)layer->shift);  \
        }                                                                                 \
        return;

static void dense_q15(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int out)
{
    if (layer->n_blocks == 0u) {
        return;
    }
    switch (layer->n_quads) {
        NS2_Q15_FOR_EACH_QUAD_COUNT(NS2_Q15_CASE)
    default:
        dense_q15_c(layer, x, y, out); /* a count the exporter did not list */
        return;
    }
}
#else
#define dense_q15 dense_q15_c
#endif

/* The hidden layers of an MLP (ReLU); returns the last hidden activation (in buf). */
static const int32_t *hidden_q15(const ns2_q15_net_t *net, const int32_t *x, int32_t buf[2][NS2_Q_WORDS])
{
    const int32_t *in = x;
    for (uint8_t l = 0; l + 1u < net->n_layers; ++l) {
        int32_t *out = buf[l & 1u];
        dense_q15(&net->layers[l], in, out, NS2_OUT_RELU);
        in = out;
    }
    return in;
}

/* Clamped 6-vector -> 4 packed words (inputs 6 and 7 are zero padding). */
static void quantize_input(const float x[6], float scale, int32_t xq[4])
{
    xq[0] = pack16(quantize(x[0], scale), quantize(x[1], scale));
    xq[1] = pack16(quantize(x[2], scale), quantize(x[3], scale));
    xq[2] = pack16(quantize(x[4], scale), quantize(x[5], scale));
    xq[3] = 0;
}

/* h = phi_t(x) (first input) or h += phi_t(x), x clamped (int32 sums: exact).
 * phi's last layer writes or adds its int16 outputs straight into h (the
 * padded rows give 0). */
static void phi_add_q15(int32_t h[NS2_HIDDEN_PAD4], uint8_t t, const float x[6], int first)
{
    int32_t xq[4];
    int32_t buf[2][NS2_Q_WORDS];
    const ns2_q15_net_t *net = &ns2_q15_phi[t];
    quantize_input(x, ns2_q15_in_scale[t], xq);
    dense_q15(&net->layers[net->n_layers - 1u], hidden_q15(net, xq, buf), h, first ? NS2_OUT_SET : NS2_OUT_ACC);
}

/* The latent sum brought to rho's input format, then rho. */
static int16_t rho_q15(uint8_t robot_type, const int32_t h[NS2_HIDDEN_PAD4])
{
    int32_t hq[NS2_HIDDEN_PAD4 / 2];
    int32_t y[2];
    int32_t buf[2][NS2_Q_WORDS];
    const ns2_q15_net_t *net = &ns2_q15_rho[robot_type];
    for (int k = 0; k < NS2_HIDDEN_PAD4 / 2; ++k) {
        const int32_t h0 = 2 * k < NS2_HIDDEN ? round_shift_sat(h[2 * k], NS2_Q_SUM_SHIFT) : 0;
        const int32_t h1 = 2 * k + 1 < NS2_HIDDEN ? round_shift_sat(h[2 * k + 1], NS2_Q_SUM_SHIFT) : 0;
        hq[k] = pack16(h0, h1);
    }
    dense_q15(&net->layers[net->n_layers - 1u], hidden_q15(net, hq, buf), y, NS2_OUT_LIN);
    return (int16_t)lo16(y[0]);
}

int16_t ns2_predict_q15(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    ns2_info_t local;
    ns2_info_t *inf = info != NULL ? info : &local;
    float x[6];
    int32_t h[NS2_HIDDEN_PAD4];
    uint16_t idx[NS2_MAX_NEIGHBORS];
    uint16_t n_used;

    if (ns2_prepare(robot_type, p, v, neighbors, n_neighbors, x, idx, &n_used, inf) != NS2_OK) {
        return 0;
    }
    phi_add_q15(h, NS2_ENV_TYPE, x, 1);
    for (uint16_t j = 0; j < n_used; ++j) {
        const ns2_neighbor_t *nb = &neighbors[idx[j]];
        ns2_clamp_input(nb->type, nb->rel, x);
        phi_add_q15(h, nb->type, x, 0);
    }
    return rho_q15(robot_type, h);
}

uint16_t ns2_job_step_q15(ns2_job_t *job, uint16_t max_phi)
{
    if (!ns2_job_claim(job, NS2_JOB_Q15)) {
        return 0;
    }
    for (uint16_t k = 0; k < max_phi && job->next < job->n_inputs; ++k) {
        phi_add_q15(job->h_q15, job->type[job->next], job->x[job->next], job->next == 0u);
        job->next++;
    }
    return (uint16_t)(job->n_inputs - job->next);
}

int16_t ns2_job_finish_q15(ns2_job_t *job, ns2_info_t *info)
{
    int16_t r = 0;
    const int claimed = ns2_job_claim(job, NS2_JOB_Q15);
    if (claimed) {
        (void)ns2_job_step_q15(job, job->n_inputs);
        r = rho_q15(job->robot_type, job->h_q15);
    }
    ns2_job_info(job, claimed, info);
    return r;
}

float ns2_predict_q15_g(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    const int16_t q = ns2_predict_q15(robot_type, p, v, neighbors, n_neighbors, info);
    return (float)q * NS2_Q_OUT_SCALE;
}
