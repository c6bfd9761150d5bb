/*
 * ns2_fly.c - host-only: n simulated Crazyflies at the stabilizer's 1 kHz, each
 * with what the real one has between its sensors and its motors (see
 * docs/sensing.md for every figure and its source):
 *   IMU    true body rates and specific force + bias + white noise, quantized to
 *          the BMI088 LSBs the firmware configures, filtered by the firmware's own
 *          lpf2p (filter.c) at the cut-offs of sensors_bmi088_bmp3xx.c;
 *   EKF    the firmware's kalman_core (kalman_core.c, mm_position.c,
 *          axis3fSubSampler.c, compiled from crazyflie-firmware) driven as
 *          estimator_kalman.c's task does: IMU subsampled, predict at 100 Hz,
 *          process noise every tick, mocap position updates as they arrive
 *          (std dev locSrv.extPosStdDev), finalize, externalize; the stabilizer
 *          reads the state of the previous task run;
 *   peers  the same mocap broadcast fills a per-robot peer-localization table
 *          (timestamp: reception tick, as peer_localization.c), each peer's robot
 *          type its true one or, as the app has it, looked up by its radio id in the
 *          robot's type table (PARAM ns2type.t0..t15, ns2_type_table_get: ns2 fly --sim);
 *   control  either ns2_pilot (firmware/src, the app's code path) at 500/100 Hz,
 *          or ns2_pilot with a position law of its own (NS2_FLY_LAW: a law's C
 *          compiled in by the host, e.g. the controller that flew the paper's real
 *          flights, paper/c/ctrl_authors.c),
 *          or the firmware's controller_mellinger.c + power_distribution_quadrotor.c
 *          + motorsCompensateBatteryVoltage (stabilizer.c's order; the stock
 *          configuration's battery compensation, host/cfhost.py);
 *   plant  PWM -> motor force through psi_1, RK4 of eq. (dynamics) (ns2_sim.c).
 * The true state x stays here and in Python; the controllers see only the EKF
 * state and the filtered gyro.  ns2_fly_run runs, every tick and robot, one function
 * per firmware task in the firmware's order: sensors_task, controller_task (the one
 * dispatch on the robot's kind), estimator_task, peers_task, motors_task; then
 * integration_task advances every robot's true state.
 */
#include "ns2_fly.h"

#include <math.h>
#include <string.h>

#include "mm_position.h"
#include "power_distribution.h"
#include "physicalConstants.h"

#include "ns2_vehicles.h"

#define FLY_X 17   /* ns2_sim.c state per robot */
#define FLY_PAR 21
#define GYRO_LPF_HZ 80.0f   /* sensors_bmi088_bmp3xx.c GYRO_LPF_CUTOFF_FREQ */
#define ACCEL_LPF_HZ 30.0f  /* ... ACCEL_LPF_CUTOFF_FREQ */
#define DEG_PER_LSB ((2.0f * 2000.0f) / 65536.0f) /* SENSORS_BMI088_DEG_PER_LSB_CFG */
#define G_PER_LSB ((2.0f * 24.0f) / 65536.0f)     /* SENSORS_BMI088_G_PER_LSB_CFG */
#define PREDICT_MS 10u      /* estimator_kalman.c PREDICT_RATE = RATE_100_HZ */
#define G_SIM NS2_G_MPS2 /* m/s^2, ns2_controller.h */

void ns2_sim_rk4(uint32_t n, double *x, const double *par, const double *u_c, const double *f_a,
                 const double *tau_a, double dt);

static const float psi1_app[NS2_NUM_ROBOT_TYPES][5] = NS2_PSI1_INIT; /* the app's psi_1 per type */

static kalmanCoreParams_t kparams; /* kalmanCoreDefaultParams, shared (read-only after init) */

void assertFail(char *exp, char *file, int line)
{
    (void)exp;
    (void)file;
    (void)line; /* kalman_core's ASSERTs: nothing to halt on the host */
}

void ns2_fly_init(ns2_fly_robot_t *r, const ns2_fly_init_t *in)
{
    memset(r, 0, sizeof(*r));
    r->kind = in->kind;
    r->id = in->id;
    r->type = in->type;
    memcpy(r->par, in->par, sizeof(r->par));
    memcpy(r->psi1, in->psi1, sizeof(r->psi1));
    r->pwm_exact = in->kind == NS2_FLY_LAW && in->pwm_exact;
    r->law = in->kind == NS2_FLY_LAW ? in->law : NULL;
    r->law_ctx = in->law_ctx;
    memcpy(r->psi1_nominal, in->psi1_nominal, sizeof(r->psi1_nominal));
    r->use_type_table = in->use_type_table != 0u;
    memcpy(r->type_table, in->type_table, sizeof(r->type_table));
    memcpy(r->bias_acc_g, in->bias_acc_g, sizeof(r->bias_acc_g));
    memcpy(r->bias_gyro_dps, in->bias_gyro_dps, sizeof(r->bias_gyro_dps));
    r->acc_scale = in->acc_scale > 0.5f ? in->acc_scale : 1.0f;
    r->sd_acc_g = in->sd_acc_g;
    r->sd_gyro_dps = in->sd_gyro_dps;
    r->ext_pos_std_m = in->ext_pos_std_m;
    kalmanCoreDefaultParams(&kparams);
    kalmanCoreParams_t p = kparams;
    p.initialX = in->p0[0]; /* PARAM kalman.initialX/Y/Z, as set before take-off */
    p.initialY = in->p0[1];
    p.initialZ = in->p0[2];
    kalmanCoreInit(&r->kc, &p, 0u);
    axis3fSubSamplerInit(&r->acc_ss, GRAVITY_MAGNITUDE);
    axis3fSubSamplerInit(&r->gyro_ss, DEG_TO_RAD);
    for (int a = 0; a < 3; ++a) {
        lpf2pInit(&r->gyro_lpf[a], 1000.0f, GYRO_LPF_HZ);
        lpf2pInit(&r->acc_lpf[a], 1000.0f, ACCEL_LPF_HZ);
    }
    r->acc_latest.z = 1.0f;
    kalmanCoreExternalizeState(&r->kc, &r->est, &r->acc_latest);
    r->next_predict_ms = 0u;
    ns2_pilot_init(&r->pilot, &in->pilot_cfg, &in->veh, &in->gains);
    /* as ns2_app.c controllerOutOfTreeInit: PARAM ns2adapt, reset, the type's psi_1 for the label */
    r->pilot.adapt_cfg = in->adapt_cfg;
    ns2_pilot_reset(&r->pilot, &in->veh);
    ns2_pilot_set_psi1(&r->pilot, psi1_app[in->type < NS2_NUM_ROBOT_TYPES ? in->type : 0u]);
    controllerMellingerInit(&r->mel);
    r->mel.mass = in->veh.mass_kg; /* PARAM ctrlMel.mass, as a user sets it for the vehicle */
    r->supply_V = 4.2f;           /* stabilizer.c batteryCompensation's filter state */
}

/* Specific force (g) and body rates (deg/s) of robot r's true state: the IMU's input. */
static void imu_truth(const double *x, const double *par, const double *f_a, float acc_g[3], float gyro_dps[3])
{
    const double qw = x[6], qx = x[7], qy = x[8], qz = x[9];
    const double m = par[0];
    const double T = x[13] + x[14] + x[15] + x[16]; /* B0 row 0: collective thrust */
    /* R^T f_a (body frame) */
    const double R[3][3] = {
        {1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)},
        {2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)},
        {2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)}};
    for (int a = 0; a < 3; ++a) {
        const double fb = R[0][a] * f_a[0] + R[1][a] * f_a[1] + R[2][a] * f_a[2];
        acc_g[a] = (float)(((a == 2 ? T : 0.0) + fb) / m / G_SIM);
        gyro_dps[a] = (float)(x[10 + a] * 180.0 / M_PI);
    }
}

static float quantize(float v, float lsb)
{
    return lsb * roundf(v / lsb);
}

static void to_ctrl_state(const state_t *st, const sensorData_t *se, ns2_ctrl_state_t *s)
{
    /* as ns2_app.c to_ctrl_state */
    s->p[0] = st->position.x;
    s->p[1] = st->position.y;
    s->p[2] = st->position.z;
    s->v[0] = st->velocity.x;
    s->v[1] = st->velocity.y;
    s->v[2] = st->velocity.z;
    s->q[0] = st->attitudeQuaternion.w;
    s->q[1] = st->attitudeQuaternion.x;
    s->q[2] = st->attitudeQuaternion.y;
    s->q[3] = st->attitudeQuaternion.z;
    s->w[0] = se->gyro.x * 0.017453292519943295f;
    s->w[1] = se->gyro.y * 0.017453292519943295f;
    s->w[2] = se->gyro.z * 0.017453292519943295f;
}

static void mellinger_tick(ns2_fly_robot_t *r, const ns2_setpoint_t *sp, uint32_t tick, float battery_V)
{
    setpoint_t s;
    memset(&s, 0, sizeof(s));
    s.mode.x = s.mode.y = s.mode.z = modeAbs;
    s.mode.yaw = modeAbs;
    s.position.x = sp->p[0];
    s.position.y = sp->p[1];
    s.position.z = sp->p[2];
    s.velocity.x = sp->v[0];
    s.velocity.y = sp->v[1];
    s.velocity.z = sp->v[2];
    s.acceleration.x = sp->a[0];
    s.acceleration.y = sp->a[1];
    s.acceleration.z = sp->a[2];
    s.attitude.yaw = sp->yaw * 57.29577951308232f;
    /* the controller updates r->control at ATTITUDE_RATE; the motors get it every tick */
    controllerMellinger(&r->mel, &r->control, &s, &r->sensors, &r->est, tick);
    /* stabilizer.c controlMotors: powerDistribution, batteryCompensation, powerDistributionCap */
    motors_thrust_uncapped_t unc, comp;
    motors_thrust_pwm_t pwm;
    powerDistribution(&r->control, &unc);
    r->supply_V = r->supply_V + 0.01f * (battery_V - r->supply_V);
    for (int m = 0; m < 4; ++m) {
        comp.list[m] = (int32_t)motorsCompensateBatteryVoltage((uint32_t)m, (float)unc.list[m], r->supply_V);
    }
    (void)powerDistributionCap(&comp, &pwm);
    for (int m = 0; m < 4; ++m) {
        r->pwm[m] = (float)pwm.list[m] / 65535.0f;
    }
}

/* PWM in [0, 1] whose force through psi_1 k (grams, in PWM and V / 4.2) is u_N: the root of
 * k3 p^2 + (k1 + k4 v) p + k0 + k2 v - f = 0 on the map's rising branch (its vertex when f is
 * below the map's least force), 0 for u_N <= 0. */
static float pwm_psi1_inverse(const double k[5], float u_N, float battery_V)
{
    if (!(u_N > 0.0f)) {
        return 0.0f;
    }
    const double f = (double)u_N * 1000.0 / G_SIM;
    const double v = (double)battery_V / 4.2;
    const double a = k[3], b = k[1] + k[4] * v, c = k[0] + k[2] * v - f;
    double p;
    if (fabs(a) < 1e-12) {
        p = fabs(b) > 1e-12 ? -c / b : 0.0;
    } else {
        const double disc = b * b - 4.0 * a * c;
        p = (-b + (a > 0.0 ? 1.0 : -1.0) * sqrt(disc > 0.0 ? disc : 0.0)) / (2.0 * a);
    }
    if (!(p > 0.0)) {
        return 0.0f;
    }
    return p < 1.0 ? (float)p : 1.0f;
}

/* The inputs and outputs of one 500 Hz run of the app's path, and the peer updates it read. */
static void trace(ns2_fly_trace_t *t, const ns2_fly_robot_t *r, const ns2_ctrl_state_t *s,
                  const ns2_setpoint_t *sp, int do_pos, uint32_t now_ms, float battery_V)
{
    t->s = *s;
    t->sp = *sp;
    t->do_pos = (uint32_t)do_pos;
    t->now_ms = now_ms;
    t->battery_V = battery_V;
    memcpy(t->pwm, r->pwm, sizeof(t->pwm));
    t->fa_hat_g = r->pilot.fa_hat_g;
    t->n_used = r->pilot.n_used;
    t->fa_used_g = r->pilot.fa_used_g;
    t->label_g = r->pilot.label.label_g;
    t->theta[0] = r->pilot.adapt.theta[0];
    t->theta[1] = r->pilot.adapt.theta[1];
    t->n_peers = do_pos ? r->n_peers : 0u;
    for (uint32_t j = 0; j < t->n_peers; ++j) {
        t->peer_id[j] = r->peer_id[j];
        t->peer_type[j] = r->peer_type[j];
        t->peer_t[j] = r->peer_t[j];
        memcpy(t->peer_p[j], r->peer_p[j], sizeof(t->peer_p[j]));
    }
}

/* sensorsTask: one IMU sample of the true state xi under f_a (world), noise nz [6] standard
 * normal (gyro, acc): bias, white noise, the BMI088's LSBs, the firmware's lpf2p. */
static void sensors_task(ns2_fly_robot_t *r, const double *xi, const double *f_a, const float *nz)
{
    float acc[3], gyro[3];
    imu_truth(xi, r->par, f_a, acc, gyro);
    float gf[3], af[3];
    for (int a = 0; a < 3; ++a) {
        gf[a] = lpf2pApply(&r->gyro_lpf[a],
                           quantize(gyro[a] + r->bias_gyro_dps[a] + r->sd_gyro_dps * nz[a], DEG_PER_LSB));
        af[a] = lpf2pApply(&r->acc_lpf[a],
                           quantize(acc[a] + r->bias_acc_g[a] + r->sd_acc_g * nz[3 + a], G_PER_LSB) / r->acc_scale);
    }
    r->sensors.gyro.x = gf[0];
    r->sensors.gyro.y = gf[1];
    r->sensors.gyro.z = gf[2];
    r->sensors.acc.x = af[0];
    r->sensors.acc.y = af[1];
    r->sensors.acc.z = af[2];
}

/* ns2_pilot_tick with the robot's position law (NS2_FLY_LAW): the pilot's prediction, then
 * the law at 100 Hz (no law: the controller keeps its last force), the pilot's attitude
 * loop at 500 Hz. */
static void law_tick(ns2_fly_robot_t *r, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, int do_pos,
                     uint32_t tick, float battery_V)
{
    if (do_pos) {
        ns2_pilot_period(&r->pilot, s, r->id, tick);
        if (r->law != NULL) {
            r->law(r->law_ctx, &r->pilot, s, sp, 1.0f / (float)NS2_PILOT_POS_HZ);
        }
    }
    ns2_pilot_slice(&r->pilot);
    ns2_pilot_attitude(&r->pilot, s, battery_V);
}

/* The app's path at 500/100 Hz (NS2_FLY_PILOT, NS2_FLY_LAW): the peer table at 100 Hz,
 * the position law of the robot's kind, psi_2 PWM (or the exact psi_1 inverse); writes one trace record to t
 * (NULL: none) when it runs.  Returns 1 when it wrote one. */
static uint32_t pilot_controller(ns2_fly_robot_t *r, const ns2_setpoint_t *sp, uint32_t tick, float battery_V,
                                 ns2_fly_trace_t *t)
{
    if (!RATE_DO_EXECUTE(RATE_500_HZ, tick)) {
        return 0u;
    }
    ns2_ctrl_state_t s;
    to_ctrl_state(&r->est, &r->sensors, &s);
    const int do_pos = RATE_DO_EXECUTE(RATE_100_HZ, tick);
    if (do_pos) { /* ns2_app.c predict_period: the peer-localization table */
        for (uint32_t j = 0; j < r->n_peers; ++j) {
            (void)ns2_pilot_peer(&r->pilot, r->peer_id[j], r->peer_type[j], r->peer_t[j], r->peer_p[j]);
        }
    }
    if (r->kind == NS2_FLY_LAW) {
        law_tick(r, &s, sp, do_pos, tick, battery_V);
    } else {
        ns2_pilot_tick(&r->pilot, &s, sp, do_pos, r->id, tick, battery_V);
    }
    memcpy(r->pwm, r->pilot.ctrl.pwm, sizeof(r->pwm));
    if (r->pwm_exact) { /* the motor forces commanded, realized through psi_1 */
        for (int m = 0; m < 4; ++m) {
            r->pwm[m] = r->pilot.ctrl.pwm[m] > 0.0f ? pwm_psi1_inverse(r->psi1_nominal, r->pilot.ctrl.u[m], battery_V)
                                                    : 0.0f;
        }
    }
    if (t == NULL) {
        return 0u;
    }
    trace(t, r, &s, sp, do_pos, tick, battery_V);
    return 1u;
}

/* stabilizer: the controller of the robot's kind on the state of the last estimator run
 * (the one dispatch of NS2_FLY_PILOT, NS2_FLY_LAW and NS2_FLY_MELLINGER).  Returns the
 * trace records written to t (NULL: none). */
static uint32_t controller_task(ns2_fly_robot_t *r, const ns2_setpoint_t *sp, uint32_t tick, float battery_V,
                                ns2_fly_trace_t *t)
{
    if (r->kind == NS2_FLY_MELLINGER) {
        mellinger_tick(r, sp, tick, battery_V);
        return 0u;
    }
    return pilot_controller(r, sp, tick, battery_V, t); /* NS2_FLY_LAW, else NS2_FLY_PILOT */
}

/* kalmanTask (estimator_kalman.c), after the stabilizer in the same tick: the IMU
 * subsampled, predict at 100 Hz, process noise every tick, the mocap position of a frame
 * robot i receives (rx[i]) this tick, finalize, externalize. */
static void estimator_task(ns2_fly_robot_t *r, uint32_t i, uint32_t tick, const ns2_fly_frame_t *frame)
{
    axis3fSubSamplerAccumulate(&r->gyro_ss, &r->sensors.gyro);
    axis3fSubSamplerAccumulate(&r->acc_ss, &r->sensors.acc);
    r->acc_latest = r->sensors.acc;
    if (tick >= r->next_predict_ms) {
        axis3fSubSamplerFinalize(&r->acc_ss);
        axis3fSubSamplerFinalize(&r->gyro_ss);
        kalmanCorePredict(&r->kc, &kparams, &r->acc_ss.subSample, &r->gyro_ss.subSample, tick, true);
        r->next_predict_ms = tick + PREDICT_MS;
    }
    kalmanCoreAddProcessNoise(&r->kc, &kparams, tick);
    if (frame != NULL && frame->tick == tick && frame->rx[i]) {
        positionMeasurement_t m;
        memset(&m, 0, sizeof(m));
        m.x = frame->p[3 * i];
        m.y = frame->p[3 * i + 1];
        m.z = frame->p[3 * i + 2];
        m.stdDev = r->ext_pos_std_m;
        kalmanCoreUpdateWithPosition(&r->kc, &m);
    }
    (void)kalmanCoreFinalize(&r->kc);
    kalmanCoreExternalizeState(&r->kc, &r->est, &r->acc_latest);
}

/* peer localization: the other robots' positions of the broadcast robot i receives this
 * tick (timestamp: the reception tick, as peer_localization.c), each peer's type its true
 * one or looked up by its radio id in the robot's type table. */
static void peers_task(ns2_fly_robot_t *rob, uint32_t n, uint32_t i, uint32_t tick, const ns2_fly_frame_t *frame)
{
    ns2_fly_robot_t *r = &rob[i];
    if (frame == NULL || frame->tick != tick || !frame->rx[i]) {
        return;
    }
    r->n_peers = 0u;
    for (uint32_t j = 0; j < n && r->n_peers < NS2_FLY_MAX_PEERS; ++j) {
        if (j != i) {
            const uint32_t e = r->n_peers++;
            r->peer_id[e] = rob[j].id;
            r->peer_type[e] = r->use_type_table ? ns2_type_table_get(r->type_table, rob[j].id, NS2_NUM_ROBOT_TYPES)
                                                : rob[j].type;
            r->peer_t[e] = tick;
            memcpy(r->peer_p[e], &frame->p[3 * j], sizeof(r->peer_p[e]));
        }
    }
}

/* motors: PWM -> force (N) of each motor through psi_1 (Table cfprops;
 * ns2codegen.data.labels.psi1_newtons) at this supply voltage. */
static void motors_task(const ns2_fly_robot_t *r, float battery_V, double u_c[4])
{
    const double v = (double)battery_V / 4.2;
    for (int m = 0; m < 4; ++m) {
        const double p = (double)r->pwm[m];
        const double *c = r->psi1;
        const double f_g = c[0] + c[1] * p + c[2] * v + c[3] * p * p + c[4] * p * v;
        u_c[m] = p > 0.0 ? (f_g > 0.0 ? f_g : 0.0) * G_SIM / 1000.0 : 0.0;
    }
}

/* integration: one RK4 step (1 ms) of every robot's true state under its motor forces. */
static void integration_task(const ns2_fly_robot_t *rob, uint32_t n, double *x, const double *u_c,
                             const double *f_a, const double *tau_a)
{
    static const double zeros[3 * NS2_FLY_MAX_ROBOTS] = {0.0};
    double par[FLY_PAR * NS2_FLY_MAX_ROBOTS];
    for (uint32_t i = 0; i < n; ++i) {
        memcpy(&par[FLY_PAR * i], rob[i].par, sizeof(rob[i].par));
    }
    ns2_sim_rk4(n, x, par, u_c, f_a, tau_a != NULL ? tau_a : zeros, 1e-3);
}

uint32_t ns2_fly_run(ns2_fly_robot_t *rob, uint32_t n, double *x, const double *f_a, const double *tau_a,
                     uint32_t ms0, uint32_t ticks,
                     const float *noise, const ns2_setpoint_t *sp, const ns2_fly_frame_t *frame, const float *battery_V,
                     ns2_fly_trace_t *tr, uint32_t tr_robot, uint32_t tr_max)
{
    double u_c[4 * NS2_FLY_MAX_ROBOTS];
    uint32_t n_tr = 0u;
    if (n > NS2_FLY_MAX_ROBOTS) {
        return 0u;
    }
    for (uint32_t k = 0; k < ticks; ++k) {
        const uint32_t tick = ms0 + k;
        for (uint32_t i = 0; i < n; ++i) {
            ns2_fly_robot_t *r = &rob[i];
            ns2_fly_trace_t *t = tr != NULL && i == tr_robot && n_tr < tr_max ? &tr[n_tr] : NULL;
            sensors_task(r, &x[FLY_X * i], &f_a[3 * i], &noise[6u * (n * k + i)]);
            n_tr += controller_task(r, &sp[i], tick, battery_V[i], t);
            estimator_task(r, i, tick, frame);
            peers_task(rob, n, i, tick, frame);
            motors_task(r, battery_V[i], &u_c[4 * i]);
        }
        integration_task(rob, n, x, u_c, f_a, tau_a);
    }
    return n_tr;
}

void ns2_fly_estimate(const ns2_fly_robot_t *r, float out[13])
{
    ns2_ctrl_state_t s;
    to_ctrl_state(&r->est, &r->sensors, &s);
    memcpy(out, &s, sizeof(s));
}
