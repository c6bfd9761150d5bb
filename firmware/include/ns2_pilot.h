/*
 * ns2_pilot.h - what the Crazyflie app does per stabilizer tick, as a library:
 * the one code path of the drone (firmware/app/src/ns2_app.c) and of the
 * simulator (host/ns2_fly.c).  No firmware headers, no dynamic memory.
 *
 * Per 500 Hz tick (ns2_pilot_tick, the simulator's call; the app calls
 * ns2_pilot_step every 1 ms, which spreads the same work and gives the same motor
 * commands):
 *  - at each 100 Hz position tick: finish the running prediction (rho) into
 *    fa_hat (limited to +-fa_limit_g), take the neighbour list from the peer
 *    table (ns2_peers: positions recorded with ns2_pilot_peer, velocities by
 *    finite differences), begin the next prediction (ns2_job_begin) from the
 *    current state, then ns2_ctrl_position with f_a = [0, 0, fa_hat] (zero when
 *    enable = 0: the paper's baseline) and the gains in pl->gains;
 *  - every tick: one slice of phi_per_tick phi evaluations (ns2_job_step_*),
 *    then ns2_ctrl_attitude (delay compensation, mixing, psi_2 PWM).
 * So the learned force used at a position tick was begun one period (10 ms)
 * earlier, from the state and neighbours of then: the on-board latency.
 * With wake memory (NS2_HISTORY_LAGS > 0) every position tick is also a history
 * tick of the peer table (ns2_peers_record before the neighbour list: lags in
 * 10 ms ticks) and the prediction begins with the own past (ns2_job_begin_hist).
 *
 * On-board adaptation (ns2_label.h, ns2_adapt.h, docs/adaptation.md): at every
 * position tick, before the position loop, the robot's own label f_a,z of two
 * ticks back is computed from the state, the motor PWM of the last attitude tick
 * and the battery voltage of the last attitude tick, and ns2_adapt_step_track turns
 * the network's fa_hat_g into fa_used_g = NN + theta^T [1, NN] (where |NN| > wake_g,
 * and with gate_neighbours = 1 also with a robot neighbour used by the prediction,
 * it never learns); with adapt_cfg.track_gain > 0 it is given the controller's
 * composite tracking error in z times the position period, (v_z - v_z,d + Lp_z
 * (z - z_d)) h, from this tick's state and setpoint.  adapt_cfg.enable = 0
 * (the default) gives fa_used_g = fa_hat_g bit for bit: the paper's controller.
 * The label needs psi_1 of the vehicle (ns2_pilot_set_psi1; NS2_PSI1_INIT of the
 * generated ns2_vehicles.h); a reset (on the ground) restarts label and adaptation.
 */
#ifndef NS2_PILOT_H
#define NS2_PILOT_H

#include <stdint.h>

#include "ns2_adapt.h"
#include "ns2_controller.h"
#include "ns2_deepset.h"
#include "ns2_label.h"
#include "ns2_peers.h"

#ifdef __cplusplus
extern "C" {
#endif

#define NS2_PILOT_POS_HZ 100u /* position loop and prediction period */
#define NS2_PILOT_ATT_HZ 500u /* attitude loop and prediction slices */
#define NS2_PILOT_STEP_HZ 1000u /* ns2_pilot_step: the stabilizer loop (RATE_MAIN_LOOP) */
#define NS2_PILOT_LABEL_MIN_Z_M 0.1f   /* below: the label's NS2_LABEL_GROUND (never learned from) */
#define NS2_PILOT_LABEL_MIN_R33 0.866f /* tilt beyond 30 degrees: NS2_LABEL_TILTED */

/* Inference paths compiled in (the app's NS2_INFER: ns2_app_config.h); with both,
 * cfg.fixed picks one at run time. */
#ifndef NS2_PILOT_Q15
#define NS2_PILOT_Q15 1
#endif
#ifndef NS2_PILOT_F32
#define NS2_PILOT_F32 1
#endif

typedef struct {
    uint8_t enable;       /* 1: learned feed-forward; 0: baseline (f_a = 0) */
    uint8_t fixed;        /* 1: fixed-point inference, 0: float */
    uint8_t self_type;    /* robot type of this robot (NS2_TYPE_*) */
    uint8_t phi_per_tick; /* phi evaluations per 500 Hz tick */
    uint16_t max_age_ms;  /* peers older than this are left out */
    float fa_limit_g;     /* |f_a,z| limit, g; not a finite number >= 0 (NaN, < 0, Inf): fa_hat 0 */
} ns2_pilot_cfg_t;

typedef struct {
    ns2_pilot_cfg_t cfg;
    ns2_gains_t gains;    /* copied into ctrl at every position tick */
    ns2_ctrl_t ctrl;      /* ctrl.pwm: the motor commands of the last tick */
    ns2_peers_t peers;
    ns2_job_t job;
    uint8_t job_begun;
    float fa_hat_g;       /* learned f_a,z in use, g */
    int32_t status;       /* ns2_info_t status of the last finished prediction */
    uint16_t n_used;      /* neighbours it used */
    float e[3];           /* position error p - p_d at the last position tick, m */
    ns2_neighbor_t nbrs[NS2_PEERS_MAX];
    uint16_t nbrs_n;      /* neighbours listed by ns2_pilot_select for the next begin */
    uint8_t nbrs_listed;  /* 1: listed at a position tick, ns2_pilot_start not yet run */
    float listed_p[3];    /* the own position (m) and velocity (m/s) of that tick */
    float listed_v[3];
    ns2_adapt_cfg_t adapt_cfg; /* the adaptation's parameters (enable = 0 by default) */
    ns2_label_t label;    /* the on-board label of two position ticks back */
    ns2_adapt_t adapt;
    float psi1[5];        /* the vehicle's psi_1 for the label (ns2_pilot_set_psi1) */
    float battery_V;      /* of the last attitude tick */
    float fa_used_g;      /* f_a,z given to the position loop, g (fa_hat_g adapted) */
} ns2_pilot_t;

/* Defaults of the app's PARAM group ns2 (enable, fixed, type, 4 phi per tick, 100 ms, 20 g). */
void ns2_pilot_default_cfg(ns2_pilot_cfg_t *cfg, uint8_t self_type);
/* Peer table emptied (velocity filter weight 0.5), gains set, controller reset. */
void ns2_pilot_init(ns2_pilot_t *pl, const ns2_pilot_cfg_t *cfg, const ns2_vehicle_t *veh, const ns2_gains_t *g);
/* Controller state (integrators, filters) and the running prediction reset, as on the ground. */
void ns2_pilot_reset(ns2_pilot_t *pl, const ns2_vehicle_t *veh);
/* psi_1 of the vehicle for the on-board label (kept over resets; the label restarts). */
void ns2_pilot_set_psi1(ns2_pilot_t *pl, const float psi1[5]);
/* A position of robot `id` (robot type `type`) received at t_ms: ns2_peers_update. */
int32_t ns2_pilot_peer(ns2_pilot_t *pl, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3]);
/* The parts of a tick:
 * finish: the running prediction (its phi left, rho) into fa_hat_g; begin: the
 * next one from the peer table and the state, in two parts: select (the history
 * tick, ns2_peers_record, and the neighbour list from the peer table and the state,
 * kept with that state in pl) then start (the own past and ns2_job_begin*: each
 * input checked and clamped into the job; nothing if nothing is listed or after a
 * reset); period: finish, then begin (100 Hz);
 * position: the label and adaptation step, then ns2_ctrl_position with
 * f_a = [0, 0, fa_used_g] (100 Hz, after period);
 * slice: phi_per_tick phi evaluations; attitude: ns2_ctrl_attitude (500 Hz). */
void ns2_pilot_finish(ns2_pilot_t *pl);
void ns2_pilot_begin(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, uint8_t self_id, uint32_t now_ms);
void ns2_pilot_select(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, uint8_t self_id, uint32_t now_ms);
void ns2_pilot_start(ns2_pilot_t *pl);
void ns2_pilot_period(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, uint8_t self_id, uint32_t now_ms);
void ns2_pilot_position(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp);
void ns2_pilot_slice(ns2_pilot_t *pl);
void ns2_pilot_attitude(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, float battery_V);
/* One 500 Hz tick: with do_pos (the 100 Hz position tick) period and position
 * first, then slice and attitude; self_id: own radio id (left out of the
 * neighbours); now_ms: the clock of the peer table. */
void ns2_pilot_tick(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, int do_pos,
                    uint8_t self_id, uint32_t now_ms, float battery_V);
/* One 1 kHz stabilizer tick (the app's schedule): the same motor commands as
 * ns2_pilot_tick at the even ticks, with the work spread so that no 1 ms step
 * carries more than two phi evaluations (phi_per_tick = 4), rho, or the neighbour
 * list and the position loop: k = tick % 10 = 0 select + position, 1 start and half
 * a slice less one phi, 2..8 half a slice each, 9 finish; attitude at even k.  The
 * start reads only what select kept (the neighbours' state of k = 0, copied), so
 * the peers received at k = 1 do not change the prediction.  Whatever the phase of the firmware's Kalman
 * prediction and measurement updates, the app's share of any millisecond stays
 * small (docs/app.md, "The 1 ms stabilizer iteration"). */
void ns2_pilot_step(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, uint32_t tick,
                    uint8_t self_id, uint32_t now_ms, float battery_V);

#ifdef __cplusplus
}
#endif

#endif /* NS2_PILOT_H */
