/*
 * hl_harness.c - the firmware's own high-level commander (crtp_commander_high_level.c,
 * with its planner.c, pptraj.c and pptraj_compressed.c) on the host, compiled against
 * the real crazyflie-firmware headers (ns2host.cfapp.build_hl_harness), decoding the
 * packets the ground side sent to one robot.  The commander is included as one
 * translation unit, so its own packet dispatch (handleCommand) and its trajectory
 * memory handler (handleMemWrite) are called as its CRTP task and mem.c call them, and
 * its statics (group mask, planner) are read.  Only functions are stubbed: the clock,
 * the FreeRTOS calls of the task and mutex, the CRTP queue, the memory registration,
 * the console (planner.c's DEBUG_PRINT).
 *
 *   hl_harness IN   IN: records, each a kind byte then
 *       0 (packet): port, channel, length (bytes), data[length], time (float64, s):
 *         port 8: the commander's handleCommand(data[0], data + 1), prints
 *           {"cmd": data[0], "ret": its return, "group_mask": the robot's group mask,
 *            "state": planner state};
 *         port 4 channel 2 (memory write: id, uint32 address, bytes): handleMemWrite,
 *           prints {"mem": address, "ok": 0/1};
 *       2 (parameter write of the group hlCommander, as param_logic.c does it): name
 *         length, name, value length, value, time (float64, s): prints
 *           {"param": name, "ret": param_write's return, "group_mask": ...};
 *       1 (evaluate): time (float64, s): the planner's goal, prints
 *           {"t": time, "state": planner state, "pos": [x, y, z], "vel": [x, y, z]} (null: no goal).
 *   Times are the ones the commander reads from usecTimestamp().
 */
#include <stdio.h>
#include <string.h>

#include "crtp_commander_high_level.c"
#include "console.h"
#include "eprintf.h"
#include "param_write.h"

static uint64_t now_us;

/* function stubs: what FreeRTOS, the CRTP stack, the console and mem.c would provide */
int consolePutchar(int ch) { return ch; }
int eprintf(putc_t putcf, const char *fmt, ...) { (void)putcf; (void)fmt; return 0; }
uint64_t usecTimestamp(void) { return now_us; }
void memoryRegisterHandler(const MemoryHandlerDef_t *handlerDef) { (void)handlerDef; }
void crtpInitTaskQueue(CRTPPort taskId) { (void)taskId; }
int crtpReceivePacketBlock(CRTPPort taskId, CRTPPacket *p) { (void)taskId; (void)p; return 0; }
int crtpSendPacketBlock(CRTPPacket *p) { (void)p; return 0; }
QueueHandle_t xQueueCreateMutexStatic(const uint8_t ucQueueType, StaticQueue_t *pxStaticQueue)
{
    (void)ucQueueType;
    return (QueueHandle_t)pxStaticQueue;
}
BaseType_t xQueueSemaphoreTake(QueueHandle_t xQueue, TickType_t xTicksToWait)
{
    (void)xQueue;
    (void)xTicksToWait;
    return pdTRUE;
}
BaseType_t xQueueGenericSend(QueueHandle_t xQueue, const void *const pvItemToQueue, TickType_t xTicksToWait,
                             const BaseType_t xCopyPosition)
{
    (void)xQueue;
    (void)pvItemToQueue;
    (void)xTicksToWait;
    (void)xCopyPosition;
    return pdTRUE;
}
TaskHandle_t xTaskCreateStatic(TaskFunction_t pxTaskCode, const char *const pcName, const uint32_t ulStackDepth,
                               void *const pvParameters, UBaseType_t uxPriority, StackType_t *const puxStackBuffer,
                               StaticTask_t *const pxTaskBuffer)
{
    (void)pxTaskCode;
    (void)pcName;
    (void)ulStackDepth;
    (void)pvParameters;
    (void)uxPriority;
    (void)puxStackBuffer;
    return (TaskHandle_t)pxTaskBuffer;
}

static void print_vec(const char *name, struct vec v)
{
    if (!visnan(v)) {
        printf(", \"%s\": [%.9g, %.9g, %.9g]", name, (double)v.x, (double)v.y, (double)v.z);
    } else {
        printf(", \"%s\": null", name); /* no goal (the planner is idle) */
    }
}

static int read_time(FILE *in)
{
    double t;
    if (fread(&t, sizeof t, 1, in) != 1 || !(t >= 0.0) || t > 1e6) {
        return -1;
    }
    now_us = (uint64_t)(t * 1e6);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: hl_harness IN\n");
        return 2;
    }
    FILE *in = fopen(argv[1], "rb");
    if (in == NULL) {
        fprintf(stderr, "%s: cannot open\n", argv[1]);
        return 1;
    }
    crtpCommanderHighLevelInit();
    int kind;
    while ((kind = fgetc(in)) != EOF) {
        if (kind == 0) {
            uint8_t head[3], data[CRTP_MAX_DATA_SIZE];
            if (fread(head, 1, 3, in) != 3 || head[2] > CRTP_MAX_DATA_SIZE || fread(data, 1, head[2], in) != head[2] ||
                read_time(in) != 0) {
                fprintf(stderr, "%s: a cut or bad packet record\n", argv[1]);
                return 1;
            }
            if (head[0] == CRTP_PORT_SETPOINT_HL && head[2] >= 1) {
                const int ret = handleCommand((enum TrajectoryCommand_e)data[0], &data[1]);
                printf("{\"cmd\": %u, \"ret\": %d, \"group_mask\": %u, \"state\": %d}\n", (unsigned)data[0], ret,
                       (unsigned)group_mask, (int)planner.state);
            } else if (head[0] == CRTP_PORT_MEM && head[1] == 2 && head[2] >= 5) {
                uint32_t addr;
                memcpy(&addr, &data[1], sizeof addr);
                const bool ok = handleMemWrite(data[0], addr, (uint8_t)(head[2] - 5), &data[5]);
                printf("{\"mem\": %u, \"ok\": %d}\n", (unsigned)addr, (int)ok);
            }
        } else if (kind == 2) {
            uint8_t n, name[64], size, value[8];
            if (fread(&n, 1, 1, in) != 1 || n >= sizeof name || fread(name, 1, n, in) != n ||
                fread(&size, 1, 1, in) != 1 || size > sizeof value || fread(value, 1, size, in) != size ||
                read_time(in) != 0) {
                fprintf(stderr, "%s: a cut or bad parameter record\n", argv[1]);
                return 1;
            }
            name[n] = 0;
            const int ret = param_write(__params_hlCommander, (const char *)name, value, size);
            printf("{\"param\": \"%s\", \"ret\": %d, \"group_mask\": %u}\n", (const char *)name, ret,
                   (unsigned)group_mask);
        } else if (kind == 1) {
            if (read_time(in) != 0) {
                fprintf(stderr, "%s: a cut or bad time record\n", argv[1]);
                return 1;
            }
            const struct traj_eval ev = plan_current_goal(&planner, (float)(now_us / 1e6));
            printf("{\"t\": %.6f, \"state\": %d", (double)now_us / 1e6, (int)planner.state);
            print_vec("pos", ev.pos);
            print_vec("vel", ev.vel);
            printf("}\n");
        } else {
            fprintf(stderr, "%s: unknown record kind %d\n", argv[1], kind);
            return 1;
        }
    }
    fclose(in);
    return 0;
}
