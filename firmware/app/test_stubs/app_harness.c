/*
 * app_harness.c - host test of the app glue (firmware/app/src/ns2_app.c), compiled
 * against the real crazyflie-firmware headers (ns2host.cfapp.harness: the include
 * folders of the firmware's Makefile, the app build's autoconf.h) together with the
 * firmware's real peer_localization.c.  Only functions are stubbed here: the clock,
 * the radio address, the battery voltage, the event-trigger and console sinks.
 * The app and the library are included as one translation unit, so the test reads
 * the app's statics.  Prints JSON.
 *
 *   harness FIXED ENABLE        one peer (radio id 2, a large robot) 0.3 m above a
 *       small robot hovering at its setpoint, one second of 1 kHz stabilizer ticks:
 *       the app's last f_a,z (g), the same prediction computed directly (ns2_peers +
 *       ns2_predict_*), the motor commands, the commands with the position setpoint
 *       disabled, the ns2Sync events.  FIXED 1 fixed point, 0 float; ENABLE 1
 *       learned term on, 0 baseline.
 *   harness swarm N K           N robots (radio ids 1..N, this one is id 1) in a
 *       ring 0.3 m around and 0.3 m above it, their positions broadcast as mocap
 *       does (peerLocalizationTellPosition), a 100 Hz frame of N-1 positions in
 *       packets of K positions, one packet per millisecond, for one second: how
 *       many peers the app keeps and its network uses, and the most the firmware's
 *       table ever held.
 *   harness trace FIXED ENABLE SELF_TYPE TYPES IN OUT
 *       TYPES: the peers' robot types, ID=TYPE,... (others type 0; "-": none), written
 *       into the type table as the ground does (PARAM ns2type.tK);
 *       the app's inputs of N 1 kHz stabilizer ticks from IN (N records of
 *       TRACE_WORDS little-endian 32-bit words: see trace_tick), given to the app as
 *       the stabilizer does (peers through peerLocalizationTellPosition, the clock,
 *       controllerOutOfTree); OUT: the app's vehicle, default gains and ns2 PARAM
 *       values (raw structs), then per tick control.normalizedForces[4] (float32).
 *   harness params STEP...
 *       from boot (controllerOutOfTreeInit), hovering: each STEP is a parameter write
 *       GROUP.NAME=VALUE of the app's groups (ns2, ns2type, ns2gain), done as the
 *       firmware's param_logic.c does it (value, then the entry's callback), or
 *       tick:N (N stabilizer ticks); prints the robot type the controller flies,
 *       the gains (PARAM ns2gain), the gains the controller uses and each type's
 *       default gains, as float arrays in ns2_gains_t order.
 *   harness peers STEP...
 *       the peer bookkeeping of the app (this robot: radio id 1, hovering), from boot;
 *       each STEP is GROUP.NAME=VALUE (a parameter write, as above), type:ID=TYPE
 *       (radio id ID's robot type written into the type table, PARAM ns2type.tK, as
 *       the ground does), ids:ID,ID,... (the robots whose positions mocap broadcasts
 *       from now on; "ids:" none), ms:N (N stabilizer ticks; every 10 ms a mocap frame
 *       of the broadcast robots, told to the firmware's peer localization in packets
 *       of 4 positions per millisecond, so at most 40 robots) or show (prints one JSON
 *       line: the time, the app's peer table in slot order as [id, type, samples,
 *       t_ms], the neighbours the last prediction used, the type table's words).
 *   harness adapt STEP...
 *       the on-board adaptation of the app (PARAM and LOG ns2adapt), from boot,
 *       hovering; each STEP is GROUP.NAME=VALUE (a parameter write, as above),
 *       tick:N (N stabilizer ticks), ground:N (N ticks without a position setpoint)
 *       or show (one JSON line: the LOG ns2adapt values, the pilot's theta, trace of
 *       P, updates and parameters in use, PARAM ns2adapt.reset as read back).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../src/ns2_lib.c"
#include "../src/ns2_app.c"
#include "param_write.h"

/* the sizes and offsets the glue relies on, as the real headers have them (the
 * header of this firmware version; a different one fails the build here) */
_Static_assert(offsetof(peerLocalizationOtherPosition_t, pos) == 4, "peerLocalizationOtherPosition_t");
_Static_assert(sizeof(point_t) == 16 && offsetof(point_t, x) == 4, "point_t = {timestamp, x, y, z}");
_Static_assert(PEER_LOCALIZATION_MAX_NEIGHBORS == 10, "this firmware keeps 10 peers (docs/app.md)");
_Static_assert(NS2_PEERS_MAX >= 16, "the app's own table holds the paper's 16-robot swarm");
_Static_assert(RATE_MAIN_LOOP == 1000, "the stabilizer loop runs at 1 kHz");

static uint32_t now_ms;
static uint32_t sync_events, sync_seq;

/* function stubs: what the firmware's drivers and tasks would provide */
int consolePutchar(int ch) { return ch; }
int eprintf(putc_t putcf, const char *fmt, ...) { (void)putcf; (void)fmt; return 0; }
void eventTrigger(const eventtrigger *event)
{
    if (strcmp(event->name, "ns2Sync") == 0 && event->payloadSize == sizeof(uint32_t)) {
        sync_events++;
        memcpy(&sync_seq, event->payload, sizeof sync_seq);
    }
}
uint64_t usecTimestamp(void) { return (uint64_t)now_ms * 1000u; }
uint64_t configblockGetRadioAddress(void) { return 0xE7E7E7E701ull; }
static float battery_V = 3.9f;
float pmGetBatteryVoltage(void) { return battery_V; }
TickType_t xTaskGetTickCount(void) { return now_ms; }
void vTaskDelay(const TickType_t ticks) { (void)ticks; }

/* Radio id `id` is of robot type `type`: its word of the type table written as the
 * ground writes it (PARAM ns2type.tK, done as param_logic.c does it). */
static int set_type(unsigned id, unsigned type)
{
    if (id > 255u || type >= NS2_TYPE_TABLE_MAX_TYPES) {
        return -1;
    }
    const unsigned k = id / 16u, shift = 2u * (id % 16u);
    const uint32_t w = (typeTable[k] & ~(3u << shift)) | ((uint32_t)type << shift);
    char name[8];
    snprintf(name, sizeof name, "t%u", k);
    return param_write(__params_ns2type, name, &w, sizeof w);
}

/* TYPES of the trace mode: ID=TYPE,... or "-" */
static int set_types(const char *spec)
{
    if (strcmp(spec, "-") == 0) {
        return 0;
    }
    for (const char *c = spec; *c != '\0';) {
        unsigned id, type;
        int used = 0;
        if (sscanf(c, "%u=%u%n", &id, &type, &used) != 2 || set_type(id, type) != 0) {
            return -1;
        }
        c += used;
        if (*c == ',') {
            ++c;
        } else if (*c != '\0') {
            return -1;
        }
    }
    return 0;
}

static void tell(int id, float x, float y, float z)
{
    positionMeasurement_t m = {0};
    m.x = x;
    m.y = y;
    m.z = z;
    (void)peerLocalizationTellPosition(id, &m);
}

/* What the stabilizer hands the app's controller: a robot hovering at 1 m. */
typedef struct {
    state_t state;
    setpoint_t sp;
    sensorData_t sensors;
    control_t control;
} rig_t;

/* The rig hovering, the app booted (controllerOutOfTreeInit). */
static void rig_boot(rig_t *r)
{
    memset(r, 0, sizeof *r);
    r->state.position.z = 1.0f;
    r->state.attitudeQuaternion.w = 1.0f;
    r->sp.position.z = 1.0f;
    r->sp.mode.x = r->sp.mode.y = r->sp.mode.z = modeAbs;
    controllerOutOfTreeInit();
}

/* One stabilizer tick of the app's controller at the clock's millisecond `tick`. */
static void rig_tick(rig_t *r, uint32_t tick)
{
    now_ms = tick;
    controllerOutOfTree(&r->control, &r->sp, &r->sensors, &r->state, tick);
}

static int swarm(int n_robots, int per_ms)
{
    rig_t r;
    rig_boot(&r);
    uint16_t n_max = 0;
    int held_max = 0;
    for (uint32_t tick = 1; tick <= 1000u; ++tick) {
        now_ms = tick;
        const int first = 2 + (int)(tick % 10u) * per_ms; /* this millisecond's packet */
        for (int id = first; id < first + per_ms && id <= n_robots; ++id) {
            const float a = 6.2831853f * (float)id / (float)n_robots;
            tell(id, 0.3f * cosf(a), 0.3f * sinf(a), 1.3f);
        }
        int held = 0;
        for (uint8_t i = 0; i < PEER_LOCALIZATION_MAX_NEIGHBORS; ++i) {
            held += peerLocalizationGetPositionByIdx(i)->id != 0u;
        }
        held_max = held > held_max ? held : held_max;
        rig_tick(&r, tick);
        n_max = nUsed > n_max ? nUsed : n_max;
    }
    printf("{\"robots\": %d, \"per_ms\": %d, \"firmware_table_max\": %d, \"app_peers\": %u, \"n_used\": %u}\n",
           n_robots, per_ms, held_max, (unsigned)pilot.peers.count, (unsigned)n_max);
    return 0;
}

/* one tick of a trace: disable (1: mode.z = modeDisable), battery_V, state
 * position[3] velocity[3] quaternion[w x y z], gyro[3] (deg/s), setpoint position[3]
 * velocity[3] acceleration[3] yaw (deg), n_peers (<= TRACE_PEERS), then per peer
 * id, x, y, z; all float32 but disable, n_peers and the ids (uint32) */
#define TRACE_PEERS 3
#define TRACE_WORDS (26 + 4 * TRACE_PEERS)

static float word_f(const uint32_t *w)
{
    float f;
    memcpy(&f, w, sizeof f);
    return f;
}

static int trace_tick(const uint32_t w[TRACE_WORDS], uint32_t tick, control_t *control)
{
    state_t state = {0};
    sensorData_t sensors = {0};
    setpoint_t sp = {0};
    state.position.x = word_f(&w[2]);
    state.position.y = word_f(&w[3]);
    state.position.z = word_f(&w[4]);
    state.velocity.x = word_f(&w[5]);
    state.velocity.y = word_f(&w[6]);
    state.velocity.z = word_f(&w[7]);
    state.attitudeQuaternion.w = word_f(&w[8]);
    state.attitudeQuaternion.x = word_f(&w[9]);
    state.attitudeQuaternion.y = word_f(&w[10]);
    state.attitudeQuaternion.z = word_f(&w[11]);
    sensors.gyro.x = word_f(&w[12]);
    sensors.gyro.y = word_f(&w[13]);
    sensors.gyro.z = word_f(&w[14]);
    sp.position.x = word_f(&w[15]);
    sp.position.y = word_f(&w[16]);
    sp.position.z = word_f(&w[17]);
    sp.velocity.x = word_f(&w[18]);
    sp.velocity.y = word_f(&w[19]);
    sp.velocity.z = word_f(&w[20]);
    sp.acceleration.x = word_f(&w[21]);
    sp.acceleration.y = word_f(&w[22]);
    sp.acceleration.z = word_f(&w[23]);
    sp.attitude.yaw = word_f(&w[24]);
    sp.mode.x = sp.mode.y = w[0] ? modeDisable : modeAbs;
    sp.mode.z = w[0] ? modeDisable : modeAbs;
    battery_V = word_f(&w[1]);
    if (w[25] > TRACE_PEERS) {
        return -1;
    }
    now_ms = tick;
    for (uint32_t j = 0; j < w[25]; ++j) {
        const uint32_t *pw = &w[26 + 4 * j];
        if (pw[0] == 0u || pw[0] > 255u) {
            return -1;
        }
        tell((int)pw[0], word_f(&pw[1]), word_f(&pw[2]), word_f(&pw[3]));
    }
    controllerOutOfTree(control, &sp, &sensors, &state, tick);
    return 0;
}

static int trace(char **argv)
{
    cfg.fixed = (uint8_t)atoi(argv[2]);
    cfg.enable = (uint8_t)atoi(argv[3]);
    cfg.self_type = (uint8_t)atoi(argv[4]);
    if (set_types(argv[5]) != 0) {
        fprintf(stderr, "%s: not ID=TYPE,... (radio id 0..255, type below %u)\n", argv[5],
                (unsigned)NS2_TYPE_TABLE_MAX_TYPES);
        return 1;
    }
    controllerOutOfTreeInit();
    FILE *in = fopen(argv[6], "rb");
    if (in == NULL) {
        fprintf(stderr, "%s: cannot open\n", argv[6]);
        return 1;
    }
    FILE *out = fopen(argv[7], "wb");
    if (out == NULL) {
        fprintf(stderr, "%s: cannot open\n", argv[7]);
        fclose(in);
        return 1;
    }
    int rc = 0;
    if (fwrite(&vehicles[ctrlType], sizeof vehicles[0], 1, out) != 1 ||
        fwrite(&default_gains[ctrlType], sizeof default_gains[0], 1, out) != 1 ||
        fwrite(&cfg, sizeof cfg, 1, out) != 1) {
        rc = 1;
    }
    control_t control = {0};
    uint32_t w[TRACE_WORDS];
    for (uint32_t tick = 0; rc == 0 && fread(w, sizeof w, 1, in) == 1; ++tick) {
        if (trace_tick(w, tick, &control) != 0) {
            fprintf(stderr, "%s: tick %u: bad peer count or radio id\n", argv[6], (unsigned)tick);
            rc = 1;
        } else if (fwrite(control.normalizedForces, sizeof(float), 4, out) != 4) {
            rc = 1;
        }
    }
    if (rc == 0 && ferror(in)) {
        fprintf(stderr, "%s: read error\n", argv[6]);
        rc = 1;
    }
    fclose(in);
    if (fclose(out) != 0) {
        rc = 1;
    }
    return rc;
}

static void print_gains(const char *name, const ns2_gains_t *g)
{
    const float *f = (const float *)g;
    printf(", \"%s\": [", name);
    for (size_t i = 0; i < sizeof *g / sizeof(float); ++i) {
        printf("%s%.9g", i ? ", " : "", (double)f[i]);
    }
    printf("]");
}

/* One parameter write GROUP.NAME=VALUE of the app's groups, as param_logic.c does it:
 * 0 written, 1 refused (message on stderr). */
static int write_step(const char *arg)
{
    char group[32], name[32];
    double value;
    if (sscanf(arg, "%31[^.].%31[^=]=%lf", group, name, &value) != 3) {
        fprintf(stderr, "%s: not GROUP.NAME=VALUE\n", arg);
        return 1;
    }
    struct param_s *table = strcmp(group, "ns2") == 0       ? __params_ns2
                            : strcmp(group, "ns2type") == 0 ? __params_ns2type
                            : strcmp(group, "ns2gain") == 0 ? __params_ns2gain
                            : strcmp(group, "ns2adapt") == 0 ? __params_ns2adapt
                                                            : NULL;
    const struct param_s *e = table != NULL ? param_find(table, name) : NULL;
    if (e == NULL) {
        fprintf(stderr, "%s: no such parameter of the app\n", arg);
        return 1;
    }
    const float f = (float)value;
    const uint32_t u32 = (uint32_t)value;
    const uint16_t u16 = (uint16_t)value;
    const uint8_t u8 = (uint8_t)value;
    const size_t size = (size_t)1u << (e->type & PARAM_BYTES_MASK);
    const void *v = (e->type & PARAM_TYPE_FLOAT) ? (const void *)&f
                    : size == 4                  ? (const void *)&u32
                    : size == 2                  ? (const void *)&u16
                                                 : (const void *)&u8;
    if (param_write(table, name, v, size) != 0) {
        fprintf(stderr, "%s: not writable\n", arg);
        return 1;
    }
    return 0;
}

static int params(int argc, char **argv)
{
    _Static_assert(sizeof(ns2_gains_t) % sizeof(float) == 0, "ns2_gains_t is floats");
    rig_t r;
    rig_boot(&r);
    uint32_t tick = 0;
    for (int a = 2; a < argc; ++a) {
        unsigned n;
        if (sscanf(argv[a], "tick:%u", &n) == 1) {
            for (unsigned k = 0; k < n; ++k, ++tick) {
                rig_tick(&r, tick);
            }
            continue;
        }
        if (write_step(argv[a]) != 0) {
            return 1;
        }
    }
    printf("{\"ctrl_type\": %u", (unsigned)ctrlType);
    print_gains("gains", &gains);
    print_gains("controller_gains", &pilot.gains);
    for (int t = 0; t < NS2_NUM_ROBOT_TYPES; ++t) {
        char key[32];
        snprintf(key, sizeof key, "default_%d", t);
        print_gains(key, &default_gains[t]);
    }
    printf("}\n");
    return 0;
}

#define PEERS_PER_MS 4u    /* positions per mocap packet (extPositionPacked) */
#define PEERS_FRAME_MS 10u /* mocap frames at 100 Hz */

static void show_peers(uint32_t tick)
{
    printf("{\"ms\": %u, \"peers\": [", (unsigned)tick);
    for (uint8_t i = 0; i < pilot.peers.count; ++i) {
        const ns2_peer_t *e = &pilot.peers.peer[i];
        printf("%s[%u, %u, %u, %u]", i ? ", " : "", (unsigned)e->id, (unsigned)e->type, (unsigned)e->samples,
               (unsigned)e->t_ms);
    }
    printf("], \"n_used\": %u, \"table\": [", (unsigned)pilot.n_used);
    for (unsigned k = 0; k < NS2_TYPE_TABLE_WORDS; ++k) {
        printf("%s%u", k ? ", " : "", (unsigned)typeTable[k]);
    }
    printf("]}\n");
}

static int peers(int argc, char **argv)
{
    rig_t r;
    rig_boot(&r);
    uint32_t tick = 1; /* the firmware's peer table stamps xTaskGetTickCount(); 0 would read as incomplete */
    unsigned ids[PEERS_PER_MS * PEERS_FRAME_MS];
    unsigned n_ids = 0;
    for (int a = 2; a < argc; ++a) {
        const char *arg = argv[a];
        unsigned n, id, type;
        if (strncmp(arg, "ids:", 4) == 0) {
            n_ids = 0;
            for (const char *c = arg + 4; *c != '\0';) {
                int used = 0;
                if (n_ids == sizeof ids / sizeof ids[0] || sscanf(c, "%u%n", &id, &used) != 1 || id > 255u) {
                    fprintf(stderr, "%s: not ids:ID,... (radio ids 0..255, at most %u)\n", arg,
                            (unsigned)(sizeof ids / sizeof ids[0]));
                    return 1;
                }
                ids[n_ids++] = id;
                c += used;
                c += *c == ',';
            }
        } else if (sscanf(arg, "ms:%u", &n) == 1) {
            for (unsigned k = 0; k < n; ++k, ++tick) {
                now_ms = tick;
                const unsigned slot = tick % PEERS_FRAME_MS; /* this millisecond's packet of the frame */
                for (unsigned j = slot * PEERS_PER_MS; j < (slot + 1u) * PEERS_PER_MS && j < n_ids; ++j) {
                    const float ang = 6.2831853f * (float)ids[j] / 256.0f;
                    tell((int)ids[j], 0.3f * cosf(ang), 0.3f * sinf(ang), 1.3f);
                }
                rig_tick(&r, tick);
            }
        } else if (sscanf(arg, "type:%u=%u", &id, &type) == 2) {
            if (set_type(id, type) != 0) {
                fprintf(stderr, "%s: radio id 0..255, type below %u\n", arg, (unsigned)NS2_TYPE_TABLE_MAX_TYPES);
                return 1;
            }
        } else if (strcmp(arg, "show") == 0) {
            show_peers(tick);
        } else if (write_step(arg) != 0) {
            return 1;
        }
    }
    return 0;
}

static void show_adapt(void)
{
    printf("{\"log\": {\"bias\": %.9g, \"scale\": %.9g, \"trP\": %.9g, \"label\": %.9g, \"term\": %.9g, "
           "\"status\": %u, \"lstatus\": %u}, ",
           (double)adBias, (double)adScale, (double)adTrP, (double)adLabel, (double)adTerm, (unsigned)adStatus,
           (unsigned)lbStatus);
    printf("\"theta\": [%.9g, %.9g], \"trP\": %.9g, \"updates\": %u, \"enable\": %u, \"forget\": %.9g, "
           "\"reset\": %u, \"fa_hat_g\": %.9g, \"fa_used_g\": %.9g, \"pwm\": [%.9g, %.9g, %.9g, %.9g]}\n",
           (double)pilot.adapt.theta[0], (double)pilot.adapt.theta[1], (double)ns2_adapt_trace(&pilot.adapt),
           (unsigned)pilot.adapt.updates, (unsigned)pilot.adapt_cfg.enable, (double)pilot.adapt_cfg.forget,
           (unsigned)adaptReset, (double)pilot.fa_hat_g, (double)pilot.fa_used_g, (double)pilot.ctrl.pwm[0],
           (double)pilot.ctrl.pwm[1], (double)pilot.ctrl.pwm[2], (double)pilot.ctrl.pwm[3]);
}

static int adapt(int argc, char **argv)
{
    rig_t r;
    rig_boot(&r);
    uint32_t tick = 0;
    for (int a = 2; a < argc; ++a) {
        unsigned n;
        if (sscanf(argv[a], "tick:%u", &n) == 1 || sscanf(argv[a], "ground:%u", &n) == 1) {
            r.sp.mode.z = argv[a][0] == 'g' ? modeDisable : modeAbs;
            for (unsigned k = 0; k < n; ++k, ++tick) {
                rig_tick(&r, tick);
            }
            r.sp.mode.z = modeAbs;
        } else if (strcmp(argv[a], "show") == 0) {
            show_adapt();
        } else if (write_step(argv[a]) != 0) {
            return 1;
        }
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc > 1 && strcmp(argv[1], "params") == 0) {
        return params(argc, argv);
    }
    if (argc > 1 && strcmp(argv[1], "adapt") == 0) {
        return adapt(argc, argv);
    }
    if (argc > 1 && strcmp(argv[1], "peers") == 0) {
        return peers(argc, argv);
    }
    if (argc > 7 && strcmp(argv[1], "trace") == 0) {
        return trace(argv);
    }
    if (argc > 3 && strcmp(argv[1], "swarm") == 0) {
        return swarm(atoi(argv[2]), atoi(argv[3]));
    }
    const uint8_t fixed = (uint8_t)(argc > 1 ? atoi(argv[1]) : 1);
    const uint8_t enable = (uint8_t)(argc > 2 ? atoi(argv[2]) : 1);
    rig_t r;
    rig_boot(&r);
    cfg.fixed = fixed;
    cfg.enable = enable;
    (void)set_type(2u, 1u); /* radio id 2 is a large robot */
    float sum[4] = {0};
    for (uint32_t tick = 0; tick < 1000u; ++tick) {
        now_ms = tick;
        tell(2, 0.05f, 0.0f, 1.3f); /* the peer's mocap position, every ms */
        if (tick == 500u) {
            syncSeq = 42u; /* the broadcast parameter write */
        }
        rig_tick(&r, tick);
        for (int m = 0; m < 4; ++m) {
            sum[m] += r.control.normalizedForces[m];
        }
    }
    /* the same prediction, directly */
    ns2_peers_t direct_peers;
    ns2_neighbor_t nb[NS2_PEERS_MAX];
    ns2_peers_init(&direct_peers, 0.5f);
    const float p[3] = {0.0f, 0.0f, 1.0f}, v[3] = {0.0f, 0.0f, 0.0f}, pp[3] = {0.05f, 0.0f, 1.3f};
    (void)ns2_peers_update(&direct_peers, 2u, 1u, 0u, pp);
    (void)ns2_peers_update(&direct_peers, 2u, 1u, 10u, pp);
#if NS2_HISTORY_LAGS > 0
    /* wake memory: hovering since long before, so every past state is the present one */
    float own_past[6 * NS2_HISTORY_LAGS];
    ns2_peers_record(&direct_peers, p, v);
#endif
    const uint16_t n = ns2_peers_neighbors(&direct_peers, 1u, p, v, 10u, 100u, nb, NS2_PEERS_MAX);
#if NS2_APP_FIXED && NS2_APP_FLOAT && NS2_HISTORY_LAGS > 0
    ns2_peers_own_past(&direct_peers, p, v, own_past);
    const float direct = fixed ? ldexpf((float)ns2_predict_q15_hist(NS2_TYPE_SMALL, p, v, own_past, nb, n, NULL),
                                        -NS2_Q_OUT_FRAC)
                               : ns2_predict_f32_hist(NS2_TYPE_SMALL, p, v, own_past, nb, n, NULL);
#elif NS2_APP_FIXED && NS2_APP_FLOAT
    const float direct = fixed ? ns2_predict_q15_g(NS2_TYPE_SMALL, p, v, nb, n, NULL)
                               : ns2_predict_f32(NS2_TYPE_SMALL, p, v, nb, n, NULL);
#else
#error "the harness compares both inference paths: build it with NS2_APP_FIXED=1 NS2_APP_FLOAT=1"
#endif
    printf("{\"mode\": %d, \"fa_hat_g\": %.9g, \"direct_g\": %.9g, \"n\": %u, \"mean_pwm\": [%.6g, %.6g, %.6g, %.6g]",
           (int)r.control.controlMode, (double)faHat, (double)direct, (unsigned)n,
           (double)(sum[0] / 1000.0f), (double)(sum[1] / 1000.0f), (double)(sum[2] / 1000.0f),
           (double)(sum[3] / 1000.0f));
    r.sp.mode.z = modeDisable;
    rig_tick(&r, 1000u);
    printf(", \"sync\": [%u, %u]", (unsigned)sync_events, (unsigned)sync_seq);
    printf(", \"off_pwm\": [%g, %g, %g, %g]}\n", (double)r.control.normalizedForces[0],
           (double)r.control.normalizedForces[1], (double)r.control.normalizedForces[2],
           (double)r.control.normalizedForces[3]);
    return 0;
}
