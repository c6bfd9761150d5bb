/*
 * ctrl_authors.h - host-only: the position law of the controller that flew the
 * paper's real flights of 16 June 2020, for the simulator's replay of them
 * (ns2paper.replay, paper/replay.py), flown by the simulator's kernel as a robot's
 * position law (host/ns2_fly.h NS2_FLY_LAW; ns2paper.controller compiles this file in).  That controller is controller_sjc.c of the authors'
 * crazyflie-firmware fork (Morgan, Subramanian, Chung, Hadaegh, IJRR 2016, sect. 7);
 * written here from its equation, not copied:
 *   e = p_d - p,  I = clamp(I + e dt, +-i_max)             (per axis)
 *   f_d = m (a_d + g e3 + Kp e + Kd (v_d - v) + Ki I) - k_fa f_a  (N, world frame)
 * with m the firmware's mass parameter (ctrlSJC.mass), f_a the learned force and
 * k_fa = 1 as written.
 * f_d then goes to ns2_ctrl_force: the attitude loop, delay compensation and
 * mixing stay the project's (the collective thrust is f_d . R e3 where the
 * authors' is |f_d|; the two differ by under 1 % below 8 degrees of tilt).
 * Gains: the authors' crazyflieTypes.yaml (paper/gains.py authors_gains).
 * Safety as ns2_controller: a non-finite integral is reset, a bad f_d turns the
 * motors off (ns2_ctrl_force).
 */
#ifndef CTRL_AUTHORS_H
#define CTRL_AUTHORS_H

#include "ns2_controller.h"
#include "ns2_pilot.h"

typedef struct {
    float mass_kg;          /* ctrlSJC.mass */
    float kp[3];            /* 1/s^2, ctrlSJC.Kpos_P */
    float kd[3];            /* 1/s, ctrlSJC.Kpos_D */
    float ki[3];            /* 1/s^3, ctrlSJC.Kpos_I */
    float i_max;            /* m s, ctrlSJC.Kpos_I_limit */
    float k_fa;             /* share of the learned force taken off: 1 the law as written; the
                               law read off the real logs takes off less (paper/gains.py READ_LAW) */
} ns2_authors_gains_t;

typedef struct {
    ns2_authors_gains_t g;
    float i_e[3];           /* integral of p_d - p, m s */
    uint32_t fa_given;      /* 1 = fly fa_given_g instead of the network's f_a,z-hat */
    float fa_given_g;       /* a prediction given from outside (a real flight's logged ctrlFa.Faz), g */
} ns2_authors_t;

void ns2_authors_init(ns2_authors_t *a, const ns2_authors_gains_t *g);
/* 100 Hz: f_d from the law above, then ns2_ctrl_force(c, s, sp, f_d, dt); fa_z_N: f_a,z. */
void ns2_authors_position(ns2_authors_t *a, ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                          float fa_z_N, float dt);
/* The law as the simulator's kernel flies it (an ns2_fly_law_fn, host/ns2_fly.h; ctx an
 * ns2_authors_t): the given prediction, else the pilot's when its learned term is on,
 * else 0, through ns2_authors_position. */
void ns2_authors_law(void *ctx, ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, float dt);

#endif /* CTRL_AUTHORS_H */
