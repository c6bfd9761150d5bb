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
 * Right shifts of negative numbers are written so that they are defined C.
 */
#include <math.h>
#include <stddef.h>

#include "ns2_internal.h"
#include "ns2_model_fixed.h"

#define NS2_Q_BUF (NS2_MAX_WIDTH + 1) /* room for the zero pad of odd widths */

/* floor(a / 2^s) for any sign, without implementation-defined shifts. */
static int32_t floor_shift(int32_t a, uint8_t s)
{
    return a >= 0 ? (int32_t)(a >> s) : (int32_t)~((~a) >> s);
}

static int16_t sat16(int32_t a)
{
    return (int16_t)(a > INT16_MAX ? INT16_MAX : (a < INT16_MIN ? INT16_MIN : a));
}

/* Round half up by s bits, saturate to int16.  |a| + 2^(s-1) <= INT32_MAX is
 * part of the exporter's overflow proof. */
static int16_t round_shift_sat(int32_t a, uint8_t s)
{
    if (s == 0u) {
        return sat16(a);
    }
    return sat16(floor_shift(a + (int32_t)(1L << (s - 1u)), s));
}

/* x -> sat16(round_half_up(x * 2^f_in)) with scale = 2^f_in; x is already clamped to the box. */
static int16_t quantize(float x, float scale)
{
    const float v = x * scale; /* exact: scale is a power of two */
    const float fl = floorf(v);
    int32_t q = (int32_t)fl;
    if (v - fl >= 0.5f) {
        q += 1;
    }
    return sat16(q);
}

static void dense_q15(const ns2_q15_layer_t *layer, const int16_t *x, int16_t *y, int relu)
{
    const int16_t *w = layer->w;
    for (uint16_t o = 0; o < layer->n_out; ++o) {
        int32_t acc = layer->b[o];
        for (uint16_t i = 0; i < layer->n_in_pad; ++i) {
            acc += (int32_t)w[i] * (int32_t)x[i];
        }
        w += layer->n_in_pad;
        const int16_t r = round_shift_sat(acc, layer->shift);
        y[o] = (relu && r < 0) ? (int16_t)0 : r;
    }
    if (layer->n_out & 1u) {
        y[layer->n_out] = 0; /* zero pad: the next layer reads an even count */
    }
}

static const int16_t *net_q15(const ns2_q15_net_t *net, const int16_t *x,
                              int16_t buf[2][NS2_Q_BUF])
{
    const int16_t *in = x;
    for (uint8_t l = 0; l < net->n_layers; ++l) {
        int16_t *out = buf[l & 1u];
        dense_q15(&net->layers[l], in, out, l + 1u < net->n_layers);
        in = out;
    }
    return in;
}

static void quantize_input(const float x[6], float scale, int16_t xq[NS2_Q_BUF])
{
    for (int a = 0; a < 6; ++a) {
        xq[a] = quantize(x[a], scale);
    }
}

int16_t ns2_predict_q15(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    ns2_info_t local;
    ns2_info_t *inf = info != NULL ? info : &local;
    float x[6];
    int16_t xq[NS2_Q_BUF];
    int16_t buf[2][NS2_Q_BUF];
    int32_t h[NS2_HIDDEN];
    int16_t hq[NS2_Q_BUF];
    uint16_t idx[NS2_MAX_NEIGHBORS];
    uint16_t n_used;

    if (ns2_prepare(robot_type, p, v, neighbors, n_neighbors, x, idx, &n_used, inf) != NS2_OK) {
        return 0;
    }
    quantize_input(x, ns2_q15_in_scale[NS2_ENV_TYPE], xq);
    const int16_t *phi = net_q15(&ns2_q15_phi[NS2_ENV_TYPE], xq, buf);
    for (int k = 0; k < NS2_HIDDEN; ++k) {
        h[k] = phi[k];
    }
    for (uint16_t j = 0; j < n_used; ++j) {
        const ns2_neighbor_t *nb = &neighbors[idx[j]];
        ns2_clamp_input(nb->type, nb->rel, x);
        quantize_input(x, ns2_q15_in_scale[nb->type], xq);
        phi = net_q15(&ns2_q15_phi[nb->type], xq, buf);
        for (int k = 0; k < NS2_HIDDEN; ++k) {
            h[k] += phi[k];
        }
    }
    for (int k = 0; k < NS2_HIDDEN; ++k) {
        hq[k] = round_shift_sat(h[k], NS2_Q_SUM_SHIFT);
    }
    hq[NS2_HIDDEN] = 0;
    return net_q15(&ns2_q15_rho[robot_type], hq, buf)[0];
}

float ns2_predict_q15_g(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info)
{
    const int16_t q = ns2_predict_q15(robot_type, p, v, neighbors, n_neighbors, info);
    return (float)q * NS2_Q_OUT_SCALE;
}
