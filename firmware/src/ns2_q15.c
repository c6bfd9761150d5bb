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
 * fully unrolled over the inputs); other targets use a portable C SMLAD with the
 * same result (integer sums are exact).  The bias tables already contain the
 * rounding offset 2^(shift-1).  The generated weights are laid out
 * [block of four output rows][input pair][row]; inputs and rows are zero-padded
 * to multiples of four.  Four output rows share each loaded input word, and
 * neighbours of the same type go through phi two at a time, so that each loaded
 * weight word serves two neighbours (activations interleaved: word 2k is pair k
 * of the first neighbour, word 2k + 1 that of the second).  Integer sums are
 * exact, so neither the grouping nor the order changes a bit.  Right shifts of
 * negative numbers are written so that they are defined C.
 */
#include <stddef.h>
#include <string.h>

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
#define NS2_IN_WORDS (NS2_PAD4(NS2_INPUT_DIM) / 2) /* int16 pairs of one phi input */

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

/* x -> sat16(round_half_up(x * scale)), scale = 2^f_in; x is already clamped.
 * Adding and subtracting 1.5 * 2^23 rounds |v| < 2^22 to the nearest integer
 * (ties to even, the default float rounding); a tie that went down is moved up.
 * The result is floor(v + 0.5), as in the reference. */
static int32_t quantize(float x, float scale)
{
    const float magic = 12582912.0f; /* 1.5 * 2^23 */
    const float v = x * scale;       /* exact: scale is a power of two; |v| < 2^16 */
    const float r = (v + magic) - magic;
    int32_t q = (int32_t)r; /* exact: r is an integer */
    if (r - v == -0.5f) {   /* exact difference */
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

/* One layer, portable C: per block the four biases, then per input pair the
 * four rows' weight words.  Not inlined into dense_q15: the Cortex-M4 dispatch
 * stays a thin switch. */
__attribute__((noinline)) static void dense_q15_c(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int out)
{
    const int32_t *w = layer->wb;
    const int relu = out == NS2_OUT_RELU;
    for (uint16_t blk = 0; blk < layer->n_blocks; ++blk) {
        int32_t acc[4] = {w[0], w[1], w[2], w[3]};
        w += 4;
        for (uint16_t p = 0; p < 2u * layer->n_quads; ++p) {
            for (int r = 0; r < 4; ++r) {
                acc[r] = ns2_smlad_c(w[r], x[p], acc[r]);
            }
            w += 4;
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

/* The assembly needs an optimized build: at -O0 the compiler keeps a frame
 * pointer and has too few registers left (Crazyflie debug builds use -O0; they
 * get the portable kernels, with the same results). */
#if defined(__ARM_FEATURE_DSP) && __ARM_FEATURE_DSP && defined(__thumb2__) && !defined(NS2_NO_ASM) && \
    defined(__OPTIMIZE__)
#define NS2_Q15_ASM 1
/* Cortex-M4 kernels, one per input-quad count NQ of the model and per output
 * kind (USAT #15 = ReLU + saturation for hidden layers, SSAT #16 for the last).
 * Per block: two LDRD of the biases; per input quad (unrolled NQ times by the
 * assembler) one LDRD of the two input words and per word an LDM of the four
 * rows' weight words and four SMLAD; then ASR (the floor shift), saturation,
 * and the store: two
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
                         "smlad %[a1], r9, %[x0], %[a1]\n\t"                                    \
                         "smlad %[a2], r10, %[x0], %[a2]\n\t"                                   \
                         "smlad %[a3], r11, %[x0], %[a3]\n\t"                                   \
                         "ldmia %[wp]!, {r8, r9, r10, r11}\n\t"                                 \
                         "smlad %[a0], r8, %[x1], %[a0]\n\t"                                    \
                         "smlad %[a1], r9, %[x1], %[a1]\n\t"                                    \
                         "smlad %[a2], r10, %[x1], %[a2]\n\t"                                   \
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
/* only the (input-quad count, output kind) pairs that the model's layers use */
#define NS2_Q15_RELU_KERNEL(NQ) NS2_Q15_KERNEL(NQ, relu, "usat", NS2_Q15_STORE_PACKED)
#define NS2_Q15_LIN_KERNEL(NQ) NS2_Q15_KERNEL(NQ, lin, "ssat", NS2_Q15_STORE_PACKED)
#define NS2_Q15_LAST_PHI_KERNELS(NQ)                      \
    NS2_Q15_KERNEL(NQ, set, "ssat", NS2_Q15_STORE_SET) \
    NS2_Q15_KERNEL(NQ, acc, "ssat", NS2_Q15_STORE_ADD)
NS2_Q15_HIDDEN_QUADS(NS2_Q15_RELU_KERNEL)
NS2_Q15_RHO_LAST_QUADS(NS2_Q15_LIN_KERNEL)
NS2_Q15_PHI_LAST_QUADS(NS2_Q15_LAST_PHI_KERNELS)

/* Two neighbours through one layer (inputs and outputs interleaved, see the top).
 * Per block: the biases (two LDRD, copied to the second neighbour's rows); per
 * input pair (unrolled 2 NQ times) one LDRD of the two neighbours' input words,
 * two LDRD of the four rows' weight words and eight SMLAD, i.e. 17 cycles for
 * 16 multiply-accumulates; then ASR, saturation and the store: four PKHBT and
 * one STM of the interleaved outputs (relu), or the sum of the two neighbours'
 * outputs added into the int32 latent sums (acc).  All fourteen core registers:
 * x in r0, w in r1, accumulators r2-r5 (first neighbour) and r6-r9 (second),
 * inputs r10-r11, weights r12/lr; y, the end of w and the shift stay in the
 * frame (r7 is free: optimized builds keep no frame pointer). */
#define NS2_Q15_PAIR_KERNEL(NQ, NAME, SAT, STORE)                                               \
    __attribute__((noinline)) static void dense2_q15_##NQ##_##NAME(                             \
        const int32_t *x, const int32_t *w, int32_t *y, uint32_t n_blocks, int32_t s)           \
    {                                                                                           \
        register const int32_t *xp __asm__("r0") = x;                                           \
        register const int32_t *wp __asm__("r1") = w;                                           \
        int32_t *y_mem = y;                                                                     \
        const int32_t *const w_end = w + n_blocks * (4u + 8u * (NQ));                           \
        const int32_t s_mem = s;                                                                \
        __asm__ volatile("1:\n\t"                                                               \
                         "ldrd r2, r3, [%[wp]], #8\n\t"                                         \
                         "ldrd r4, r5, [%[wp]], #8\n\t"                                         \
                         "mov r6, r2\n\t"                                                       \
                         "mov r7, r3\n\t"                                                       \
                         "mov r8, r4\n\t"                                                       \
                         "mov r9, r5\n\t"                                                       \
                         ".rept %c[np]\n\t"                                                     \
                         "ldrd r10, r11, [%[xp]], #8\n\t"                                       \
                         "ldrd r12, lr, [%[wp]], #8\n\t"                                        \
                         "smlad r2, r12, r10, r2\n\t"                                           \
                         "smlad r6, r12, r11, r6\n\t"                                           \
                         "smlad r3, lr, r10, r3\n\t"                                            \
                         "smlad r7, lr, r11, r7\n\t"                                            \
                         "ldrd r12, lr, [%[wp]], #8\n\t"                                        \
                         "smlad r4, r12, r10, r4\n\t"                                           \
                         "smlad r8, r12, r11, r8\n\t"                                           \
                         "smlad r5, lr, r10, r5\n\t"                                            \
                         "smlad r9, lr, r11, r9\n\t"                                            \
                         ".endr\n\t"                                                            \
                         "sub %[xp], %[xp], #%c[back]\n\t"                                      \
                         "ldr r10, %[smem]\n\t"                                                 \
                         "asr r2, r2, r10\n\t"                                                  \
                         "asr r3, r3, r10\n\t"                                                  \
                         "asr r4, r4, r10\n\t"                                                  \
                         "asr r5, r5, r10\n\t"                                                  \
                         "asr r6, r6, r10\n\t"                                                  \
                         "asr r7, r7, r10\n\t"                                                  \
                         "asr r8, r8, r10\n\t"                                                  \
                         "asr r9, r9, r10\n\t"                                                  \
                         SAT " r2, " SAT_BITS_##NAME ", r2\n\t"                                 \
                         SAT " r3, " SAT_BITS_##NAME ", r3\n\t"                                 \
                         SAT " r4, " SAT_BITS_##NAME ", r4\n\t"                                 \
                         SAT " r5, " SAT_BITS_##NAME ", r5\n\t"                                 \
                         SAT " r6, " SAT_BITS_##NAME ", r6\n\t"                                 \
                         SAT " r7, " SAT_BITS_##NAME ", r7\n\t"                                 \
                         SAT " r8, " SAT_BITS_##NAME ", r8\n\t"                                 \
                         SAT " r9, " SAT_BITS_##NAME ", r9\n\t"                                 \
                         "ldr r11, %[ymem]\n\t"                                                 \
                         STORE                                                                  \
                         "str r11, %[ymem]\n\t"                                                 \
                         "ldr r12, %[wend]\n\t"                                                 \
                         "cmp %[wp], r12\n\t"                                                   \
                         "bne 1b"                                                               \
                         : [xp] "+r"(xp), [wp] "+r"(wp), [ymem] "+m"(y_mem)                     \
                         : [np] "i"(2 * (NQ)), [back] "i"(16 * (NQ)), [smem] "m"(s_mem),        \
                           [wend] "m"(w_end)                                                    \
                         : "r2", "r3", "r4", "r5", "r6", "r7", "r8", "r9", "r10", "r11", "r12",  \
                           "lr", "cc", "memory");                                               \
    }
#define NS2_Q15_PAIR_STORE_PACKED             \
    "pkhbt r2, r2, r3, lsl #16\n\t"          \
    "pkhbt r3, r6, r7, lsl #16\n\t"          \
    "pkhbt r4, r4, r5, lsl #16\n\t"          \
    "pkhbt r5, r8, r9, lsl #16\n\t"          \
    "stmia r11!, {r2, r3, r4, r5}\n\t"
#define NS2_Q15_PAIR_STORE_ADD                \
    "add r2, r2, r6\n\t"                     \
    "add r3, r3, r7\n\t"                     \
    "add r4, r4, r8\n\t"                     \
    "add r5, r5, r9\n\t"                     \
    "ldmia r11, {r6, r7, r8, r9}\n\t"        \
    "add r6, r6, r2\n\t"                     \
    "add r7, r7, r3\n\t"                     \
    "add r8, r8, r4\n\t"                     \
    "add r9, r9, r5\n\t"                     \
    "stmia r11!, {r6, r7, r8, r9}\n\t"
#define NS2_Q15_PAIR_RELU_KERNEL(NQ) NS2_Q15_PAIR_KERNEL(NQ, relu, "usat", NS2_Q15_PAIR_STORE_PACKED)
#define NS2_Q15_PAIR_ACC_KERNEL(NQ) NS2_Q15_PAIR_KERNEL(NQ, acc, "ssat", NS2_Q15_PAIR_STORE_ADD)
NS2_Q15_PHI_HIDDEN_QUADS(NS2_Q15_PAIR_RELU_KERNEL)
NS2_Q15_PHI_LAST_QUADS(NS2_Q15_PAIR_ACC_KERNEL)

#define NS2_Q15_CASE(NQ, NAME)                                                            \
    case NQ:                                                                              \
        dense_q15_##NQ##_##NAME(x, layer->wb, y, layer->n_blocks, (int32_t)layer->shift); \
        return;
#define NS2_Q15_CASE_RELU(NQ) NS2_Q15_CASE(NQ, relu)
#define NS2_Q15_CASE_LIN(NQ) NS2_Q15_CASE(NQ, lin)
#define NS2_Q15_CASE_SET(NQ) NS2_Q15_CASE(NQ, set)
#define NS2_Q15_CASE_ACC(NQ) NS2_Q15_CASE(NQ, acc)

static void dense_q15(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int out)
{
    if (layer->n_blocks == 0u) {
        return;
    }
    switch (out) {
    case NS2_OUT_RELU:
        switch (layer->n_quads) {
            NS2_Q15_HIDDEN_QUADS(NS2_Q15_CASE_RELU)
        default:
            break;
        }
        break;
    case NS2_OUT_LIN:
        switch (layer->n_quads) {
            NS2_Q15_RHO_LAST_QUADS(NS2_Q15_CASE_LIN)
        default:
            break;
        }
        break;
    case NS2_OUT_SET:
        switch (layer->n_quads) {
            NS2_Q15_PHI_LAST_QUADS(NS2_Q15_CASE_SET)
        default:
            break;
        }
        break;
    default:
        switch (layer->n_quads) {
            NS2_Q15_PHI_LAST_QUADS(NS2_Q15_CASE_ACC)
        default:
            break;
        }
        break;
    }
    dense_q15_c(layer, x, y, out); /* a count the exporter did not list */
}
#else
#define dense_q15 dense_q15_c
#endif

/* Two neighbours through one layer, portable: the same sums as the Cortex-M4
 * pair kernels, inputs and (relu) outputs interleaved, or (acc) both
 * neighbours' outputs added into the int32 sums y. */
__attribute__((noinline)) static void dense2_q15_c(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int out)
{
    const int32_t *w = layer->wb;
    for (uint16_t blk = 0; blk < layer->n_blocks; ++blk) {
        int32_t acc[2][4];
        for (int r = 0; r < 4; ++r) {
            acc[0][r] = acc[1][r] = w[r];
        }
        w += 4;
        for (uint16_t p = 0; p < 2u * layer->n_quads; ++p) {
            for (int r = 0; r < 4; ++r) {
                acc[0][r] = ns2_smlad_c(w[r], x[2u * p], acc[0][r]);
                acc[1][r] = ns2_smlad_c(w[r], x[2u * p + 1u], acc[1][r]);
            }
            w += 4;
        }
        if (out == NS2_OUT_ACC) {
            for (uint16_t r = 0; r < 4u; ++r) {
                y[4u * blk + r] += finish(acc[0][r], layer->shift, 0) + finish(acc[1][r], layer->shift, 0);
            }
        } else {
            for (uint16_t k = 0; k < 2u; ++k) {
                y[4u * blk + k] = pack16(finish(acc[k][0], layer->shift, 1), finish(acc[k][1], layer->shift, 1));
                y[4u * blk + 2u + k] = pack16(finish(acc[k][2], layer->shift, 1), finish(acc[k][3], layer->shift, 1));
            }
        }
    }
}

#ifdef NS2_Q15_ASM
#define NS2_Q15_PAIR_CASE(NQ, NAME)                                                       \
    case NQ:                                                                              \
        dense2_q15_##NQ##_##NAME(x, layer->wb, y, layer->n_blocks, (int32_t)layer->shift); \
        return;
#define NS2_Q15_PAIR_CASE_RELU(NQ) NS2_Q15_PAIR_CASE(NQ, relu)
#define NS2_Q15_PAIR_CASE_ACC(NQ) NS2_Q15_PAIR_CASE(NQ, acc)

/* out: NS2_OUT_RELU (interleaved outputs) or NS2_OUT_ACC (both added into y) */
static void dense2_q15(const ns2_q15_layer_t *layer, const int32_t *x, int32_t *y, int out)
{
    if (layer->n_blocks == 0u) {
        return;
    }
    if (out == NS2_OUT_RELU) {
        switch (layer->n_quads) {
            NS2_Q15_PHI_HIDDEN_QUADS(NS2_Q15_PAIR_CASE_RELU)
        default:
            break;
        }
    } else {
        switch (layer->n_quads) {
            NS2_Q15_PHI_LAST_QUADS(NS2_Q15_PAIR_CASE_ACC)
        default:
            break;
        }
    }
    dense2_q15_c(layer, x, y, out); /* a count the exporter did not list */
}
#else
#define dense2_q15 dense2_q15_c
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

/* Clamped phi input -> NS2_IN_WORDS packed words xq[0], xq[step], ... (NS2_INPUT_DIM
 * is a multiple of 6: three words per time, then zero padding to a multiple of four
 * inputs; step 2: one neighbour of an interleaved pair). */
static void quantize_input(const float x[NS2_INPUT_DIM], float scale, int32_t *xq, int step)
{
    int w = 0;
    for (int k = 0; k < NS2_INPUT_DIM; k += 6, w += 3) {
        xq[w * step] = pack16(quantize(x[k], scale), quantize(x[k + 1], scale));
        xq[(w + 1) * step] = pack16(quantize(x[k + 2], scale), quantize(x[k + 3], scale));
        xq[(w + 2) * step] = pack16(quantize(x[k + 4], scale), quantize(x[k + 5], scale));
    }
#if NS2_INPUT_DIM % 4 != 0
    xq[w * step] = 0; /* inputs NS2_INPUT_DIM and NS2_INPUT_DIM + 1 */
#endif
}

/* h = phi_t(x) (first input) or h += phi_t(x), x clamped (int32 sums: exact).
 * phi's last layer writes or adds its int16 outputs straight into h (the
 * padded rows give 0). */
static void phi_add_q15(int32_t h[NS2_HIDDEN_PAD4], uint8_t t, const float x[NS2_INPUT_DIM], int first)
{
    int32_t xq[NS2_IN_WORDS];
    int32_t buf[2][NS2_Q_WORDS];
    const ns2_q15_net_t *net = &ns2_q15_phi[t];
    quantize_input(x, ns2_q15_in_scale[t], xq, 1);
    dense_q15(&net->layers[net->n_layers - 1u], hidden_q15(net, xq, buf), h, first ? NS2_OUT_SET : NS2_OUT_ACC);
}

/* h += phi_t(xa) + phi_t(xb): two neighbours of the same type t, whose inputs
 * and activations are interleaved so that each weight word serves both. */
static void phi2_add_q15(int32_t h[NS2_HIDDEN_PAD4], uint8_t t, const float xa[NS2_INPUT_DIM],
                        const float xb[NS2_INPUT_DIM])
{
    int32_t xq[2 * NS2_IN_WORDS];
    int32_t buf[2][2 * NS2_Q_WORDS];
    const ns2_q15_net_t *net = &ns2_q15_phi[t];
    const int32_t *in = xq;
    quantize_input(xa, ns2_q15_in_scale[t], xq, 2);
    quantize_input(xb, ns2_q15_in_scale[t], xq + 1, 2);
    for (uint8_t l = 0; l + 1u < net->n_layers; ++l) {
        dense2_q15(&net->layers[l], in, buf[l & 1u], NS2_OUT_RELU);
        in = buf[l & 1u];
    }
    dense2_q15(&net->layers[net->n_layers - 1u], in, h, NS2_OUT_ACC);
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
    return ns2_predict_q15_hist(robot_type, p, v, NULL, neighbors, n_neighbors, info);
}

int16_t ns2_predict_q15_hist(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                             const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    ns2_info_t local;
    ns2_info_t *inf = info != NULL ? info : &local;
    float x[NS2_INPUT_DIM];
    float xa[NS2_INPUT_DIM];
    int32_t h[NS2_HIDDEN_PAD4];
    uint16_t idx[NS2_MAX_NEIGHBORS];
    uint16_t n_used;

    if (ns2_prepare(robot_type, p, v, own_past, neighbors, n_neighbors, x, idx, &n_used, inf) != NS2_OK) {
        return 0;
    }
    phi_add_q15(h, NS2_ENV_TYPE, x, 1);
    /* the neighbours type by type, two at a time (integer sums: any order is exact) */
    for (uint8_t t = 0; t < NS2_NUM_ROBOT_TYPES; ++t) {
        int pending = 0;
        for (uint16_t j = 0; j < n_used; ++j) {
            const ns2_neighbor_t *nb = &neighbors[idx[j]];
            if (nb->type != t) {
                continue;
            }
            if (pending) {
                ns2_clamp_input(t, nb->rel, x);
                phi2_add_q15(h, t, xa, x);
            } else {
                ns2_clamp_input(t, nb->rel, xa);
            }
            pending = !pending;
        }
        if (pending) {
            phi_add_q15(h, t, xa, 0);
        }
    }
    return rho_q15(robot_type, h);
}

/* Moves the next input of the same type as input i (a robot neighbour) to i + 1;
 * 1 if there is one.  Only the fixed-point path reorders a job's inputs. */
static int pair_up(ns2_job_t *job, uint16_t i)
{
    for (uint16_t m = (uint16_t)(i + 1u); m < job->n_inputs; ++m) {
        if (job->type[m] == job->type[i]) {
            if (m != i + 1u) {
                float tmp[NS2_INPUT_DIM];
                memcpy(tmp, job->x[m], sizeof tmp);
                memcpy(job->x[m], job->x[i + 1u], sizeof tmp);
                memcpy(job->x[i + 1u], tmp, sizeof tmp);
                job->type[m] = job->type[i + 1u];
                job->type[i + 1u] = job->type[i];
            }
            return 1;
        }
    }
    return 0;
}

uint16_t ns2_job_step_q15(ns2_job_t *job, uint16_t max_phi)
{
    if (!ns2_job_claim(job, NS2_JOB_Q15)) {
        return 0;
    }
    for (uint16_t k = 0; k < max_phi && job->next < job->n_inputs;) {
        const uint16_t i = job->next;
        if (i > 0u && k + 2u <= max_phi && pair_up(job, i)) {
            phi2_add_q15(job->h_q15, job->type[i], job->x[i], job->x[i + 1u]);
            job->next = (uint16_t)(i + 2u);
            k = (uint16_t)(k + 2u);
        } else {
            phi_add_q15(job->h_q15, job->type[i], job->x[i], i == 0u);
            job->next++;
            k++;
        }
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
