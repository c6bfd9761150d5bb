/* ns2_pilot.c - see ns2_pilot.h. */
#include "ns2_pilot.h"

#include <float.h>
#include <math.h>
#include <stddef.h>

void ns2_pilot_default_cfg(ns2_pilot_cfg_t *cfg, uint8_t self_type)
{
    cfg->enable = 1u;
    cfg->fixed = 1u;
    cfg->self_type = self_type;
    cfg->phi_per_tick = 4u;
    cfg->max_age_ms = 100u;
    cfg->fa_limit_g = 20.0f;
}

/* the label's configuration for the vehicle of the controller and pl->psi1 */
static void pilot_label_init(ns2_pilot_t *pl)
{
    ns2_label_cfg_t lc;
    lc.mass_kg = pl->ctrl.veh.mass_kg;
    lc.lambda = pl->ctrl.veh.lambda;
    for (int i = 0; i < 5; ++i) {
        lc.psi1[i] = pl->psi1[i];
    }
    lc.h_s = 1.0f / (float)NS2_PILOT_POS_HZ;
    lc.min_z_m = NS2_PILOT_LABEL_MIN_Z_M;
    lc.min_r33 = NS2_PILOT_LABEL_MIN_R33;
    ns2_label_init(&pl->label, &lc);
}

void ns2_pilot_reset(ns2_pilot_t *pl, const ns2_vehicle_t *veh)
{
    ns2_ctrl_init(&pl->ctrl, veh, &pl->gains);
    pl->job_begun = 0u;
    pl->nbrs_listed = 0u;
    pl->fa_hat_g = 0.0f;
    pl->status = 0; /* no prediction: the same after a reset at any millisecond of ns2_pilot_step */
    pl->n_used = 0u;
    pl->fa_used_g = 0.0f;
    pl->battery_V = 0.0f;
    pilot_label_init(pl);
    ns2_adapt_reset(&pl->adapt, &pl->adapt_cfg);
}

void ns2_pilot_set_psi1(ns2_pilot_t *pl, const float psi1[5])
{
    for (int i = 0; i < 5; ++i) {
        pl->psi1[i] = psi1[i];
    }
    pilot_label_init(pl);
}

void ns2_pilot_init(ns2_pilot_t *pl, const ns2_pilot_cfg_t *cfg, const ns2_vehicle_t *veh, const ns2_gains_t *g)
{
    pl->cfg = *cfg;
    pl->gains = *g;
    ns2_peers_init(&pl->peers, 0.5f);
    pl->e[0] = pl->e[1] = pl->e[2] = 0.0f;
    ns2_adapt_default_cfg(&pl->adapt_cfg);
    pl->adapt_cfg.enable = 0u;
    for (int i = 0; i < 5; ++i) {
        pl->psi1[i] = 0.0f;
    }
    ns2_pilot_reset(pl, veh);
}

int32_t ns2_pilot_peer(ns2_pilot_t *pl, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3])
{
    return ns2_peers_update(&pl->peers, id, type, t_ms, p);
}

#if NS2_PILOT_Q15
/* fixed point unless cfg.fixed = 0 with the float path compiled in too */
static int pilot_use_fixed(const ns2_pilot_t *pl)
{
    return !NS2_PILOT_F32 || pl->cfg.fixed != 0u;
}
#endif

static float pilot_finish(ns2_pilot_t *pl, ns2_info_t *info)
{
#if NS2_PILOT_Q15
    if (pilot_use_fixed(pl)) {
        return ldexpf((float)ns2_job_finish_q15(&pl->job, info), -NS2_Q_OUT_FRAC);
    }
#endif
#if NS2_PILOT_F32
    return ns2_job_finish_f32(&pl->job, info);
#else
    return 0.0f; /* not reached: without the float path the fixed one returned */
#endif
}

void ns2_pilot_finish(ns2_pilot_t *pl)
{
    if (pl->job_begun) {
        ns2_info_t info;
        const float f = pilot_finish(pl, &info);
        const float lim = pl->cfg.fa_limit_g;
        pl->status = info.status;
        pl->n_used = info.n_used;
        /* a limit that is not a finite number >= 0 (NaN, negative, infinite) gives 0: no learned force */
        pl->fa_hat_g = !(lim >= 0.0f && lim <= FLT_MAX) ? 0.0f : (f > lim ? lim : (f < -lim ? -lim : f));
        pl->job_begun = 0u;
    }
}

void ns2_pilot_select(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, uint8_t self_id, uint32_t now_ms)
{
#if NS2_HISTORY_LAGS > 0
    /* wake memory: this position tick is a history tick of the peer table */
    ns2_peers_record(&pl->peers, s->p, s->v);
#endif
    pl->nbrs_n = ns2_peers_neighbors(&pl->peers, self_id, s->p, s->v, now_ms, pl->cfg.max_age_ms, pl->nbrs,
                                     NS2_PEERS_MAX);
    for (int a = 0; a < 3; ++a) {
        pl->listed_p[a] = s->p[a];
        pl->listed_v[a] = s->v[a];
    }
    pl->nbrs_listed = 1u;
}

void ns2_pilot_start(ns2_pilot_t *pl)
{
    if (!pl->nbrs_listed) {
        return;
    }
#if NS2_HISTORY_LAGS > 0
    /* the own ring changes only at a history tick (ns2_peers_record), so it still is the select's */
    float own_past[6 * NS2_HISTORY_LAGS];
    ns2_peers_own_past(&pl->peers, pl->listed_p, pl->listed_v, own_past);
    (void)ns2_job_begin_hist(&pl->job, pl->cfg.self_type, pl->listed_p, pl->listed_v, own_past, pl->nbrs,
                             pl->nbrs_n);
#else
    (void)ns2_job_begin(&pl->job, pl->cfg.self_type, pl->listed_p, pl->listed_v, pl->nbrs, pl->nbrs_n);
#endif
    pl->nbrs_listed = 0u;
    pl->job_begun = 1u;
}

void ns2_pilot_begin(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, uint8_t self_id, uint32_t now_ms)
{
    ns2_pilot_select(pl, s, self_id, now_ms);
    ns2_pilot_start(pl);
}

void ns2_pilot_period(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, uint8_t self_id, uint32_t now_ms)
{
    ns2_pilot_finish(pl);
    ns2_pilot_begin(pl, s, self_id, now_ms);
}

void ns2_pilot_position(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp)
{
    const uint32_t lst = ns2_label_step(&pl->label, s->v[2], s->p[2], s->q, pl->ctrl.pwm, pl->battery_V);
    /* the composite law's tracking error in z (the controller's s = v - v_r, v_r = v_d - Lp (p - p_d))
     * times the position period, m; only computed when the law uses it */
    const float h = 1.0f / (float)NS2_PILOT_POS_HZ;
    const float s_h = pl->adapt_cfg.track_gain > 0.0f
        ? (s->v[2] - sp->v[2] + pl->gains.Lp[2] * (s->p[2] - sp->p[2])) * h : 0.0f;
    pl->fa_used_g = ns2_adapt_step_track(&pl->adapt, &pl->adapt_cfg, pl->fa_hat_g, pl->n_used > 0u, pl->label.label_g,
                                         lst, s_h);
    const float fa[3] = {0.0f, 0.0f, pl->cfg.enable ? pl->fa_used_g * 1e-3f * (float)NS2_G_MPS2 : 0.0f}; /* g -> N */
    pl->ctrl.g = pl->gains;
    ns2_ctrl_position(&pl->ctrl, s, sp, fa, h);
    for (int a = 0; a < 3; ++a) {
        pl->e[a] = s->p[a] - sp->p[a];
    }
}

static void pilot_step_phi(ns2_pilot_t *pl, uint16_t n)
{
#if NS2_PILOT_Q15
    if (pilot_use_fixed(pl)) {
        (void)ns2_job_step_q15(&pl->job, n);
        return;
    }
#endif
#if NS2_PILOT_F32
    (void)ns2_job_step_f32(&pl->job, n);
#endif
}

void ns2_pilot_slice(ns2_pilot_t *pl)
{
    pilot_step_phi(pl, pl->cfg.phi_per_tick);
}

void ns2_pilot_attitude(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, float battery_V)
{
    ns2_ctrl_attitude(&pl->ctrl, s, 1.0f / (float)NS2_PILOT_ATT_HZ, battery_V);
    pl->battery_V = battery_V;
}

void ns2_pilot_tick(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, int do_pos,
                    uint8_t self_id, uint32_t now_ms, float battery_V)
{
    if (do_pos) {
        ns2_pilot_period(pl, s, self_id, now_ms);
        ns2_pilot_position(pl, s, sp);
    }
    ns2_pilot_slice(pl);
    ns2_pilot_attitude(pl, s, battery_V);
}

/* k = tick % 10: 0 select + position, 1 start + half a slice less one phi (the start costs
 * about one phi), 2..8 half a slice (rounded up at odd k), 9 finish; attitude at even k.
 * Same motor commands as ns2_pilot_tick: the prediction begun from the state and neighbours
 * of k = 0 is finished before the next k = 0 either way, and slicing does not change its
 * result (ns2_deepset.h). */
void ns2_pilot_step(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, uint32_t tick,
                    uint8_t self_id, uint32_t now_ms, float battery_V)
{
    const uint32_t per_pos = NS2_PILOT_STEP_HZ / NS2_PILOT_POS_HZ, per_att = NS2_PILOT_STEP_HZ / NS2_PILOT_ATT_HZ;
    const uint32_t k = tick % per_pos;
    if (k == per_pos - 1u) {
        ns2_pilot_finish(pl);
        return;
    }
    if (k == 0u) {
        ns2_pilot_select(pl, s, self_id, now_ms);
        ns2_pilot_position(pl, s, sp);
    } else {
        const uint16_t half = (uint16_t)(pl->cfg.phi_per_tick / per_att);
        uint16_t n = (uint16_t)(k % per_att ? pl->cfg.phi_per_tick - half : half);
        if (k == 1u) {
            ns2_pilot_start(pl);
            n = n > 0u ? (uint16_t)(n - 1u) : 0u;
        }
        pilot_step_phi(pl, n);
    }
    if (k % per_att == 0u) {
        ns2_pilot_attitude(pl, s, battery_V);
    }
}
