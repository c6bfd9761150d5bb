/*
 * app_harness.c - host test of the app glue (firmware/app/src/ns2_app.c) with the
 * firmware stand-ins of this folder implemented here: one peer (radio id 2, a
 * large robot) 0.3 m above a small robot hovering at its setpoint; one second of
 * 1 kHz stabilizer ticks.  Prints JSON: the app's last f_a,z (g), the same
 * prediction computed directly (ns2_peers + ns2_predict_*), the motor commands,
 * and the commands with the position setpoint disabled.  The app and the library
 * are included as one translation unit, so the test reads the app's statics.
 *
 *   argv[1]: 1 fixed point, 0 float;  argv[2]: 1 learned term on, 0 baseline
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "app.h"
#include "configblock.h"
#include "controller.h"
#include "peer_localization.h"
#include "pm.h"
#include "task.h"
#include "usec_time.h"

#include "../src/ns2_lib.c"
#include "../src/ns2_app.c"

static uint32_t now_ms;
static uint32_t sync_events, sync_seq;
static peerLocalizationOtherPosition_t peer = {2u, 0u, {0.05f, 0.0f, 1.3f}, {0.0f, 0.0f, 0.0f, 1.0f}};

int consolePrintf(const char *fmt, ...) { (void)fmt; return 0; }
void eventTrigger(const eventTrigger_t *event)
{
    sync_events++;
    sync_seq = *(const uint32_t *)event->payload;
}
uint64_t usecTimestamp(void) { return (uint64_t)now_ms * 1000u; }
uint64_t configblockGetRadioAddress(void) { return 0xE7E7E7E701ull; }
float pmGetBatteryVoltage(void) { return 3.9f; }
TickType_t xTaskGetTickCount(void) { return now_ms; }
void vTaskDelay(const TickType_t ticks) { (void)ticks; }
peerLocalizationOtherPosition_t *peerLocalizationGetPositionByIdx(uint8_t idx)
{
    peer.timestamp = now_ms;
    return idx == 0u ? &peer : NULL;
}

int main(int argc, char **argv)
{
    const uint8_t fixed = (uint8_t)(argc > 1 ? atoi(argv[1]) : 1);
    const uint8_t enable = (uint8_t)(argc > 2 ? atoi(argv[2]) : 1);
    state_t state = {0};
    sensorData_t sensors = {0};
    setpoint_t sp = {0};
    control_t control = {0};
    state.position.z = 1.0f;
    state.attitudeQuaternion.w = 1.0f;
    sp.position.z = 1.0f;
    sp.mode.x = sp.mode.y = sp.mode.z = modeAbs;
    controllerOutOfTreeInit();
    cfg.fixed = fixed;
    cfg.enable = enable;
    typeMask1 = 1u << 2; /* radio id 2 is a large robot */
    float sum[4] = {0};
    for (uint32_t tick = 0; tick < 1000u; ++tick) {
        now_ms = tick;
        if (tick == 500u) {
            syncSeq = 42u; /* the broadcast parameter write */
        }
        controllerOutOfTree(&control, &sp, &sensors, &state, tick);
        for (int m = 0; m < 4; ++m) {
            sum[m] += control.normalizedForces[m];
        }
    }
    /* the same prediction, directly */
    ns2_peers_t direct_peers;
    ns2_neighbor_t nb[NS2_PEERS_MAX];
    ns2_peers_init(&direct_peers, 0.5f);
    const float p[3] = {0.0f, 0.0f, 1.0f}, v[3] = {0.0f, 0.0f, 0.0f}, pp[3] = {0.05f, 0.0f, 1.3f};
    (void)ns2_peers_update(&direct_peers, 2u, 1u, 0u, pp);
    (void)ns2_peers_update(&direct_peers, 2u, 1u, 10u, pp);
    const uint16_t n = ns2_peers_neighbors(&direct_peers, 1u, p, v, 10u, 100u, nb, NS2_PEERS_MAX);
    const float direct = fixed ? ns2_predict_q15_g(NS2_TYPE_SMALL, p, v, nb, n, NULL)
                               : ns2_predict_f32(NS2_TYPE_SMALL, p, v, nb, n, NULL);
    printf("{\"mode\": %d, \"fa_hat_g\": %.9g, \"direct_g\": %.9g, \"n\": %u, \"mean_pwm\": [%.6g, %.6g, %.6g, %.6g]",
           (int)control.controlMode, (double)faHat, (double)direct, (unsigned)n,
           (double)(sum[0] / 1000.0f), (double)(sum[1] / 1000.0f), (double)(sum[2] / 1000.0f),
           (double)(sum[3] / 1000.0f));
    sp.mode.z = modeDisable;
    now_ms = 1000u;
    controllerOutOfTree(&control, &sp, &sensors, &state, 1000u);
    printf(", \"sync\": [%u, %u]", (unsigned)sync_events, (unsigned)sync_seq);
    printf(", \"off_pwm\": [%g, %g, %g, %g]}\n", (double)control.normalizedForces[0],
           (double)control.normalizedForces[1], (double)control.normalizedForces[2],
           (double)control.normalizedForces[3]);
    return 0;
}
