/* ns2_adapt.c - see ns2_adapt.h.  Every expression is written in the order of the
 * float32 reference (ns2codegen/onboard.py); -ffp-contract=off keeps it so. */
#include "ns2_adapt.h"

#define ADAPT_MEM_MAX 1.0e30f

static int adapt_in(float x, float lo, float hi)
{
    return x >= lo && x <= hi; /* false for NaN */
}

static float adapt_clamp(float x, float lim, uint32_t *st)
{
    if (x > lim) {
        *st |= NS2_ADAPT_CLAMPED;
        return lim;
    }
    if (x < -lim) {
        *st |= NS2_ADAPT_CLAMPED;
        return -lim;
    }
    return x;
}

void ns2_adapt_default_cfg(ns2_adapt_cfg_t *cfg)
{
    cfg->enable = 1u;
    cfg->gate_neighbours = 0u;
    cfg->forget = 0.995f;
    cfg->p0 = 1.0f;
    cfg->p_max = 10.0f;
    cfg->bias_max_g = 10.0f;
    cfg->scale_max = 0.0f;
    cfg->fa_max_g = 10.0f;
    cfg->label_max_g = 40.0f;
    cfg->wake_g = 15.0f;
    cfg->track_gain = 0.0f;
}

int ns2_adapt_cfg_ok(const ns2_adapt_cfg_t *c)
{
    return c->gate_neighbours <= 1u && adapt_in(c->forget, NS2_ADAPT_FORGET_MIN, 1.0f) && adapt_in(c->p_max, NS2_ADAPT_P_MIN, NS2_ADAPT_LIMIT_MAX)
        && adapt_in(c->p0, NS2_ADAPT_P_MIN, c->p_max) && adapt_in(c->bias_max_g, 0.0f, NS2_ADAPT_LIMIT_MAX)
        && adapt_in(c->scale_max, 0.0f, NS2_ADAPT_LIMIT_MAX) && adapt_in(c->fa_max_g, 0.0f, NS2_ADAPT_LIMIT_MAX)
        && adapt_in(c->label_max_g, 0.0f, NS2_ADAPT_LIMIT_MAX) && adapt_in(c->wake_g, 0.0f, NS2_ADAPT_LIMIT_MAX)
        && adapt_in(c->track_gain, 0.0f, NS2_ADAPT_TRACK_GAIN_MAX);
}

void ns2_adapt_reset(ns2_adapt_t *a, const ns2_adapt_cfg_t *cfg)
{
    const float p0 = ns2_adapt_cfg_ok(cfg) ? cfg->p0 : 1.0f;
    a->theta[0] = a->theta[1] = 0.0f;
    a->P[0] = p0;
    a->P[1] = 0.0f;
    a->P[2] = p0;
    for (unsigned i = 0; i <= NS2_ADAPT_NN_DELAY; ++i) {
        a->nn[i] = 0.0f;
    }
    a->wake = 0u;
    a->n_nn = 0u;
    a->term_g = 0.0f;
    a->out_g = 0.0f;
    a->status = 0u;
    a->updates = 0u;
}

float ns2_adapt_trace(const ns2_adapt_t *a)
{
    return a->P[0] + a->P[2];
}

static int adapt_memory_ok(const ns2_adapt_t *a)
{
    return adapt_in(a->theta[0], -ADAPT_MEM_MAX, ADAPT_MEM_MAX) && adapt_in(a->theta[1], -ADAPT_MEM_MAX, ADAPT_MEM_MAX)
        && adapt_in(a->P[0], -ADAPT_MEM_MAX, ADAPT_MEM_MAX) && adapt_in(a->P[1], -ADAPT_MEM_MAX, ADAPT_MEM_MAX)
        && adapt_in(a->P[2], -ADAPT_MEM_MAX, ADAPT_MEM_MAX);
}

/* the recursive least-squares step with forgetting on (psi = [1, n], y); psi = [1, 0]
 * (the bias alone) when scale_max = 0; with track_gain > 0 and a good s_h also the
 * composite law's tracking term track_gain s_h P psi */
static void adapt_rls(ns2_adapt_t *a, const ns2_adapt_cfg_t *c, float n, float y, float s_h, uint32_t *st)
{
    float *P = a->P;
    const float x = c->scale_max > 0.0f ? n : 0.0f; /* psi_1 */
    const float Pp0 = P[0] + P[1] * x;
    const float Pp1 = P[1] + P[2] * x;
    const float den = c->forget + (Pp0 + x * Pp1);
    const float k0 = Pp0 / den;
    const float k1 = Pp1 / den;
    const float e = y - n - (a->theta[0] + a->theta[1] * n);
    if (c->track_gain > 0.0f) {
        if (adapt_in(s_h, -NS2_ADAPT_TRACK_SH_MAX, NS2_ADAPT_TRACK_SH_MAX)) {
            const float gs = c->track_gain * s_h;
            a->theta[0] = adapt_clamp(a->theta[0] + k0 * e + gs * Pp0, c->bias_max_g, st);
            a->theta[1] = adapt_clamp(a->theta[1] + k1 * e + gs * Pp1, c->scale_max, st);
        } else {
            *st |= NS2_ADAPT_BAD_TRACK;
            a->theta[0] = adapt_clamp(a->theta[0] + k0 * e, c->bias_max_g, st);
            a->theta[1] = adapt_clamp(a->theta[1] + k1 * e, c->scale_max, st);
        }
    } else {
        a->theta[0] = adapt_clamp(a->theta[0] + k0 * e, c->bias_max_g, st);
        a->theta[1] = adapt_clamp(a->theta[1] + k1 * e, c->scale_max, st);
    }
    P[0] = (P[0] - k0 * Pp0) / c->forget;
    P[1] = (P[1] - k0 * Pp1) / c->forget;
    P[2] = (P[2] - k1 * Pp1) / c->forget;
    P[0] = P[0] < c->p_max ? P[0] : c->p_max; /* no wind-up of an unexcited direction */
    P[2] = P[2] < c->p_max ? P[2] : c->p_max;
    P[0] = P[0] > NS2_ADAPT_P_MIN ? P[0] : NS2_ADAPT_P_MIN;
    P[2] = P[2] > NS2_ADAPT_P_MIN ? P[2] : NS2_ADAPT_P_MIN;
    if (P[1] * P[1] > P[0] * P[2]) {
        P[1] = 0.0f;
    }
    a->updates++;
    *st |= NS2_ADAPT_UPDATED;
}

float ns2_adapt_step(ns2_adapt_t *a, const ns2_adapt_cfg_t *c, float nn_g, int wake, float label_g,
                     uint32_t label_status)
{
    return ns2_adapt_step_track(a, c, nn_g, wake, label_g, label_status, 0.0f);
}

float ns2_adapt_step_track(ns2_adapt_t *a, const ns2_adapt_cfg_t *c, float nn_g, int wake, float label_g,
                           uint32_t label_status, float s_h)
{
    uint32_t st = 0u;
    if (!adapt_in(nn_g, -ADAPT_MEM_MAX, ADAPT_MEM_MAX)) {
        a->n_nn = 0u;
        a->term_g = a->out_g = 0.0f;
        a->status = NS2_ADAPT_BAD_INPUT;
        return 0.0f;
    }
    for (unsigned i = 0; i < NS2_ADAPT_NN_DELAY; ++i) {
        a->nn[i] = a->nn[i + 1u];
    }
    a->nn[NS2_ADAPT_NN_DELAY] = nn_g;
    a->wake = (uint8_t)(((unsigned)a->wake << 1u | (wake != 0)) & ((1u << (NS2_ADAPT_NN_DELAY + 1u)) - 1u));
    if (a->n_nn <= NS2_ADAPT_NN_DELAY) {
        ++a->n_nn;
    }
    if (!ns2_adapt_cfg_ok(c) || !c->enable) {
        a->term_g = 0.0f;
        a->out_g = nn_g;
        a->status = ns2_adapt_cfg_ok(c) ? NS2_ADAPT_OFF : NS2_ADAPT_BAD_PARAM;
        return nn_g;
    }
    if (!adapt_memory_ok(a)) {
        ns2_adapt_reset(a, c);
        a->nn[NS2_ADAPT_NN_DELAY] = nn_g;
        a->wake = (uint8_t)(wake != 0);
        a->n_nn = 1u;
        st |= NS2_ADAPT_RESET;
    }
    const float n = a->nn[0];
    if (label_status != 0u || a->n_nn <= NS2_ADAPT_NN_DELAY) {
        st |= NS2_ADAPT_LABEL;
    } else if (!adapt_in(label_g, -c->label_max_g, c->label_max_g)) {
        st |= NS2_ADAPT_LABEL_BOUND;
    } else if ((c->gate_neighbours && ((a->wake >> NS2_ADAPT_NN_DELAY) & 1u)) || !adapt_in(n, -c->wake_g, c->wake_g)) {
        st |= NS2_ADAPT_WAKE;
    } else {
        adapt_rls(a, c, n, label_g, s_h, &st);
    }
    a->term_g = adapt_clamp(a->theta[0] + a->theta[1] * nn_g, c->fa_max_g, &st);
    a->out_g = nn_g + a->term_g;
    a->status = st;
    return a->out_g;
}
