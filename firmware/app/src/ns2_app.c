/*
 * ns2_app.c - Crazyflie app: the Neural-Swarm2 interaction-aware tracking
 * controller (firmware/src/ns2_controller.c) with the learned interaction force
 * f_a,z as feed-forward, as the firmware's out-of-tree controller.
 *
 * Thin glue; all logic is in the tested library (firmware/src), the per-tick part
 * in ns2_pilot (the same code path the simulator flies, host/ns2_fly.c):
 *  - neighbours: positions of the other Crazyflies from the firmware's peer
 *    localization (mocap broadcasts), drained every 1 ms into the app's own table
 *    of up to NS2_PEERS_MAX = 16 robots (the firmware keeps 10 and never frees a
 *    slot; see drain_peers), velocity by finite differences (ns2_peers), robot
 *    types from the type table ns2type.t0..t15 (2 bits for each radio id
 *    0..255, written by the ground side); the environment is always included by
 *    the library;
 *  - prediction spread over the 1 ms stabilizer ticks (ns2_pilot_step, ns2_job_*):
 *    begun at each 100 Hz position tick from the current state and neighbours,
 *    ns2.phiPerTick phi evaluations per 500 Hz tick (half in each millisecond),
 *    finished (rho) in the millisecond before the next position tick, fixed point
 *    or float (ns2.fixed), limited to +-ns2.faLimit grams; no millisecond carries
 *    more than one of these parts, so the app's share of the millisecond in which
 *    the firmware's Kalman filter predicts and fuses mocap stays small whatever
 *    their phase (docs/app.md);
 *  - control: ns2_ctrl_position at 100 Hz with f_a = [0, 0, f_a,z] (zero when
 *    ns2.enable = 0: the paper's baseline), ns2_ctrl_attitude at 500 Hz (delay
 *    compensation, mixing capped as the firmware caps it, PWM from psi_2 and the battery
 *    voltage), motor PWM ratios through controlModeForce.  Build the firmware
 *    without battery compensation of the motor commands
 *    (CONFIG_ENABLE_THRUST_BAT_COMPENSATED unset): psi_2 already uses the voltage.
 *  - no position setpoint (mode.z == modeDisable, e.g. on the ground): motors off,
 *    controller state reset.  Non-finite state or setpoint: the library's safe
 *    outputs (ns2_controller.h).
 * Vehicle parameters and default gains of each robot type come from the
 * generated ns2_vehicles.h; the gains of this robot are in PARAM group ns2gain.
 * Clock synchronization for the logs (paper, "Data Collection"): writing the
 * parameter ns2.sync (broadcast to all drones before take-off) logs the uSD
 * event ns2Sync with the written value as seq; ns2codegen.logs.align aligns the
 * robots' clocks on it.
 * PARAM: ns2 (switches, limits, sync, modelId), ns2type (t0..t15: the robot type of every
 * radio id, ns2_type_table_get), ns2gain, ns2adapt (the on-board adaptation on top of
 * the network: enable (0 by default), forget, p0, pMax, biasMax, scaleMax, faMax,
 * labelMax, wakeG, gateNbr, trackGain, reset; docs/adaptation.md).
 * LOG ns2: faHat (g), inferUs (the app's longest 1 ms step in the last period, us),
 * nUsed, status, ctrlStatus, ex/ey/ez (position error, m).  LOG ns2adapt: bias (g), scale,
 * trP (trace of P), label (the on-board f_a,z of 20 ms ago, g), term (the adapted term
 * in use, g), status (NS2_ADAPT_*), lstatus (NS2_LABEL_*).
 */
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "app.h"
#include "FreeRTOS.h"
#include "task.h"

#define DEBUG_MODULE "NS2"
#include "debug.h"

#include "eventtrigger.h"

#include "configblock.h"
#include "controller.h"
#include "log.h"
#include "param.h"
#include "peer_localization.h"
#include "pm.h"
#include "stabilizer_types.h"
#include "usec_time.h"

#include "ns2_app_config.h"
#include "ns2_controller.h"
#include "ns2_deepset.h"
#include "ns2_peers.h"
#include "ns2_pilot.h"
#include "ns2_vehicles.h"

#if !NS2_HAVE_VEHICLES
#error "ns2_vehicles.h: a robot type lacks rigid-body parameters in the config (see ns2codegen/default.toml)"
#endif
#if NS2_NUM_ROBOT_TYPES > NS2_TYPE_TABLE_MAX_TYPES
#error "the app's type table (ns2type.t0..t15, 2 bits per radio id) names at most 4 robot types"
#endif

#define NS2_DEG2RAD 0.017453292519943295f

static const ns2_vehicle_t vehicles[NS2_NUM_ROBOT_TYPES] = NS2_VEHICLES_INIT;
static const ns2_gains_t default_gains[NS2_NUM_ROBOT_TYPES] = NS2_DEFAULT_GAINS_INIT;
static const float psi1[NS2_NUM_ROBOT_TYPES][5] = NS2_PSI1_INIT;

/* PARAM ns2: switches and limits of ns2_pilot (enable, fixed, self_type,
 * phi_per_tick, max_age_ms, fa_limit_g), copied into the pilot at every tick */
static ns2_pilot_cfg_t cfg = {1, 1, NS2_TYPE_SMALL, 4, 100, 20.0f};

/* PARAM ns2.modelId (read-only): the low 32 bits of the generated headers'
 * NS2_MODEL_ID (the first 60 bits of the model hash), which the ground side
 * compares with the export it is told to fly before anything else */
static uint32_t modelId = (uint32_t)(NS2_MODEL_ID & 0xFFFFFFFFu);

static uint32_t syncSeq;   /* PARAM ns2.sync: a new value logs the event ns2Sync */
static uint32_t syncLogged;
EVENTTRIGGER(ns2Sync, uint32, seq)

/* PARAM ns2type.t0..t15: the robot type of radio id i is bits 2 (i % 16) and up of
 * word i / 16 (ns2_peers.h, ns2_type_table_get); all 0 (the first type) at boot */
static uint32_t typeTable[NS2_TYPE_TABLE_WORDS];

static ns2_gains_t gains;  /* PARAM ns2gain, copied into the controller at 100 Hz */
static uint8_t gainsType = 0xFFu; /* robot type whose default gains were loaded last */
static ns2_pilot_t pilot;  /* the drone's code path: peers, sliced prediction, controller */
static uint8_t ctrlType = 0xFFu; /* robot type the pilot was initialized for */

static float faHat;        /* g */
static uint32_t inferUs;   /* us */
static uint32_t stepUsMax;
static uint8_t nUsed;
static int32_t status;
static uint32_t ctrlStatus;
static float ex, ey, ez;   /* m */

/* PARAM ns2adapt: the on-board adaptation (ns2_adapt.h, docs/adaptation.md), copied
 * into the pilot at every tick; off by default.  ns2adapt.reset = 1 resets theta and
 * P at the next tick (and reads back 0); a take-off resets them too. */
static ns2_adapt_cfg_t adaptCfg = {0, 0, 0.995f, 1.0f, 10.0f, 10.0f, 0.0f, 10.0f, 40.0f, 15.0f, 0.0f};
static uint8_t adaptReset;
/* LOG ns2adapt, at the position tick */
static float adBias, adScale, adTrP, adLabel, adTerm; /* g, 1, -, g, g */
static uint16_t adStatus;  /* NS2_ADAPT_* */
static uint8_t lbStatus;   /* NS2_LABEL_* */

void appMain(void)
{
    DEBUG_PRINT("ns2 model " NS2_MODEL_HASH "\n");
    while (1) {
        vTaskDelay(M2T(2000));
    }
}

static uint8_t self_type(void)
{
    return cfg.self_type < NS2_NUM_ROBOT_TYPES ? cfg.self_type : 0u;
}

/* PARAM ns2.selfType callback (the param task, when the write arrives, before the
 * ground gets its confirmation): a new robot type loads its default gains here and
 * only here, so gains written after it stay (the ground writes selfType first). */
static void self_type_written(void)
{
    if (self_type() != gainsType) {
        gainsType = self_type();
        gains = default_gains[gainsType];
    }
}

/* Reset the controller state (integrators, filters) and the prediction; a new
 * robot type also gets its vehicle parameters (its gains came with the write). */
static void reset_controller(void)
{
    ctrlType = self_type();
    pilot.gains = gains;
    pilot.adapt_cfg = adaptCfg;
    ns2_pilot_reset(&pilot, &vehicles[ctrlType]);
    ns2_pilot_set_psi1(&pilot, psi1[ctrlType]);
    faHat = 0.0f;
}

static void set3(float out[3], float x, float y, float z)
{
    out[0] = x;
    out[1] = y;
    out[2] = z;
}

static void to_ctrl_state(const state_t *state, const sensorData_t *sensors, ns2_ctrl_state_t *s)
{
    const quaternion_t *q = &state->attitudeQuaternion;
    set3(s->p, state->position.x, state->position.y, state->position.z);
    set3(s->v, state->velocity.x, state->velocity.y, state->velocity.z);
    s->q[0] = q->w; /* [w x y z] */
    set3(&s->q[1], q->x, q->y, q->z);
    set3(s->w, sensors->gyro.x * NS2_DEG2RAD, sensors->gyro.y * NS2_DEG2RAD, sensors->gyro.z * NS2_DEG2RAD);
}

static void to_setpoint(const setpoint_t *sp, ns2_setpoint_t *d)
{
    set3(d->p, sp->position.x, sp->position.y, sp->position.z);
    set3(d->v, sp->velocity.x, sp->velocity.y, sp->velocity.z);
    set3(d->a, sp->acceleration.x, sp->acceleration.y, sp->acceleration.z);
    set3(d->w, 0.0f, 0.0f, 0.0f);
    d->yaw = sp->attitude.yaw * NS2_DEG2RAD;
}

/* Drain the firmware's peer localization into the app's table (ns2_peers, up to
 * NS2_PEERS_MAX robots), every stabilizer tick.  The firmware keeps at most
 * PEER_LOCALIZATION_MAX_NEIGHBORS = 10 robots and never frees a slot, so an 11th
 * broadcaster would never be seen; here each complete entry is copied and its slot
 * freed, so any 10 positions per millisecond get through (docs/app.md).  The radio
 * task writes id, x, y, z, then the timestamp (after a call, so last): an entry
 * with timestamp 0 is being written (or free) and is taken at the next tick.  The
 * app owns the peer table: other readers of peer localization see it drained.
 * Each position gets the robot type of its radio id in the type table as it is
 * now, so a type the ground rewrites holds from the peer's next position on.  Id 0
 * marks a free slot in the firmware's table (peer_localization.c), so a robot
 * whose radio id is 0 is never seen as a peer (the ground side refuses it in a
 * swarm). */
static void drain_peers(void)
{
    for (uint8_t i = 0; i < PEER_LOCALIZATION_MAX_NEIGHBORS; ++i) {
        peerLocalizationOtherPosition_t *o = peerLocalizationGetPositionByIdx(i);
        if (o == NULL || o->id == 0u || o->pos.timestamp == 0u) {
            continue;
        }
        const float p[3] = {o->pos.x, o->pos.y, o->pos.z};
        (void)ns2_pilot_peer(&pilot, o->id, ns2_type_table_get(typeTable, o->id, NS2_NUM_ROBOT_TYPES),
                             o->pos.timestamp, p);
        o->pos.timestamp = 0u;
        o->id = 0u;
    }
}

static uint32_t elapsed_us(uint64_t t0)
{
    return (uint32_t)(usecTimestamp() - t0);
}

void controllerOutOfTreeInit(void)
{
    ctrlType = self_type();
    if (gainsType == 0xFFu) { /* at boot; a later init (controller switched) keeps the gains set */
        gainsType = ctrlType;
        gains = default_gains[ctrlType];
    }
    ns2_pilot_init(&pilot, &cfg, &vehicles[ctrlType], &gains); /* peers emptied, controller reset */
    pilot.adapt_cfg = adaptCfg;
    ns2_pilot_reset(&pilot, &vehicles[ctrlType]);
    ns2_pilot_set_psi1(&pilot, psi1[ctrlType]);
    faHat = 0.0f;
}

bool controllerOutOfTreeTest(void)
{
    return true;
}

void controllerOutOfTree(control_t *control, const setpoint_t *setpoint, const sensorData_t *sensors,
                         const state_t *state, const uint32_t tick)
{
    control->controlMode = controlModeForce;
    if (syncSeq != syncLogged) {
        syncLogged = syncSeq;
        eventTrigger_ns2Sync_payload.seq = syncSeq;
        eventTrigger(&eventTrigger_ns2Sync);
    }
    drain_peers();
    if (setpoint->mode.z == modeDisable || self_type() != ctrlType) {
        reset_controller(); /* on the ground, or the robot type was changed */
        for (int m = 0; m < STABILIZER_NR_OF_MOTORS; ++m) {
            control->normalizedForces[m] = 0.0f;
        }
        return;
    }
    ns2_ctrl_state_t s;
    ns2_setpoint_t sp;
    to_ctrl_state(state, sensors, &s);
    to_setpoint(setpoint, &sp);
    pilot.cfg = cfg; /* live parameters */
    pilot.cfg.self_type = ctrlType;
    pilot.gains = gains;
    pilot.adapt_cfg = adaptCfg;
    if (adaptReset) {
        adaptReset = 0u;
        ns2_adapt_reset(&pilot.adapt, &pilot.adapt_cfg);
    }
    const uint64_t t0 = usecTimestamp();
    ns2_pilot_step(&pilot, &s, &sp, tick, (uint8_t)(configblockGetRadioAddress() & 0xFFu),
                   (uint32_t)T2M(xTaskGetTickCount()), pmGetBatteryVoltage());
    const uint32_t us = elapsed_us(t0);
    stepUsMax = us > stepUsMax ? us : stepUsMax;
    if (RATE_DO_EXECUTE(RATE_100_HZ, tick)) { /* the prediction finished at the tick before */
        inferUs = stepUsMax;
        stepUsMax = 0;
        status = pilot.status;
        nUsed = (uint8_t)pilot.n_used;
        faHat = pilot.fa_hat_g;
        ex = pilot.e[0];
        ey = pilot.e[1];
        ez = pilot.e[2];
        adBias = pilot.adapt.theta[0];
        adScale = pilot.adapt.theta[1];
        adTrP = ns2_adapt_trace(&pilot.adapt);
        adLabel = pilot.label.label_g;
        adTerm = pilot.adapt.term_g;
        adStatus = (uint16_t)pilot.adapt.status;
        lbStatus = (uint8_t)pilot.label.status;
    }
    ctrlStatus = pilot.ctrl.status;
    for (int m = 0; m < STABILIZER_NR_OF_MOTORS; ++m) {
        control->normalizedForces[m] = pilot.ctrl.pwm[m];
    }
}

PARAM_GROUP_START(ns2)
PARAM_ADD(PARAM_UINT8, enable, &cfg.enable)
PARAM_ADD(PARAM_UINT8, fixed, &cfg.fixed)
PARAM_ADD_WITH_CALLBACK(PARAM_UINT8, selfType, &cfg.self_type, &self_type_written)
PARAM_ADD(PARAM_UINT8, phiPerTick, &cfg.phi_per_tick)
PARAM_ADD(PARAM_UINT16, maxAgeMs, &cfg.max_age_ms)
PARAM_ADD(PARAM_FLOAT, faLimit, &cfg.fa_limit_g)
PARAM_ADD(PARAM_UINT32, sync, &syncSeq)
PARAM_ADD(PARAM_UINT32 | PARAM_RONLY, modelId, &modelId)
PARAM_GROUP_STOP(ns2)

/* the type table: tK holds radio ids 16 K .. 16 K + 15 */
PARAM_GROUP_START(ns2type)
PARAM_ADD(PARAM_UINT32, t0, &typeTable[0])
PARAM_ADD(PARAM_UINT32, t1, &typeTable[1])
PARAM_ADD(PARAM_UINT32, t2, &typeTable[2])
PARAM_ADD(PARAM_UINT32, t3, &typeTable[3])
PARAM_ADD(PARAM_UINT32, t4, &typeTable[4])
PARAM_ADD(PARAM_UINT32, t5, &typeTable[5])
PARAM_ADD(PARAM_UINT32, t6, &typeTable[6])
PARAM_ADD(PARAM_UINT32, t7, &typeTable[7])
PARAM_ADD(PARAM_UINT32, t8, &typeTable[8])
PARAM_ADD(PARAM_UINT32, t9, &typeTable[9])
PARAM_ADD(PARAM_UINT32, t10, &typeTable[10])
PARAM_ADD(PARAM_UINT32, t11, &typeTable[11])
PARAM_ADD(PARAM_UINT32, t12, &typeTable[12])
PARAM_ADD(PARAM_UINT32, t13, &typeTable[13])
PARAM_ADD(PARAM_UINT32, t14, &typeTable[14])
PARAM_ADD(PARAM_UINT32, t15, &typeTable[15])
PARAM_GROUP_STOP(ns2type)
_Static_assert(NS2_TYPE_TABLE_WORDS == 16u, "ns2type.t0..t15 are the type table's words");

/* gains of eqs. (v_ref), (pos_ctrl), (omega_ref), (att_ctrl): see ns2_controller.h */
#define NS2_GAIN3(NAME)                      \
    PARAM_ADD(PARAM_FLOAT, NAME##x, &gains.NAME[0]) \
    PARAM_ADD(PARAM_FLOAT, NAME##y, &gains.NAME[1]) \
    PARAM_ADD(PARAM_FLOAT, NAME##z, &gains.NAME[2])
PARAM_GROUP_START(ns2gain)
NS2_GAIN3(Lp)
NS2_GAIN3(Kv)
NS2_GAIN3(Gv)
NS2_GAIN3(Lq)
NS2_GAIN3(Kw)
NS2_GAIN3(Gw)
NS2_GAIN3(Kwd)
PARAM_ADD(PARAM_FLOAT, intVMax, &gains.int_v_max)
PARAM_ADD(PARAM_FLOAT, intWMax, &gains.int_w_max)
PARAM_ADD(PARAM_FLOAT, faMaxN, &gains.fa_max_N)
PARAM_GROUP_STOP(ns2gain)

PARAM_GROUP_START(ns2adapt)
PARAM_ADD(PARAM_UINT8, enable, &adaptCfg.enable)
PARAM_ADD(PARAM_FLOAT, forget, &adaptCfg.forget)
PARAM_ADD(PARAM_FLOAT, p0, &adaptCfg.p0)
PARAM_ADD(PARAM_FLOAT, pMax, &adaptCfg.p_max)
PARAM_ADD(PARAM_FLOAT, biasMax, &adaptCfg.bias_max_g)
PARAM_ADD(PARAM_FLOAT, scaleMax, &adaptCfg.scale_max)
PARAM_ADD(PARAM_FLOAT, faMax, &adaptCfg.fa_max_g)
PARAM_ADD(PARAM_FLOAT, labelMax, &adaptCfg.label_max_g)
PARAM_ADD(PARAM_FLOAT, wakeG, &adaptCfg.wake_g)
PARAM_ADD(PARAM_UINT8, gateNbr, &adaptCfg.gate_neighbours)
PARAM_ADD(PARAM_FLOAT, trackGain, &adaptCfg.track_gain)
PARAM_ADD(PARAM_UINT8, reset, &adaptReset)
PARAM_GROUP_STOP(ns2adapt)

LOG_GROUP_START(ns2adapt)
LOG_ADD(LOG_FLOAT, bias, &adBias)
LOG_ADD(LOG_FLOAT, scale, &adScale)
LOG_ADD(LOG_FLOAT, trP, &adTrP)
LOG_ADD(LOG_FLOAT, label, &adLabel)
LOG_ADD(LOG_FLOAT, term, &adTerm)
LOG_ADD(LOG_UINT16, status, &adStatus)
LOG_ADD(LOG_UINT8, lstatus, &lbStatus)
LOG_GROUP_STOP(ns2adapt)

LOG_GROUP_START(ns2)
LOG_ADD(LOG_FLOAT, faHat, &faHat)
LOG_ADD(LOG_UINT32, inferUs, &inferUs)
LOG_ADD(LOG_UINT8, nUsed, &nUsed)
LOG_ADD(LOG_INT32, status, &status)
LOG_ADD(LOG_UINT32, ctrlStatus, &ctrlStatus)
LOG_ADD(LOG_FLOAT, ex, &ex)
LOG_ADD(LOG_FLOAT, ey, &ey)
LOG_ADD(LOG_FLOAT, ez, &ez)
LOG_GROUP_STOP(ns2)
