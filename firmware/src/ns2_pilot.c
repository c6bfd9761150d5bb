/* ns2_pilot.c - see ns2_pilot.h. */
#include "ns2_pilot.h"

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

void ns2_pilot_reset(ns2_pilot_t *pl, const ns2_vehicle_t *veh)
{
    ns2_ctrl_init(&pl->ctrl, veh, &pl->gains);
    pl->job_begun = 0u;
    pl->fa_hat_g = 0.0f;
}

void ns2_pilot_init(ns2_pilot_t *pl, const ns2_pilot_cfg_t *cfg, const ns2_vehicle_t *veh, const ns2_gains_t *g)
{
    pl->cfg = *cfg;
    pl->gains = *g;
    ns2_peers_init(&pl->peers, 0.5f);
    pl->status = 0;
    pl->n_used = 0u;
    pl->e[0] = pl->e[1] = pl->e[2] = 0.0f;
    ns2_pilot_reset(pl, veh);
}

int32_t ns2_pilot_peer(ns2_pilot_t *pl, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3])
{
    return ns2_peers_update(&pl->peers, id, type, t_ms, p);
}

/* Finish the running prediction into fa_hat, begin the next from s and the peers. */
static void predict_period(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, uint8_t self_id, uint32_t now_ms)
{
    if (pl->job_begun) {
        ns2_info_t info;
        const float f = pl->cfg.fixed ? ldexpf((float)ns2_job_finish_q15(&pl->job, &info), -NS2_Q_OUT_FRAC)
                                      : ns2_job_finish_f32(&pl->job, &info);
        const float lim = pl->cfg.fa_limit_g;
        pl->status = info.status;
        pl->n_used = info.n_used;
        pl->fa_hat_g = f > lim ? lim : (f < -lim ? -lim : f);
    }
    const uint16_t n = ns2_peers_neighbors(&pl->peers, self_id, s->p, s->v, now_ms, pl->cfg.max_age_ms,
                                           pl->nbrs, NS2_PEERS_MAX);
    (void)ns2_job_begin(&pl->job, pl->cfg.self_type, s->p, s->v, pl->nbrs, n);
    pl->job_begun = 1u;
}

void ns2_pilot_tick(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, int do_pos,
                    uint8_t self_id, uint32_t now_ms, float battery_V)
{
    if (do_pos) {
        predict_period(pl, s, self_id, now_ms);
        const float fa[3] = {0.0f, 0.0f, pl->cfg.enable ? pl->fa_hat_g * 1e-3f * NS2_PILOT_GRAVITY : 0.0f};
        pl->ctrl.g = pl->gains;
        ns2_ctrl_position(&pl->ctrl, s, sp, fa, 1.0f / (float)NS2_PILOT_POS_HZ);
        for (int a = 0; a < 3; ++a) {
            pl->e[a] = s->p[a] - sp->p[a];
        }
    }
    if (pl->cfg.fixed) {
        (void)ns2_job_step_q15(&pl->job, pl->cfg.phi_per_tick);
    } else {
        (void)ns2_job_step_f32(&pl->job, pl->cfg.phi_per_tick);
    }
    ns2_ctrl_attitude(&pl->ctrl, s, 1.0f / (float)NS2_PILOT_ATT_HZ, battery_V);
}
