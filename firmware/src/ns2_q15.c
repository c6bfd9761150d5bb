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
#include <math.h>
#include <stddef.h>

#include "ns2_internal.h"
#include "ns2_model_fixed.h"

/* Portable SMLAD: acc + lo(a) lo(b) + hi(a) hi(b) (no overflow: see the proof). */
static int32_t lo16(int32_t w)
{
    const int32_t u = w & 0xFFFF;
    return u >= 0x8000 ? u - 0x10000 : u;
}

static int32_t hi16(int32_t w)
{
    return (w - (w & 0xFFFF)) / 0x10000; /* exact: a multiple of 2^16 */
}

static int32_t ns2_smlad_c(int32_t a, int32_t b, int32_t acc)
{
    return acc + lo16(a) * lo16(b) + hi16(a) * hi16(b);
}

#define NS2_Q_WORDS (NS2_PAD4(NS2_MAX_WIDTH) / 2) /* int16 pairs per activation buffer */

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

static int32_t unpack_lo(int32_t w)
{
    const int32_t u = w & 0xFFFF;
    return u >= 0x8000 ? u - 0x10000 : u;
}

static int32_t unpack_hi(int32_t w)
{
    return (w - (w & 0xFFFF)) / 0x10000; /* exact: a multiple of 2^16 */
}

/* x -> sat16(round_half_up(x * scale)), scale = 2^f_in; x is already clamped. */
static int32_t quantize(float x, float scale)
{
    const float v = x * scale; /* exact: scale is a power of two */
    const float fl = floorf(v);
    int32_t q = (int32_t)fl;
    if (v - fl >= 0.5f) {
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

/* Four rows over n_quads input quads, portable C (any target, any quad count). */
static void quads_c(uint16_t n_quads, const int32_t *xp, const int32_t **wp, int32_t acc[4])
{
    const int32_t *w = *wp;
    for (uint16_t q = 0; q < n_quads; ++q) {
        const int32_t x01 = xp[0];
        const int32_t x23 = xp[1];
        xp += 2;
        for (int r = 0; r < 4; ++r) {
            acc[r] = ns2_smlad_c(w[2 * r], x01, acc[r]);
            acc[r] = ns2_smlad_c(w[2 * r + 1], x23, acc[r]);
        }
        w += 8;
    }
    *wp = w;
}

static void dense_q15_c(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int relu)
{
    const int32_t *w = layer->w;
    const int32_t *b = layer->b;
    for (uint16_t o = 0; o < layer->n_out; o = (uint16_t)(o + 4u)) {
        int32_t acc[4] = {b[o], b[o + 1u], b[o + 2u], b[o + 3u]};
        quads_c(layer->n_quads, x, &w, acc);
        y[o / 2u] = pack16(finish(acc[0], layer->shift, relu), finish(acc[1], layer->shift, relu));
        y[o / 2u + 1u] = pack16(finish(acc[2], layer->shift, relu), finish(acc[3], layer->shift, relu));
    }
}

#if defined(__ARM_FEATURE_DSP) && __ARM_FEATURE_DSP && defined(__thumb2__) && !defined(NS2_NO_ASM)
/* SSAT #16 (saturate to int16) and USAT #15 (ReLU and saturate to [0, 32767]) */
static inline int32_t ssat16(int32_t v)
{
    int32_t r;
    __asm__("ssat %0, #16, %1" : "=r"(r) : "r"(v));
    return r;
}

static inline int32_t usat15(int32_t v)
{
    int32_t r;
    __asm__("usat %0, #15, %1" : "=r"(r) : "r"(v));
    return r;
}

/* Cortex-M4 kernels, one per input-quad count NQ of the model (fully unrolled by
 * the assembler): per quad one LDRD of the two input words, four LDRD of weight
 * pairs and eight SMLAD for four rows.  The epilogue uses ASR (arithmetic: GCC's
 * documented >> of negative numbers) and SSAT #16 / USAT #15, i.e. the same floor shift,
 * saturation and ReLU as finish(). */
#define NS2_Q15_KERNEL(NQ)                                                                      \
    __attribute__((noinline)) static void dense_q15_##NQ(const ns2_q15_layer_t *layer,           \
                                                         const int32_t *x, int32_t *y,           \
                               int relu)                                                        \
    {                                                                                           \
        const int32_t *w = layer->w;                                                            \
        const int32_t *b = layer->b;                                                            \
        const int32_t s = layer->shift;                                                         \
        for (uint16_t o = 0; o < layer->n_out; o = (uint16_t)(o + 4u)) {                         \
            int32_t a0 = b[0], a1 = b[1], a2 = b[2], a3 = b[3];                                 \
            int32_t x0, x1, w0, w1;                                                             \
            const int32_t *xp = x;                                                              \
            b += 4;                                                                             \
            __asm__ volatile(".rept %c[nq]\n\t"                                                 \
                             "ldrd %[x0], %[x1], [%[xp]], #8\n\t"                               \
                             "ldrd %[w0], %[w1], [%[wp]], #8\n\t"                               \
                             "smlad %[a0], %[w0], %[x0], %[a0]\n\t"                             \
                             "smlad %[a0], %[w1], %[x1], %[a0]\n\t"                             \
                             "ldrd %[w0], %[w1], [%[wp]], #8\n\t"                               \
                             "smlad %[a1], %[w0], %[x0], %[a1]\n\t"                             \
                             "smlad %[a1], %[w1], %[x1], %[a1]\n\t"                             \
                             "ldrd %[w0], %[w1], [%[wp]], #8\n\t"                               \
                             "smlad %[a2], %[w0], %[x0], %[a2]\n\t"                             \
                             "smlad %[a2], %[w1], %[x1], %[a2]\n\t"                             \
                             "ldrd %[w0], %[w1], [%[wp]], #8\n\t"                               \
                             "smlad %[a3], %[w0], %[x0], %[a3]\n\t"                             \
                             "smlad %[a3], %[w1], %[x1], %[a3]\n\t"                             \
                             ".endr"                                                            \
                             : [a0] "+r"(a0), [a1] "+r"(a1), [a2] "+r"(a2), [a3] "+r"(a3),       \
                               [xp] "+r"(xp), [wp] "+r"(w), [x0] "=&r"(x0), [x1] "=&r"(x1),      \
                               [w0] "=&r"(w0), [w1] "=&r"(w1)                                   \
                             : [nq] "i"(NQ)                                                     \
                             : "memory");                                                       \
            if (relu) {                                                                         \
                a0 = usat15(a0 >> s);                                              \
                a1 = usat15(a1 >> s);                                              \
                a2 = usat15(a2 >> s);                                              \
                a3 = usat15(a3 >> s);                                              \
            } else {                                                                            \
                a0 = ssat16(a0 >> s);                                                       \
                a1 = ssat16(a1 >> s);                                                       \
                a2 = ssat16(a2 >> s);                                                       \
                a3 = ssat16(a3 >> s);                                                       \
            }                                                                                   \
            y[0] = pack16(a0, a1);                                                              \
            y[1] = pack16(a2, a3);                                                              \
            y += 2;                                                                             \
        }                                                                                       \
    }
NS2_Q15_FOR_EACH_QUAD_COUNT(NS2_Q15_KERNEL)

#define NS2_Q15_CASE(NQ)                   \
    case NQ:                               \
        dense_q15_##NQ(layer, x, y, relu); \
        return;

static void dense_q15(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int relu)
{
    switch (layer->n_quads) {
        NS2_Q15_FOR_EACH_QUAD_COUNT(NS2_Q15_CASE)
    default:
        dense_q15_c(layer, x, y, relu); /* a count the exporter did not list */
        return;
    }
}
#else
#define dense_q15 dense_q15_c
#endif

static const int32_t *net_q15(const ns2_q15_net_t *net, const int32_t *x, int32_t buf[2][NS2_Q_WORDS])
{
    const int32_t *in = x;
    for (uint8_t l = 0; l < net->n_layers; ++l) {
        int32_t *out = buf[l & 1u];
        dense_q15(&net->layers[l], in, out, l + 1u < net->n_layers);
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

static void accumulate(int32_t h[NS2_HIDDEN], const int32_t *phi)
{
    for (int k = 0; k + 1 < NS2_HIDDEN; k += 2) {
        h[k] += unpack_lo(phi[k / 2]);
        h[k + 1] += unpack_hi(phi[k / 2]);
    }
#if NS2_HIDDEN % 2
    h[NS2_HIDDEN - 1] += unpack_lo(phi[NS2_HIDDEN / 2]);
#endif
}

int16_t ns2_predict_q15(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    ns2_info_t local;
    ns2_info_t *inf = info != NULL ? info : &local;
    float x[6];
    int32_t xq[4];
    int32_t buf[2][NS2_Q_WORDS];
    int32_t h[NS2_HIDDEN];
    int32_t hq[NS2_PAD4(NS2_HIDDEN) / 2];
    uint16_t idx[NS2_MAX_NEIGHBORS];
    uint16_t n_used;

    if (ns2_prepare(robot_type, p, v, neighbors, n_neighbors, x, idx, &n_used, inf) != NS2_OK) {
        return 0;
    }
    for (int k = 0; k < NS2_HIDDEN; ++k) {
        h[k] = 0;
    }
    quantize_input(x, ns2_q15_in_scale[NS2_ENV_TYPE], xq);
    accumulate(h, net_q15(&ns2_q15_phi[NS2_ENV_TYPE], xq, buf));
    for (uint16_t j = 0; j < n_used; ++j) {
        const ns2_neighbor_t *nb = &neighbors[idx[j]];
        ns2_clamp_input(nb->type, nb->rel, x);
        quantize_input(x, ns2_q15_in_scale[nb->type], xq);
        accumulate(h, net_q15(&ns2_q15_phi[nb->type], xq, buf));
    }
    for (int k = 0; k < NS2_PAD4(NS2_HIDDEN) / 2; ++k) {
        const int32_t h0 = 2 * k < NS2_HIDDEN ? round_shift_sat(h[2 * k], NS2_Q_SUM_SHIFT) : 0;
        const int32_t h1 = 2 * k + 1 < NS2_HIDDEN ? round_shift_sat(h[2 * k + 1], NS2_Q_SUM_SHIFT) : 0;
        hq[k] = pack16(h0, h1);
    }
    return (int16_t)unpack_lo(net_q15(&ns2_q15_rho[robot_type], hq, buf)[0]);
}

float ns2_predict_q15_g(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    const int16_t q = ns2_predict_q15(robot_type, p, v, neighbors, n_neighbors, info);
    return (float)q * NS2_Q_OUT_SCALE;
}
