/*
 * cf_stabilizer.c - entry points for counting one 1 ms stabilizer iteration on the
 * emulated Cortex-M4 (ns2host.stabilizer): the firmware's own Kalman estimator
 * (kalman_core, the iteration of estimator_kalman.c's task with a position
 * measurement), its stock PID controller (controller_pid.c) and the ns2 app's
 * out-of-tree controller, all compiled from the crazyflie-firmware tarball and
 * firmware/app for the STM32F405.  Only functions are stubbed here.
 *
 * bench_init(n_peers, xyz): a hovering Crazyflie (radio id 1) at (0, 0, 1) m with
 *     n_peers robots (ids 2..n_peers+1) at the positions xyz (3 floats each, m; the
 *     caller's ring: libm's trigonometry is not used here, its cosf gave wrong
 *     values in the emulator); the Kalman filter, the PID and the app initialized.
 * bench_radio(tick): what the radio task does in that millisecond: one mocap
 *     broadcast packet of 4 positions told to the firmware's peer localization
 *     (a 100 Hz frame of all peers in the first ticks of each period).
 * bench_estimator(now_ms, predict, measure): one iteration of the estimator task
 *     (process noise, finalize, externalize; predict = 1: the 100 Hz prediction too;
 *     measure = 1: a mocap position measurement too).
 * bench_pid(tick), bench_app(tick): one call of each controller at stabilizer step tick.
 */
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#include "FreeRTOS.h"
#include "task.h"
#include "controller.h"
#include "controller_pid.h"
#include "eventtrigger.h"
#include "kalman_core.h"
#include "mm_position.h"
#include "peer_localization.h"
#include "stabilizer_types.h"

int main(void);

static kalmanCoreData_t kd;
static kalmanCoreParams_t kp;
static state_t state;
static sensorData_t sensors;
static setpoint_t setpoint;
static control_t control;
static Axis3f acc = {.z = 1.0f}, gyro;
static uint32_t now;
static uint32_t peers;
#define BENCH_MAX_PEERS 32u
static float ring[BENCH_MAX_PEERS][3];

/* function stubs: the firmware's clock, radio, power and logging services */
TickType_t xTaskGetTickCount(void) { return now; }
void vTaskDelay(const TickType_t ticks) { (void)ticks; }
uint64_t usecTimestamp(void) { return (uint64_t)now * 1000u; }
uint64_t configblockGetRadioAddress(void) { return 0xE7E7E7E701ull; }
float pmGetBatteryVoltage(void) { return 3.9f; }
void eventTrigger(const eventtrigger *event) { (void)event; }
int consolePutchar(int ch) { return ch; }
int eprintf(int (*putcf)(int), const char *fmt, ...) { (void)putcf; (void)fmt; return 0; }
void assertFail(char *exp, char *file, int line) { (void)exp; (void)file; (void)line; }

void bench_init(uint32_t n_peers, const float *xyz)
{
    peers = n_peers < BENCH_MAX_PEERS ? n_peers : BENCH_MAX_PEERS;
    memcpy(ring, xyz, (size_t)peers * sizeof ring[0]);
    kalmanCoreDefaultParams(&kp);
    kalmanCoreInit(&kd, &kp, 0u);
    controllerPidInit();
    controllerOutOfTreeInit();
    memset(&state, 0, sizeof state);
    state.position.z = 1.0f;
    state.attitudeQuaternion.w = 1.0f;
    memset(&setpoint, 0, sizeof setpoint);
    setpoint.position.z = 1.0f;
    setpoint.mode.x = setpoint.mode.y = setpoint.mode.z = modeAbs;
    setpoint.mode.yaw = modeAbs;
}

void bench_radio(uint32_t tick)
{
    now = tick;
    const uint32_t first = (tick % 10u) * 4u;
    for (uint32_t i = first; i < first + 4u && i < peers; ++i) {
        positionMeasurement_t m = {0};
        m.x = ring[i][0];
        m.y = ring[i][1];
        m.z = ring[i][2];
        (void)peerLocalizationTellPosition((int)(i + 2u), &m);
    }
}

void bench_estimator(uint32_t now_ms, uint32_t predict, uint32_t measure)
{
    now = now_ms;
    if (predict) {
        kalmanCorePredict(&kd, &kp, &acc, &gyro, now_ms, true);
    }
    kalmanCoreAddProcessNoise(&kd, &kp, now_ms);
    if (measure) {
        positionMeasurement_t pos = {0};
        pos.x = 0.01f;
        pos.y = -0.01f;
        pos.z = 1.0f;
        pos.stdDev = 0.01f;
        kalmanCoreUpdateWithPosition(&kd, &pos);
    }
    (void)kalmanCoreFinalize(&kd);
    kalmanCoreExternalizeState(&kd, &state, &acc);
    state.position.z = 1.0f; /* the controllers see the hover state */
}

void bench_pid(uint32_t tick)
{
    now = tick;
    controllerPid(&control, &setpoint, &sensors, &state, tick);
}

void bench_app(uint32_t tick)
{
    now = tick;
    controllerOutOfTree(&control, &setpoint, &sensors, &state, tick);
}

int main(void)
{
    return 0;
}
