/*
 * ns2_f32.c - float32 inference of the heterogeneous deep set.
 *
 * Bit-reproducible by construction: every dot product starts from the bias and
 * accumulates inputs in index order, the latent sum runs environment first and
 * then neighbours in array order, and the library is built with
 * -ffp-contract=off (no fused multiply-add) and without -ffast-math.  The Python
 * reference (ns2codegen.reference) performs the same float32 operations in the
 * same order, so both agree bit for bit.
 */
#include <math.h>
#include <stddef.h>

#include "ns2_internal.h"
#include "ns2_model_float.h"

/* y = W x + b, optional ReLU (eq. sn's g(x) layer); NaN -> 0 in the ReLU. */
static void dense_f32(const ns2_f32_layer_t *layer, const float *x, float *y, int relu)
{
    const float *w = layer->w;
    for (uint16_t o = 0; o < layer->n_out; ++o) {
        float acc = layer->b[o];
        for (uint16_t i = 0; i < layer->n_in; ++i) {
            acc += w[i] * x[i];
        }
        w += layer->n_in;
        y[o] = relu ? (acc > 0.0f ? acc : 0.0f) : acc;
    }
}

/* Evaluate an MLP; returns a pointer to its output (inside buf). */
static const float *net_f32(const ns2_f32_net_t *net, const float *x,
                            float buf[2][NS2_MAX_WIDTH])
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
    float buf[2][NS2_MAX_WIDTH];
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
