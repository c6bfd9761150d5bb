/* ctrl_authors.c - see ctrl_authors.h. */
#include "ctrl_authors.h"

#include <math.h>
#include <string.h>

void ns2_authors_init(ns2_authors_t *a, const ns2_authors_gains_t *g)
{
    memset(a, 0, sizeof *a);
    a->g = *g;
}

static float clamp_abs(float x, float lim)
{
    return x > lim ? lim : (x < -lim ? -lim : x);
}

void ns2_authors_position(ns2_authors_t *a, ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                          float fa_z_N, float dt)
{
    const ns2_authors_gains_t *g = &a->g;
    const float fa[3] = {0.0f, 0.0f, isfinite(fa_z_N) ? fa_z_N : 0.0f};
    float f_d[3];
    for (int i = 0; i < 3; ++i) {
        const float e = sp->p[i] - s->p[i];
        const float e_v = sp->v[i] - s->v[i];
        a->i_e[i] = clamp_abs(a->i_e[i] + e * dt, g->i_max);
        if (!isfinite(a->i_e[i])) {
            a->i_e[i] = 0.0f;
        }
        f_d[i] = g->mass_kg * (sp->a[i] + g->kp[i] * e + g->kd[i] * e_v + g->ki[i] * a->i_e[i]) - g->k_fa * fa[i];
    }
    f_d[2] += g->mass_kg * (float)NS2_G_MPS2;
    ns2_ctrl_force(c, s, sp, f_d, dt);
}

void ns2_authors_law(void *ctx, ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, float dt)
{
    ns2_authors_t *a = (ns2_authors_t *)ctx;
    const float fa_g = a->fa_given ? a->fa_given_g : (pl->cfg.enable ? pl->fa_hat_g : 0.0f);
    const float fa_z_N = fa_g * 1e-3f * (float)NS2_G_MPS2;
    ns2_authors_position(a, &pl->ctrl, s, sp, fa_z_N, dt);
}
