/* ns2_label.c - see ns2_label.h.  Every expression is written in the order of the
 * float32 reference (ns2codegen/onboard.py); -ffp-contract=off keeps it so. */
#include "ns2_label.h"

#include "ns2_controller.h"

#define LABEL_G ((float)NS2_G_MPS2)
#define LABEL_V_NORM 4.2f

static int label_in(float x, float lo, float hi)
{
    return x >= lo && x <= hi; /* false for NaN */
}

float ns2_label_exp_neg(float x)
{
    if (!(x > 0.0f)) {
        return 1.0f;
    }
    if (!(x <= 1.0e4f)) {
        return 0.0f;
    }
    int s = 0;
    while (x > 0.5f) { /* exact halvings: x / 2^s in (0.25, 0.5] */
        x *= 0.5f;
        ++s;
    }
    /* Taylor series of exp(-x) to degree 8, Horner (|error| < 1e-9 for x <= 0.5) */
    float y = 1.0f - x / 8.0f;
    y = 1.0f - x / 7.0f * y;
    y = 1.0f - x / 6.0f * y;
    y = 1.0f - x / 5.0f * y;
    y = 1.0f - x / 4.0f * y;
    y = 1.0f - x / 3.0f * y;
    y = 1.0f - x / 2.0f * y;
    y = 1.0f - x * y;
    for (; s > 0; --s) {
        y = y * y;
    }
    return y;
}

static int label_config_ok(const ns2_label_cfg_t *c)
{
    int ok = label_in(c->mass_kg, 1.0e-6f, 100.0f) && label_in(c->lambda, 0.0f, 1.0e4f)
        && label_in(c->h_s, 1.0e-4f, 1.0f) && label_in(c->min_z_m, -1.0e3f, 1.0e3f)
        && label_in(c->min_r33, -2.0f, 2.0f);
    for (int i = 0; i < 5; ++i) {
        ok = ok && label_in(c->psi1[i], -1.0e6f, 1.0e6f);
    }
    return ok;
}

void ns2_label_restart(ns2_label_t *l)
{
    for (unsigned i = 0; i < NS2_LABEL_STENCIL; ++i) {
        l->vz[i] = 0.0f;
    }
    for (unsigned i = 0; i <= NS2_LABEL_DELAY; ++i) {
        l->ft[i] = l->z[i] = l->r33[i] = 0.0f;
    }
    for (int m = 0; m < 4; ++m) {
        l->u[m] = l->uc[m] = 0.0f;
    }
    l->sat = 0u;
    l->n_good = 0u;
    l->label_N = l->label_g = 0.0f;
}

void ns2_label_init(ns2_label_t *l, const ns2_label_cfg_t *cfg)
{
    l->cfg = *cfg;
    l->config_ok = (uint8_t)label_config_ok(cfg);
    l->a = l->config_ok ? ns2_label_exp_neg(cfg->lambda * cfg->h_s) : 0.0f;
    l->status = l->config_ok ? NS2_LABEL_WARMUP : NS2_LABEL_BAD_CONFIG;
    ns2_label_restart(l);
}

/* psi_1 of one motor in newtons (labels.psi1_newtons): 0 for a stopped motor */
static float label_motor_N(const float k[5], float p, float v)
{
    if (!(p > 0.0f)) {
        return 0.0f;
    }
    float f = k[0] + k[1] * p + k[2] * v + k[3] * p * p + k[4] * p * v;
    f = f > 0.0f ? f : 0.0f;
    return f * LABEL_G / 1000.0f;
}

static int label_input_ok(float vz, float z, const float q[4], const float pwm[4], float battery_V)
{
    const float n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    int ok = label_in(vz, -NS2_CTRL_V_MAX_MS, NS2_CTRL_V_MAX_MS) && label_in(z, -NS2_CTRL_P_MAX_M, NS2_CTRL_P_MAX_M)
        && label_in(n2, 0.25f, 4.0f) && label_in(battery_V, 0.0f, NS2_CTRL_BAT_MAX_V);
    for (int m = 0; m < 4; ++m) {
        ok = ok && label_in(pwm[m], 0.0f, 1.0f);
    }
    return ok;
}

static void label_shift(float *h, unsigned n, float x)
{
    for (unsigned i = 0; i + 1u < n; ++i) {
        h[i] = h[i + 1u];
    }
    h[n - 1u] = x;
}

uint32_t ns2_label_step(ns2_label_t *l, float vz, float z, const float q[4], const float pwm[4], float battery_V)
{
    if (!l->config_ok) {
        l->label_N = l->label_g = 0.0f;
        return l->status = NS2_LABEL_BAD_CONFIG;
    }
    if (!label_input_ok(vz, z, q, pwm, battery_V)) {
        ns2_label_restart(l);
        return l->status = NS2_LABEL_BAD_INPUT;
    }
    const float v = battery_V / LABEL_V_NORM;
    float uc[4];
    uint8_t sat = 0u;
    for (int m = 0; m < 4; ++m) {
        uc[m] = label_motor_N(l->cfg.psi1, pwm[m], v);
        sat = (uint8_t)(sat | (pwm[m] <= 0.0f || pwm[m] >= 1.0f));
    }
    for (int m = 0; m < 4; ++m) { /* u of this sample from the last one's u and command */
        l->u[m] = l->n_good ? l->a * l->u[m] + (1.0f - l->a) * l->uc[m] : uc[m];
        l->uc[m] = uc[m];
    }
    const float T = l->u[0] + l->u[1] + l->u[2] + l->u[3];
    const float r33 = 1.0f - 2.0f * (q[1] * q[1] + q[2] * q[2]);
    label_shift(l->vz, NS2_LABEL_STENCIL, vz);
    label_shift(l->ft, NS2_LABEL_DELAY + 1u, r33 * T);
    label_shift(l->z, NS2_LABEL_DELAY + 1u, z);
    label_shift(l->r33, NS2_LABEL_DELAY + 1u, r33);
    l->sat = (uint8_t)(((unsigned)l->sat << 1u | sat) & ((1u << NS2_LABEL_STENCIL) - 1u));
    if (l->n_good < NS2_LABEL_STENCIL) {
        ++l->n_good;
    }
    if (l->n_good < NS2_LABEL_STENCIL) {
        l->label_N = l->label_g = 0.0f;
        return l->status = NS2_LABEL_WARMUP;
    }
    const float *x = l->vz;
    const float vdot = (-x[4] + 8.0f * x[3] - 8.0f * x[1] + x[0]) / (12.0f * l->cfg.h_s);
    const float m = l->cfg.mass_kg;
    l->label_N = m * vdot + m * LABEL_G - l->ft[0];
    l->label_g = l->label_N * 1000.0f / LABEL_G;
    uint32_t st = NS2_LABEL_OK;
    st |= l->z[0] < l->cfg.min_z_m ? NS2_LABEL_GROUND : 0u;
    st |= l->r33[0] < l->cfg.min_r33 ? NS2_LABEL_TILTED : 0u;
    st |= l->sat ? NS2_LABEL_SATURATED : 0u;
    return l->status = st;
}
