/* ns2_fly.h - host-only: simulated Crazyflies at 1 kHz with the firmware's
 * sensing chain, EKF and controllers (see ns2_fly.c). */
#ifndef NS2_FLY_H
#define NS2_FLY_H

#include <stdint.h>

#include "axis3fSubSampler.h"
#include "controller_mellinger.h"
#include "filter.h"
#include "kalman_core.h"
#include "stabilizer_types.h"

#include "ns2_pilot.h"

#define NS2_FLY_MAX_ROBOTS 32u
#define NS2_FLY_MAX_PEERS 10u /* PEER_LOCALIZATION_MAX_NEIGHBORS */
#define NS2_FLY_PILOT 0u      /* the app's code path, ns2_pilot */
#define NS2_FLY_MELLINGER 1u  /* the firmware's controller_mellinger.c */
#define NS2_FLY_LAW 2u        /* ns2_pilot with a position law of its own (ns2_fly_law_fn) */

/* A position law flown in ns2_pilot's place at 100 Hz (NS2_FLY_LAW): after the pilot's
 * prediction of the period (pl->fa_hat_g; pl->cfg.enable: whether the learned term is on),
 * it sets the pilot's controller's desired force (ns2_ctrl_force on &pl->ctrl); the pilot's
 * attitude loop and mixing stay.  ctx: the law's own state (the caller's memory, alive
 * while the robot flies); dt: its period, s.  The host compiles a law's C into this
 * library when a robot flies it (host/cfhost.py load_fly, FlyLaw). */
typedef void (*ns2_fly_law_fn)(void *ctx, ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                               float dt);

typedef struct {
    uint32_t kind;             /* NS2_FLY_PILOT, NS2_FLY_MELLINGER or NS2_FLY_LAW */
    uint8_t id, type;          /* radio id (not 0: the firmware's peer table takes id 0 for a free
                                * slot), robot type (its own; its peers' come from type_table) */
    double par[21];            /* ns2_sim.c parameters: m, J, lambda, B0 */
    double psi1[5];            /* PWM -> force (g), Table cfprops */
    float p0[3];               /* start position (kalman.initialX/Y/Z) */
    float bias_acc_g[3], bias_gyro_dps[3];
    float acc_scale;           /* the firmware's accScale (|acc| at rest, in g, found at start-up) */
    float sd_acc_g, sd_gyro_dps; /* white noise per 1 kHz sample */
    float ext_pos_std_m;       /* EKF's mocap std dev (locSrv.extPosStdDev) */
    ns2_vehicle_t veh;
    ns2_gains_t gains;
    ns2_pilot_cfg_t pilot_cfg;
    ns2_fly_law_fn law;        /* NS2_FLY_LAW only: the position law and its state */
    void *law_ctx;
    uint32_t pwm_exact;        /* NS2_FLY_LAW: 1 = the motor forces the controller commands turned into PWM by
                                * the exact inverse of psi1_nominal (a firmware that maps forces through
                                * psi_1, e.g. the one that flew the paper's real flights), 0 = by the
                                * controller's own psi_2 */
    double psi1_nominal[5];    /* the type's psi_1 (psi1 above may carry the robot's thrust scatter) */
    uint32_t use_type_table;   /* 1: each peer's robot type is looked up by its radio id in type_table, as
                                * the app does (ns2_type_table_get); 0: its true type (any number of types) */
    uint32_t type_table[NS2_TYPE_TABLE_WORDS]; /* the app's PARAM ns2type.t0..t15 */
    ns2_adapt_cfg_t adapt_cfg; /* the app's PARAM ns2adapt (NS2_FLY_PILOT: label and adaptation in ns2_pilot) */
} ns2_fly_init_t;

typedef struct {
    uint32_t kind;
    uint8_t id, type;
    double par[21];
    double psi1[5];
    float bias_acc_g[3], bias_gyro_dps[3];
    float acc_scale, sd_acc_g, sd_gyro_dps, ext_pos_std_m;
    kalmanCoreData_t kc;
    Axis3fSubSampler_t acc_ss, gyro_ss;
    lpf2pData gyro_lpf[3], acc_lpf[3];
    Axis3f acc_latest;
    uint32_t next_predict_ms;
    state_t est;               /* the estimate every controller sees */
    sensorData_t sensors;      /* filtered IMU of the last tick */
    ns2_pilot_t pilot;
    ns2_fly_law_fn law;        /* ns2_fly_init_t's (NS2_FLY_LAW) */
    void *law_ctx;
    controllerMellinger_t mel;
    control_t control;
    float supply_V;
    float pwm[4];              /* motor commands in [0, 1] */
    uint32_t pwm_exact;        /* ns2_fly_init_t's */
    double psi1_nominal[5];
    uint32_t n_peers;          /* peer-localization table */
    uint8_t peer_id[NS2_FLY_MAX_PEERS], peer_type[NS2_FLY_MAX_PEERS];
    uint32_t peer_t[NS2_FLY_MAX_PEERS];
    float peer_p[NS2_FLY_MAX_PEERS][3];
    uint32_t use_type_table;   /* ns2_fly_init_t's */
    uint32_t type_table[NS2_TYPE_TABLE_WORDS];
} ns2_fly_robot_t;

/* One mocap broadcast frame: noisy positions [n][3] of all robots, received by robot i when rx[i]. */
typedef struct {
    uint32_t tick;
    const float *p;
    const uint8_t *rx;
} ns2_fly_frame_t;

/* The inputs of one ns2_pilot_tick of the traced robot, its peer updates and outputs. */
typedef struct {
    ns2_ctrl_state_t s;
    ns2_setpoint_t sp;
    uint32_t do_pos, now_ms;
    float battery_V;
    uint32_t n_peers;
    uint8_t peer_id[NS2_FLY_MAX_PEERS], peer_type[NS2_FLY_MAX_PEERS];
    uint32_t peer_t[NS2_FLY_MAX_PEERS];
    float peer_p[NS2_FLY_MAX_PEERS][3];
    float pwm[4];
    float fa_hat_g;
    uint16_t n_used;           /* the prediction's neighbours used (the adaptation's wake flag) */
    float fa_used_g;           /* the network's f_a,z with the adapted term (ns2_pilot's fa_used_g) */
    float label_g;             /* the on-board label of this tick (ns2_label_t label_g) */
    float theta[2];            /* the adaptation's bias (g) and scale after this tick */
} ns2_fly_trace_t;

void ns2_fly_init(ns2_fly_robot_t *r, const ns2_fly_init_t *in);
/* ticks 1 kHz ticks from ms0 for n robots; x [n][17] true states (advanced in place),
 * f_a [n][3] world and tau_a [n][3] body (NULL: none) held, noise [ticks][n][6] standard
 * normal (gyro, acc), sp [n], frame NULL or one broadcast delivered at frame->tick,
 * battery_V [n] each robot's supply voltage (V).
 * Returns the trace records written. */
uint32_t ns2_fly_run(ns2_fly_robot_t *rob, uint32_t n, double *x, const double *f_a, const double *tau_a,
                     uint32_t ms0, uint32_t ticks,
                     const float *noise, const ns2_setpoint_t *sp, const ns2_fly_frame_t *frame, const float *battery_V,
                     ns2_fly_trace_t *tr, uint32_t tr_robot, uint32_t tr_max);
/* p, v, q, w (ns2_ctrl_state_t layout) the controllers see now. */
void ns2_fly_estimate(const ns2_fly_robot_t *r, float out[13]);

/* src/drivers/src/motors.c (extracted by host/cfhost.py, compiled with the stock
 * configuration: battery compensation on, as a Crazyflie flying Mellinger has it) */
float motorsCompensateBatteryVoltage(uint32_t id, float iThrust, float supplyVoltage);

#endif /* NS2_FLY_H */
