/* ns2_adapt.c - see ns2_adapt.h.  Every expression is written in the order of the
 * float32 reference (ns2codegen/onboard.py); -ffp-contract=off keeps it so. */
#include "ns2_adapt.h"

#define MEM_MAX 1.0e30f

static int in_range(float x, float lo, float hi)
{
    return x >= lo && x <= hi; /* false for NaN */
}

static float clampf(float x, float lim, uint32_t *st)
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
    cfg->forget = 0.995f;
    cfg->p0 = 1.0f;
    cfg->p_max = 10.0f;
    cfg->bias_max_g = 10.0f;
    cfg->scale_max = 0.5f;
    cfg->fa_max_g = 10.0f;
    cfg->label_max_g = 40.0f;
    cfg->wake_g = 15.0f;
}

int ns2_adapt_cfg_ok(const ns2_adapt_cfg_t *c)
{
    return in_range(c->forget, NS2_ADAPT_FORGET_MIN, 1.0f) && in_range(c->p_max, NS2_ADAPT_P_MIN, NS2_ADAPT_LIMIT_MAX)
        && in_range(c->p0, NS2_ADAPT_P_MIN, c->p_max) && in_range(c->bias_max_g, 0.0f, NS2_ADAPT_LIMIT_MAX)
        && in_range(c->scale_max, 0.0f, NS2_ADAPT_LIMIT_MAX) && in_range(c->fa_max_g, 0.0f, NS2_ADAPT_LIMIT_MAX)
        && in_range(c->label_max_g, 0.0f, NS2_ADAPT_LIMIT_MAX) && in_range(c->wake_g, 0.0f, NS2_ADAPT_LIMIT_MAX);
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

static int memory_ok(const ns2_adapt_t *a)
{
    return in_range(a->theta[0], -MEM_MAX, MEM_MAX) && in_range(a->theta[1], -MEM_MAX, MEM_MAX)
        && in_range(a->P[0], -MEM_MAX, MEM_MAX) && in_range(a->P[1], -MEM_MAX, MEM_MAX)
        && in_range(a->P[2], -MEM_MAX, MEM_MAX);
}

/* the recursive least-squares step with forgetting on (psi = [1, n], y) */
static void rls_update(ns2_adapt_t *a, const ns2_adapt_cfg_t *c, float n, float y, uint32_t *st)
{
    float *P = a->P;
    const float Pp0 = P[0] + P[1] * n;
    const float Pp1 = P[1] + P[2] * n;
    const float den = c->forget + (Pp0 + n * Pp1);
    const float k0 = Pp0 / den;
    const float k1 = Pp1 / den;
    const float e = y - n - (a->theta[0] + a->theta[1] * n);
    a->theta[0] = clampf(a->theta[0] + k0 * e, c->bias_max_g, st);
    a->theta[1] = clampf(a->theta[1] + k1 * e, c->scale_max, st);
    P[0] = (P[0] - k0 * Pp0) / c->forget;
    P[1] = (P[1] - k0 * Pp1) / c->forget;
    P[2] = (P[2] - k1 * Pp1) / c->forget;
    const float tr = P[0] + P[2];
    if (tr > c->p_max) {
        const float s = c->p_max / tr;
        P[0] = P[0] * s;
        P[1] = P[1] * s;
        P[2] = P[2] * s;
    }
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
    uint32_t st = 0u;
    if (!in_range(nn_g, -MEM_MAX, MEM_MAX)) {
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
    if (!memory_ok(a)) {
        ns2_adapt_reset(a, c);
        a->nn[NS2_ADAPT_NN_DELAY] = nn_g;
        a->wake = (uint8_t)(wake != 0);
        a->n_nn = 1u;
        st |= NS2_ADAPT_RESET;
    }
    const float n = a->nn[0];
    if (label_status != 0u || a->n_nn <= NS2_ADAPT_NN_DELAY) {
        st |= NS2_ADAPT_LABEL;
    } else if (!in_range(label_g, -c->label_max_g, c->label_max_g)) {
        st |= NS2_ADAPT_LABEL_BOUND;
    } else if ((a->wake >> NS2_ADAPT_NN_DELAY) & 1u || !in_range(n, -c->wake_g, c->wake_g)) {
        st |= NS2_ADAPT_WAKE;
    } else {
        rls_update(a, c, n, label_g, &st);
    }
    a->term_g = clampf(a->theta[0] + a->theta[1] * nn_g, c->fa_max_g, &st);
    a->out_g = nn_g + a->term_g;
    a->status = st;
    return a->out_g;
}
