/*
 * ns2_app.c - Crazyflie app: the learned interaction force f_a,z (Neural-Swarm2)
 * as a feed-forward term of the on-board controller.
 *
 * Thin glue, all logic is in the tested library (firmware/src):
 *  - neighbours: positions of the other Crazyflies from the firmware's peer
 *    localization (mocap broadcasts), velocity by finite differences
 *    (ns2_peers), robot types from the ns2type parameters, the environment
 *    always included by ns2_predict_*;
 *  - prediction at 100 Hz from the own state estimate, float or fixed point
 *    (param ns2.fixed), limited to +-ns2.faLimit grams;
 *  - control: until the ns2 tracking controller lands, the firmware's Mellinger
 *    controller runs and its thrust is corrected by -f_a,z (thrust units per N =
 *    ns2.massThrust, the Mellinger constant); ns2.enable = 0 is the baseline.
 * PARAM groups: ns2 (switches, limits), ns2type (robot type of radio ids 0..31);
 * LOG group ns2: faHat (g), inferUs (us), nUsed, status.
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "app.h"
#include "FreeRTOS.h"
#include "task.h"

#define DEBUG_MODULE "NS2"
#include "debug.h"

#include "configblock.h"
#include "controller.h"
#include "controller_mellinger.h"
#include "log.h"
#include "param.h"
#include "peer_localization.h"
#include "stabilizer_types.h"
#include "usec_time.h"

#include "ns2_deepset.h"
#include "ns2_peers.h"

#define NS2_GRAVITY 9.81f

static struct {
    uint8_t enable;     /* 1: apply the learned feed-forward; 0: baseline */
    uint8_t fixed;      /* 1: fixed-point inference, 0: float */
    uint8_t selfType;   /* robot type of this Crazyflie (NS2_TYPE_*) */
    uint16_t maxAgeMs;  /* peers older than this are ignored */
    float faLimit;      /* |f_a,z| limit, g */
    float massThrust;   /* thrust units per newton of the controller output */
} cfg = {1, 1, NS2_TYPE_SMALL, 100, 20.0f, 132000.0f};

static uint32_t typeMask1; /* radio id i is robot type 1 when bit i is set */
static uint32_t typeMask2; /* ... type 2 (for a third robot type) */

static ns2_peers_t peers;
static float faHat;       /* g */
static uint32_t inferUs;  /* us */
static uint8_t nUsed;
static int32_t status;

void appMain(void)
{
    DEBUG_PRINT("ns2 model " NS2_MODEL_HASH "\n");
    while (1) {
        vTaskDelay(M2T(2000));
    }
}

static uint8_t type_of(uint8_t id)
{
    if (id < 32u && (typeMask2 >> id) & 1u) {
        return 2u < NS2_NUM_ROBOT_TYPES ? 2u : 0u;
    }
    if (id < 32u && (typeMask1 >> id) & 1u) {
        return 1u < NS2_NUM_ROBOT_TYPES ? 1u : 0u;
    }
    return 0u;
}

static void predict(const state_t *state, uint32_t now_ms)
{
    static ns2_neighbor_t nb[NS2_PEERS_MAX];
    for (uint8_t i = 0; i < PEER_LOCALIZATION_MAX_NEIGHBORS; ++i) {
        const peerLocalizationOtherPosition_t *o = peerLocalizationGetPositionByIdx(i);
        if (o != NULL && o->id != 0u) {
            const float p[3] = {o->pos.x, o->pos.y, o->pos.z};
            (void)ns2_peers_update(&peers, o->id, type_of(o->id), o->timestamp, p);
        }
    }
    const float p[3] = {state->position.x, state->position.y, state->position.z};
    const float v[3] = {state->velocity.x, state->velocity.y, state->velocity.z};
    const uint8_t self = (uint8_t)(configblockGetRadioAddress() & 0xFFu);
    const uint16_t n = ns2_peers_neighbors(&peers, self, p, v, now_ms, cfg.maxAgeMs, nb, NS2_PEERS_MAX);
    ns2_info_t info;
    const uint64_t t0 = usecTimestamp();
    float f = cfg.fixed ? ns2_predict_q15_g(cfg.selfType, p, v, nb, n, &info)
                        : ns2_predict_f32(cfg.selfType, p, v, nb, n, &info);
    inferUs = (uint32_t)(usecTimestamp() - t0);
    status = info.status;
    nUsed = (uint8_t)info.n_used;
    faHat = f > cfg.faLimit ? cfg.faLimit : (f < -cfg.faLimit ? -cfg.faLimit : f);
}

void controllerOutOfTreeInit(void)
{
    controllerMellingerInit();
    ns2_peers_init(&peers, 0.5f);
}

bool controllerOutOfTreeTest(void)
{
    return controllerMellingerTest();
}

void controllerOutOfTree(control_t *control, const setpoint_t *setpoint, const sensorData_t *sensors,
                         const state_t *state, const uint32_t tick)
{
    controllerMellinger(control, setpoint, sensors, state, tick);
    if (RATE_DO_EXECUTE(RATE_100_HZ, tick)) {
        predict(state, (uint32_t)T2M(xTaskGetTickCount()));
    }
    if (cfg.enable && control->thrust > 0.0f) {
        /* the controller should produce m a_d - f_a: subtract the learned force */
        const float thrust = control->thrust - faHat * 1e-3f * NS2_GRAVITY * cfg.massThrust;
        control->thrust = thrust > 0.0f ? thrust : 0.0f;
    }
}

PARAM_GROUP_START(ns2)
PARAM_ADD(PARAM_UINT8, enable, &cfg.enable)
PARAM_ADD(PARAM_UINT8, fixed, &cfg.fixed)
PARAM_ADD(PARAM_UINT8, selfType, &cfg.selfType)
PARAM_ADD(PARAM_UINT16, maxAgeMs, &cfg.maxAgeMs)
PARAM_ADD(PARAM_FLOAT, faLimit, &cfg.faLimit)
PARAM_ADD(PARAM_FLOAT, massThrust, &cfg.massThrust)
PARAM_GROUP_STOP(ns2)

PARAM_GROUP_START(ns2type)
PARAM_ADD(PARAM_UINT32, mask1, &typeMask1)
PARAM_ADD(PARAM_UINT32, mask2, &typeMask2)
PARAM_GROUP_STOP(ns2type)

LOG_GROUP_START(ns2)
LOG_ADD(LOG_FLOAT, faHat, &faHat)
LOG_ADD(LOG_UINT32, inferUs, &inferUs)
LOG_ADD(LOG_UINT8, nUsed, &nUsed)
LOG_ADD(LOG_INT32, status, &status)
LOG_GROUP_STOP(ns2)
