/*
 * ns2_fuzz.c - structured fuzzing of the firmware library under ASan + UBSan
 * (built and run by host/fuzz.py; `make fuzz`, bounded run in the tests).
 *
 *   ns2_fuzz TARGET COUNT SEED     TARGET: infer sliced peers ctrl adapt pilot hil regress
 *
 * Every target draws structured inputs from a seeded generator: plausible values
 * mixed with NaN (both signs, payloads), +-Inf, +-FLT_MAX, huge finite values,
 * subnormals and -0, bad counts, types and pointers, glitches followed by good
 * input.  Beyond the sanitizers (any report aborts: -fno-sanitize-recover) each
 * target checks the documented contract and, after a glitch, recovery within
 * the documented bound.  A failed check prints "FAIL <target> <input index>: why"
 * and exits 1.  On success one line of JSON: target, inputs, checks, the export's
 * NS2_INPUT_DIM and predictions_ok (predictions with status NS2_OK and at least one
 * neighbour used: that the inference was reached, not only refused).
 *
 * Wake memory (an export with NS2_HISTORY_LAGS > 0): every neighbour's past inputs
 * and the robot's own past are drawn like the present (hostile values included) and
 * the *_hist entry points are called (own_past sometimes NULL: refused); the plain
 * ones must refuse (NS2_ERR_STATE); the peer table's history ring is recorded with
 * any own state and, after a glitch, must hold only good states within
 * NS2_PEERS_HIST history ticks; HIL PREDICT bodies carry 6 (1 + lags) inputs per
 * neighbour and the own past.  Without it the driver runs as before.
 */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ns2_adapt.h"
#include "ns2_controller.h"
#include "ns2_deepset.h"
#include "ns2_hil.h"
#include "ns2_label.h"
#include "ns2_peers.h"
#include "ns2_pilot.h"
#include "ns2_vehicles.h"

static uint64_t rng_state;
static unsigned long long n_checks;
static unsigned long long n_ok; /* predictions with NS2_OK and n_used > 0 */
static const char *target_name = "";
static unsigned long long input_index;

static uint64_t rnd(void) /* splitmix64 */
{
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static uint32_t below(uint32_t n) { return n ? (uint32_t)(rnd() % n) : 0u; }

static float uniform(float lo, float hi)
{
    return lo + (hi - lo) * (float)((double)(rnd() >> 11) * (1.0 / 9007199254740992.0));
}

static float from_bits(uint32_t u)
{
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static uint32_t bits_of(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

/* A hostile value. */
static float special(void)
{
    switch (below(16)) {
    case 0: return NAN;
    case 1: return -NAN;
    case 2: return from_bits(0x7FA00001u | (uint32_t)(rnd() & 0x1FFFFFu)); /* NaN payloads */
    case 3: return INFINITY;
    case 4: return -INFINITY;
    case 5: return FLT_MAX;
    case 6: return -FLT_MAX;
    case 7: return 1e37f;
    case 8: return -1e20f;
    case 9: return 1e12f;
    case 10: return from_bits(1u); /* smallest subnormal */
    case 11: return -1e-40f;
    case 12: return -0.0f;
    case 13: return FLT_MIN;
    case 14: return 3e38f;
    default: return from_bits((uint32_t)rnd());
    }
}

/* Mostly a plausible value in [lo, hi], a hostile one with probability 1/p_bad. */
static float value(float lo, float hi, uint32_t p_bad)
{
    return (p_bad && below(p_bad) == 0u) ? special() : uniform(lo, hi);
}

static void fail(const char *why)
{
    printf("FAIL %s %llu: %s\n", target_name, input_index, why);
    fflush(stdout);
    exit(1);
}

static void check(int ok, const char *why)
{
    ++n_checks;
    if (!ok) {
        fail(why);
    }
}

/* ------------------------------------------------------------------ inference */
#define NB_CAP (2u * NS2_MAX_NEIGHBORS + 8u)

#if NS2_HISTORY_LAGS > 0
static float fz_past[6u * NS2_HISTORY_LAGS]; /* the robot's own [p; v] at each lag */
static const float *past_arg = fz_past;      /* fz_past, sometimes NULL (refused) */
#endif

/* The entry points of the export: HIST(ns2_predict_f32)(rt, p, v, OWN_PAST nb, n, info) is
 * ns2_predict_f32_hist with the own past past_arg with wake memory, else ns2_predict_f32. */
#if NS2_HISTORY_LAGS > 0
#define HIST(fn) fn##_hist
#define OWN_PAST past_arg,
#else
#define HIST(fn) fn
#define OWN_PAST
#endif

static uint16_t random_query(uint8_t *rt, float p[3], float v[3], ns2_neighbor_t *nb, uint32_t p_bad)
{
    *rt = (uint8_t)(below(8) == 0 ? below(256) : below(NS2_NUM_ROBOT_TYPES));
    for (int a = 0; a < 3; ++a) {
        p[a] = value(-1.5f, 1.5f, p_bad);
        v[a] = value(-2.0f, 2.0f, p_bad);
    }
    p[2] = fabsf(p[2]) + (below(2) ? 0.0f : 0.5f);
    const uint16_t n = (uint16_t)(below(4) == 0 ? below(NB_CAP + 1u) : below(NS2_MAX_NEIGHBORS + 1u));
    for (uint16_t j = 0; j < n; ++j) {
        nb[j].type = (uint8_t)(below(10) == 0 ? below(256) : below(NS2_NUM_ROBOT_TYPES));
        for (int a = 0; a < 3; ++a) {
            nb[j].rel[a] = value(-0.6f, 0.6f, p_bad);
            nb[j].rel[a + 3] = value(-2.0f, 2.0f, p_bad);
        }
#if NS2_HISTORY_LAGS > 0
        for (int k = 6; k < NS2_INPUT_DIM; k += 6) { /* the past at each lag: rarer hostile values */
            for (int a = 0; a < 3; ++a) {
                nb[j].rel[k + a] = value(-0.6f, 0.6f, 4u * p_bad);
                nb[j].rel[k + a + 3] = value(-2.0f, 2.0f, 4u * p_bad);
            }
        }
#endif
    }
#if NS2_HISTORY_LAGS > 0
    for (int l = 0; l < NS2_HISTORY_LAGS; ++l) {
        for (int a = 0; a < 3; ++a) {
            fz_past[6 * l + a] = value(-1.5f, 1.5f, 4u * p_bad);
            fz_past[6 * l + a + 3] = value(-2.0f, 2.0f, 4u * p_bad);
        }
    }
    past_arg = below(64) == 0 ? NULL : fz_past;
#endif
    return n;
}

static int same_info(const ns2_info_t *a, const ns2_info_t *b)
{
    return a->status == b->status && a->n_used == b->n_used && a->n_invalid == b->n_invalid &&
           a->n_outside == b->n_outside && a->n_truncated == b->n_truncated;
}

static void check_prediction(uint16_t n, float f, int16_t q, const ns2_info_t *fi, const ns2_info_t *qi)
{
    check(isfinite(f), "float prediction not finite");
    check(same_info(fi, qi), "float and fixed path disagree on the neighbour selection");
    if (fi->status != NS2_OK) {
        check(bits_of(f) == 0u && q == 0, "error status but a non-zero result");
    } else {
        check((uint32_t)fi->n_used + fi->n_invalid + fi->n_outside + fi->n_truncated == n,
              "neighbour counters do not add up to n");
        check(fi->n_used <= NS2_MAX_NEIGHBORS, "more than NS2_MAX_NEIGHBORS used");
        n_ok += fi->n_used > 0u;
    }
#if NS2_HISTORY_LAGS > 0
    if (past_arg == NULL) {
        check(fi->status < 0, "wake memory: a NULL own past accepted");
    }
#endif
}

static void fuzz_infer(unsigned long long count)
{
    static ns2_neighbor_t nb[NB_CAP];
    for (input_index = 0; input_index < count; ++input_index) {
        uint8_t rt;
        float p[3], v[3];
        const uint16_t n = random_query(&rt, p, v, nb, 8u);
        ns2_info_t fi, qi, gi;
        const int null_nb = below(64) == 0;
        const float f = HIST(ns2_predict_f32)(rt, p, v, OWN_PAST null_nb ? NULL : nb, n, &fi);
        const int16_t q = HIST(ns2_predict_q15)(rt, p, v, OWN_PAST null_nb ? NULL : nb, n, &qi);
        const float g = ns2_predict_q15_g(rt, p, v, null_nb ? NULL : nb, n, &gi);
        check_prediction(n, f, q, &fi, &qi);
#if NS2_HISTORY_LAGS > 0
        { /* the plain entry points (no own past) refuse a model with wake memory */
            ns2_info_t pi;
            check(g == 0.0f && gi.status < 0, "wake memory: ns2_predict_q15_g without own past accepted");
            check(ns2_predict_f32(rt, p, v, null_nb ? NULL : nb, n, &pi) == 0.0f && pi.status < 0,
                  "wake memory: ns2_predict_f32 without own past accepted");
        }
#else
        check(g == ldexpf((float)q, -NS2_Q_OUT_FRAC), "q15_g is not q * 2^-NS2_Q_OUT_FRAC");
#endif
        if (null_nb && n > 0u) {
            check(fi.status == NS2_ERR_NULL || fi.status == NS2_ERR_ROBOT_TYPE || fi.status == NS2_ERR_STATE,
                  "NULL neighbours not refused");
        }
        if (below(16) == 0) { /* NULL own state and NULL info are refused / allowed */
            ns2_info_t ni;
            check(HIST(ns2_predict_f32)(rt, NULL, v, OWN_PAST nb, n, &ni) == 0.0f && ni.status < 0, "NULL p accepted");
            (void)HIST(ns2_predict_q15)(rt, p, v, OWN_PAST nb, n, NULL);
        }
    }
}

/* ------------------------------------------------------------------ sliced API */
static void fuzz_sliced(unsigned long long count)
{
    static ns2_neighbor_t nb[NB_CAP];
    static ns2_job_t job;
    for (input_index = 0; input_index < count; ++input_index) {
        uint8_t rt;
        float p[3], v[3];
        const uint16_t n = random_query(&rt, p, v, nb, 16u);
        const int fixed = (int)below(2);
        ns2_info_t one, sl;
        const float f1 = fixed ? 0.0f : HIST(ns2_predict_f32)(rt, p, v, OWN_PAST nb, n, &one);
        const int16_t q1 = fixed ? HIST(ns2_predict_q15)(rt, p, v, OWN_PAST nb, n, &one) : 0;
        n_ok += one.status == NS2_OK && one.n_used > 0u;
        if (below(32) == 0) { /* a job never begun (zeroed) or stepped by the other path */
            memset(&job, 0, sizeof job);
            check(ns2_job_step_f32(&job, 3) == 0u && ns2_job_finish_q15(&job, &sl) == 0 &&
                      sl.status == NS2_ERR_JOB, "zeroed job not refused");
        }
        const int32_t st = HIST(ns2_job_begin)(&job, rt, p, v, OWN_PAST nb, n);
        check(st == one.status, "ns2_job_begin status differs from the one-shot call");
        uint16_t left = 1u;
        for (int guard = 0; left > 0u && guard < 200; ++guard) {
            const uint16_t k = (uint16_t)below(6); /* 0 steps allowed: no progress */
            left = fixed ? ns2_job_step_q15(&job, k) : ns2_job_step_f32(&job, k);
            if (below(8) == 0) {
                break; /* finish early: finish does the rest */
            }
        }
        if (below(16) == 0) { /* the other path must refuse a job of this path */
            ns2_info_t other;
            if (st != NS2_OK || job.next == 0u) {
                /* not yet bound to a path */
            } else if (fixed) {
                check(ns2_job_finish_f32(&job, &other) == 0.0f && other.status == NS2_ERR_JOB, "f32 finished a q15 job");
            } else {
                check(ns2_job_finish_q15(&job, &other) == 0 && other.status == NS2_ERR_JOB, "q15 finished an f32 job");
            }
        }
        if (fixed) {
            const int16_t q2 = ns2_job_finish_q15(&job, &sl);
            check(q2 == q1 && same_info(&sl, &one), "sliced fixed result differs from the one-shot call");
        } else {
            const float f2 = ns2_job_finish_f32(&job, &sl);
            check(bits_of(f2) == bits_of(f1) && same_info(&sl, &one), "sliced float result differs from one-shot");
        }
        check(HIST(ns2_job_begin)(NULL, rt, p, v, OWN_PAST nb, n) == NS2_ERR_JOB, "NULL job not refused");
    }
}

/* ------------------------------------------------------------------ peers */
static void check_neighbors(const ns2_peers_t *s, uint32_t now, int require_all_valid, const float p_self[3])
{
    ns2_neighbor_t out[NS2_PEERS_MAX + 4u];
    const float v0[3] = {0.0f, 0.0f, 0.0f};
    const uint16_t max = (uint16_t)below(NS2_PEERS_MAX + 4u);
    const uint16_t n = ns2_peers_neighbors(s, 255u, p_self, v0, now, 5000u, out, max);
    check(n <= max && n <= NS2_PEERS_MAX, "more neighbours than asked for");
    for (uint16_t k = 0; k < n; ++k) {
        for (int a = 0; a < NS2_INPUT_DIM; ++a) { /* now and, with wake memory, each lag */
            check(isfinite(out[k].rel[a]), "non-finite neighbour state");
        }
        if (k > 0u) {
            const float d0 = out[k - 1u].rel[0] * out[k - 1u].rel[0] + out[k - 1u].rel[1] * out[k - 1u].rel[1] +
                             out[k - 1u].rel[2] * out[k - 1u].rel[2];
            const float d1 = out[k].rel[0] * out[k].rel[0] + out[k].rel[1] * out[k].rel[1] +
                             out[k].rel[2] * out[k].rel[2];
            check(d0 <= d1, "neighbours not nearest first");
        }
    }
    (void)require_all_valid;
}

/* The bookkeeping stays bounded: at most NS2_PEERS_MAX entries, one per radio id. */
static void check_table(const ns2_peers_t *s)
{
    check(s->count <= NS2_PEERS_MAX, "peer table beyond NS2_PEERS_MAX");
    for (uint8_t i = 0; i < s->count; ++i) {
        for (uint8_t j = (uint8_t)(i + 1u); j < s->count; ++j) {
            check(s->peer[i].id != s->peer[j].id, "one radio id in two slots");
        }
    }
}

/* ns2_type_table_get on any table, id and number of types against the documented
 * layout (2 bits per radio id, 16 ids per word; a type not below n_types is 0). */
static void check_type_table(void)
{
    uint32_t table[NS2_TYPE_TABLE_WORDS];
    for (unsigned k = 0; k < NS2_TYPE_TABLE_WORDS; ++k) {
        table[k] = below(3) == 0 ? 0u : (uint32_t)rnd();
    }
    const uint8_t n_types = (uint8_t)(below(4) == 0 ? below(256) : 1u + below(NS2_TYPE_TABLE_MAX_TYPES));
    for (int q = 0; q < 8; ++q) {
        const uint8_t id = (uint8_t)(q == 0 ? 0u : q == 1 ? 255u : below(256));
        const uint8_t raw = (uint8_t)((table[id / 16u] >> (2u * (id % 16u))) & 3u);
        const uint8_t got = ns2_type_table_get(table, id, n_types);
        check(got == (raw < n_types ? raw : 0u), "type table: not the documented layout");
        check(got < NS2_TYPE_TABLE_MAX_TYPES && (got < n_types || got == 0u), "type table: a type out of range");
    }
    check(ns2_type_table_get(NULL, (uint8_t)below(256), n_types) == 0u, "type table: NULL is not type 0");
}

#if NS2_HISTORY_LAGS > 0
/* The robot's own past is finite whatever the ring holds (given a finite present). */
static void check_own_past(const ns2_peers_t *s)
{
    const float z[3] = {0.0f, 0.0f, 0.0f};
    float own[6u * NS2_HISTORY_LAGS];
    ns2_peers_own_past(s, z, z, own);
    for (uint32_t a = 0; a < 6u * NS2_HISTORY_LAGS; ++a) {
        check(isfinite(own[a]), "non-finite own past");
    }
}

/* After NS2_PEERS_HIST history ticks of the robot at rest at the origin and no new
 * sample, the ring holds only those ticks: every lag of every neighbour is its
 * present (bit for bit: the same subtraction), and the own past is the origin. */
static void check_history_settled(const ns2_peers_t *s, uint32_t now)
{
    const float z[3] = {0.0f, 0.0f, 0.0f};
    float own[6u * NS2_HISTORY_LAGS];
    ns2_peers_own_past(s, z, z, own);
    for (uint32_t a = 0; a < 6u * NS2_HISTORY_LAGS; ++a) {
        check(own[a] == 0.0f, "own past is not the recorded state after NS2_PEERS_HIST history ticks");
    }
    ns2_neighbor_t out[NS2_PEERS_MAX];
    const uint16_t n = ns2_peers_neighbors(s, 255u, z, z, now, 100u, out, NS2_PEERS_MAX);
    for (uint16_t k = 0; k < n; ++k) {
        for (int a = 6; a < NS2_INPUT_DIM; ++a) {
            check(bits_of(out[k].rel[a]) == bits_of(out[k].rel[a % 6]),
                  "a neighbour's past is not its steady state after NS2_PEERS_HIST history ticks");
        }
    }
}
#endif

static void fuzz_peers(unsigned long long count)
{
    static ns2_peers_t s;
    unsigned long long done = 0;
    for (input_index = 0; done < count; ++input_index) {
        check_type_table();
        ns2_peers_init(&s, below(4) == 0 ? value(-1.0f, 2.0f, 4u) : uniform(0.1f, 1.0f));
        const uint8_t n_ids = (uint8_t)(1u + below(NS2_PEERS_MAX + 4u));
        const uint8_t id_base = (uint8_t)(below(2) ? 0u : below(256)); /* ids anywhere in 0..255, wrapping */
        uint32_t t = (uint32_t)rnd();
        /* hostile phase: wild samples, timestamps and ids */
        const uint32_t n_bad = 1u + below(60);
        for (uint32_t k = 0; k < n_bad; ++k, ++done) {
            float p[3];
            for (int a = 0; a < 3; ++a) {
                p[a] = value(-3.0f, 3.0f, 3u);
            }
            t += below(30); /* true time; some samples carry a glitched timestamp */
            const uint32_t stamp = below(4) == 0 ? (uint32_t)rnd() : t;
            const int32_t r = ns2_peers_update(&s, (uint8_t)(id_base + below(n_ids)), (uint8_t)below(256), stamp,
                                               below(50) ? p : NULL);
            check(r == NS2_PEERS_OK || r == NS2_PEERS_REJECTED || r == NS2_PEERS_RESTARTED, "unknown status");
            check_table(&s);
            float self[3] = {value(-3.0f, 3.0f, 8u), value(-3.0f, 3.0f, 8u), value(0.0f, 2.0f, 8u)};
            check_neighbors(&s, t + below(100), 0, self);
#if NS2_HISTORY_LAGS > 0
            if (below(3) == 0u) { /* a history tick, with any own state */
                const float sv[3] = {value(-2.0f, 2.0f, 8u), value(-2.0f, 2.0f, 8u), value(-2.0f, 2.0f, 8u)};
                ns2_peers_record(&s, below(32) ? self : NULL, sv);
            }
            check_own_past(&s);
#endif
        }
        /* good phase: every known peer flies at constant velocity, 10 ms samples;
         * after at most 3 samples each its velocity must be the true one */
        t += 20000u;
        float vel[NS2_PEERS_MAX][3], p0[NS2_PEERS_MAX][3];
        for (uint8_t i = 0; i < s.count; ++i) {
            for (int a = 0; a < 3; ++a) {
                vel[i][a] = uniform(-2.0f, 2.0f);
                p0[i][a] = uniform(-3.0f, 3.0f);
            }
        }
        for (uint32_t k = 0; k < 4u; ++k) {
            for (uint8_t i = 0; i < s.count; ++i, ++done) {
                float p[3];
                for (int a = 0; a < 3; ++a) {
                    p[a] = p0[i][a] + vel[i][a] * 0.01f * (float)k;
                }
                const int32_t r = ns2_peers_update(&s, s.peer[i].id, 0u, t + 10u * k, p);
                check(r != NS2_PEERS_REJECTED, "good sample rejected after a glitch");
                check(k < 2u || r == NS2_PEERS_OK, "track still restarting after two good samples");
            }
        }
        for (uint8_t i = 0; i < s.count; ++i) {
            check(s.peer[i].samples == 2u, "peer without velocity after good samples");
            for (int a = 0; a < 3; ++a) {
                check(fabsf(s.peer[i].v[a] - vel[i][a]) < 0.05f + 0.01f * fabsf(vel[i][a]),
                      "velocity did not recover after good samples");
            }
        }
        const float origin[3] = {0.0f, 0.0f, 0.0f};
        check_neighbors(&s, t + 30u, 1, origin);
#if NS2_HISTORY_LAGS > 0
        for (uint32_t k = 0; k < NS2_PEERS_HIST; ++k) {
            ns2_peers_record(&s, origin, origin);
        }
        check_history_settled(&s, t + 30u);
#endif
        ns2_neighbor_t out[NS2_PEERS_MAX];
        const float z[3] = {0.0f, 0.0f, 0.0f};
        uint16_t others = 0; /* every peer but the robot itself (radio id 255 here) */
        for (uint8_t i = 0; i < s.count; ++i) {
            others = (uint16_t)(others + (s.peer[i].id != 255u));
        }
        check(ns2_peers_neighbors(&s, 255u, z, z, t + 30u, 100u, out, NS2_PEERS_MAX) == others,
              "a recovered peer is missing from the neighbour list");
        /* churn: the table filled up with robots heard at the same time, then a robot
         * never heard before arrives; with the table full of live peers it is refused,
         * once one of them has been silent for NS2_PEERS_STALE_MS it takes that slot (the
         * stalest: not the one heard again), a new track, and the others stay */
        const uint32_t last = t + 30u; /* every peer's last sample */
        const float p_new[3] = {0.5f, -0.5f, 1.0f};
        uint8_t fresh_id = (uint8_t)rnd();
        while (s.count <= NS2_PEERS_MAX) {
            for (int again = 1; again;) {
                again = 0;
                for (uint8_t i = 0; i < s.count; ++i) {
                    if (s.peer[i].id == fresh_id) {
                        fresh_id = (uint8_t)(fresh_id + 1u);
                        again = 1;
                    }
                }
            }
            if (s.count == NS2_PEERS_MAX) {
                break;
            }
            ++done;
            check(ns2_peers_update(&s, fresh_id, 0u, last, p_new) == NS2_PEERS_OK, "a free slot refused");
            check_table(&s);
        }
        ++done;
        check(ns2_peers_update(&s, fresh_id, 1u, last + below(NS2_PEERS_STALE_MS + 1u), p_new) == NS2_PEERS_REJECTED,
              "a new peer took the slot of a live one");
        const uint8_t keep = (uint8_t)below(NS2_PEERS_MAX); /* one peer is heard again later */
        const uint32_t t_keep = last + 1u + below(NS2_PEERS_STALE_MS);
        const uint8_t kept_id = s.peer[keep].id;
        check(ns2_peers_update(&s, kept_id, 0u, t_keep, s.peer[keep].p) != NS2_PEERS_REJECTED,
              "a live peer's sample rejected");
        const uint32_t t_new = t_keep + 1u + below(NS2_PEERS_STALE_MS);
        const int stale_any = t_new - last > NS2_PEERS_STALE_MS;
        ++done;
        const int32_t r = ns2_peers_update(&s, fresh_id, 1u, t_new, p_new);
        check(r == (stale_any ? NS2_PEERS_OK : NS2_PEERS_REJECTED), "a silent peer's slot not given / given");
        check_table(&s);
        check(s.count == NS2_PEERS_MAX, "the table changed size");
        int found_new = 0, found_kept = 0;
        for (uint8_t i = 0; i < s.count; ++i) {
            found_new |= s.peer[i].id == fresh_id && s.peer[i].type == 1u && s.peer[i].samples == 1u;
            found_kept |= s.peer[i].id == kept_id;
        }
        check(found_new == stale_any && found_kept, "the new peer or the live one missing");
    }
    input_index = done;
}

/* ------------------------------------------------------------------ controller */
#if NS2_HAVE_VEHICLES
static const ns2_vehicle_t fz_veh[NS2_NUM_ROBOT_TYPES] = NS2_VEHICLES_INIT;
static const ns2_gains_t fz_gains[NS2_NUM_ROBOT_TYPES] = NS2_DEFAULT_GAINS_INIT;
#endif

static void good_tick(ns2_ctrl_state_t *s, ns2_setpoint_t *sp, float fa[3], uint32_t k)
{
    const float t = 0.002f * (float)k;
    for (int a = 0; a < 3; ++a) {
        sp->p[a] = 0.1f * sinf(t + (float)a);
        sp->v[a] = 0.1f * cosf(t + (float)a);
        sp->a[a] = -0.1f * sinf(t + (float)a);
        sp->w[a] = 0.0f;
        s->p[a] = sp->p[a] + 0.02f * sinf(3.0f * t + (float)a);
        s->v[a] = sp->v[a] + 0.05f * cosf(5.0f * t);
        s->w[a] = 0.3f * sinf(7.0f * t + (float)a);
        fa[a] = a == 2 ? -0.05f : 0.0f;
    }
    sp->p[2] += 1.0f;
    s->p[2] += 1.0f;
    sp->yaw = 0.2f * sinf(t);
    const float h = 0.05f * sinf(2.0f * t);
    s->q[0] = cosf(h);
    s->q[1] = sinf(h);
    s->q[2] = 0.5f * sinf(h);
    s->q[3] = 0.0f;
}

static void hostile(float *x, int n)
{
    for (int i = 0; i < n; ++i) {
        if (below(3) == 0) {
            x[i] = special();
        }
    }
}

static void check_outputs(const ns2_ctrl_t *c, float f_max)
{
    for (int i = 0; i < 4; ++i) {
        check(c->pwm[i] >= 0.0f && c->pwm[i] <= 1.0f, "PWM outside [0, 1] or NaN");
        check(c->u[i] >= 0.0f && c->u[i] <= f_max, "motor force outside [0, f_max] or NaN");
    }
}

static void fuzz_ctrl(unsigned long long count)
{
#if NS2_HAVE_VEHICLES
    static ns2_ctrl_t c, fresh;
    unsigned long long done = 0;
    for (input_index = 0; done < count; ++input_index) {
        const uint8_t rt = (uint8_t)below(NS2_NUM_ROBOT_TYPES);
        const ns2_vehicle_t *veh = &fz_veh[rt];
        ns2_ctrl_init(&c, veh, &fz_gains[rt]);
        uint32_t k = 0;
        ns2_ctrl_state_t s;
        ns2_setpoint_t sp;
        float fa[3];
        /* good flight, then a burst of hostile ticks; in half the runs the last one
         * is surely a bad state (non-finite body rate), so the controller resets */
        const uint32_t n_good = below(300);
        const uint32_t n_bad = 1u + below(20);
        const int force_fault = (int)below(2);
        for (uint32_t j = 0; j < n_good + n_bad; ++j, ++k, ++done) {
            good_tick(&s, &sp, fa, k);
            float dt_pos = 0.01f, dt_att = 0.002f, bat = 3.9f;
            const int bad = j >= n_good;
            if (bad) {
                switch (below(8)) {
                case 0: hostile(s.p, 3); hostile(s.v, 3); break;
                case 1: hostile(s.q, 4); hostile(s.w, 3); break;
                case 2: hostile(sp.p, 3); hostile(sp.v, 3); hostile(sp.a, 3); break;
                case 3: hostile(&sp.yaw, 1); hostile(sp.w, 3); break;
                case 4: hostile(fa, 3); break;
                case 5: hostile(&dt_pos, 1); hostile(&dt_att, 1); break;
                case 6: hostile(&bat, 1); break;
                default: /* everything at once */
                    hostile(s.p, 3); hostile(s.q, 4); hostile(s.w, 3); hostile(sp.p, 3); hostile(&sp.yaw, 1);
                    hostile(fa, 3); hostile(&dt_att, 1);
                    break;
                }
                if (force_fault && j + 1u == n_good + n_bad) {
                    s.w[below(3)] = NAN;
                }
            }
            if (k % 5u == 0u) {
                ns2_ctrl_position(&c, &s, below(64) ? &sp : NULL, below(64) ? fa : NULL, dt_pos);
            }
            ns2_ctrl_attitude(&c, &s, dt_att, bat);
            check_outputs(&c, veh->f_max_N);
        }
        /* good input again: continue to the next position tick, then compare with a
         * fresh controller fed the same good ticks (bit for bit once c has reset) */
        while (k % 5u != 0u) {
            good_tick(&s, &sp, fa, k);
            ns2_ctrl_attitude(&c, &s, 0.002f, 3.9f);
            check_outputs(&c, veh->f_max_N);
            ++k;
            ++done;
        }
        ns2_ctrl_init(&fresh, veh, &fz_gains[rt]);
        const int was_reset = force_fault;
        uint32_t recovering_ticks = 0;
        for (uint32_t j = 0; j < NS2_CTRL_RECOVERY_TICKS + 25u; ++j, ++k, ++done) {
            good_tick(&s, &sp, fa, k);
            if (k % 5u == 0u) {
                ns2_ctrl_position(&c, &s, &sp, fa, 0.01f);
                ns2_ctrl_position(&fresh, &s, &sp, fa, 0.01f);
            }
            ns2_ctrl_attitude(&c, &s, 0.002f, 3.9f);
            ns2_ctrl_attitude(&fresh, &s, 0.002f, 3.9f);
            check_outputs(&c, veh->f_max_N);
            check((c.status & (NS2_CTRL_BAD_STATE | NS2_CTRL_RESET | NS2_CTRL_BAD_SETPOINT)) == 0u,
                  "fault reported on good input");
            if (c.status & NS2_CTRL_RECOVERING) {
                ++recovering_ticks;
            }
            if (was_reset) {
                check(memcmp(c.u, fresh.u, sizeof c.u) == 0 && memcmp(c.pwm, fresh.pwm, sizeof c.pwm) == 0,
                      "after a fault the controller differs from a fresh one on the same good input");
            }
            for (int i = 0; i < 4 && was_reset; ++i) { /* (without a reset, wound-up integrators may saturate) */
                check(c.pwm[i] > 0.0f, "no thrust on good input after recovery");
            }
        }
        check(recovering_ticks <= NS2_CTRL_RECOVERY_TICKS, "recovery not within NS2_CTRL_RECOVERY_TICKS");
        check((c.status & NS2_CTRL_RECOVERING) == 0u, "still recovering after the bound");
        check(!was_reset || recovering_ticks > 0u, "a fault without NS2_CTRL_RECOVERING");
    }
    input_index = done;
#else
    (void)count;
    fail("the export has no vehicle parameters (NS2_HAVE_VEHICLES 0)");
#endif
}

/* ------------------------------------------------- on-board label and adaptation */

/* hover-like inputs of the label at position tick k */
static void good_label_in(float *vz, float *z, float q[4], float pwm[4], float *bat, float *nn, uint32_t k)
{
    const float t = 0.01f * (float)k;
    *vz = 0.2f * sinf(t);
    *z = 1.0f + 0.2f * cosf(t);
    q[0] = 1.0f;
    q[1] = 0.02f * sinf(3.0f * t);
    q[2] = q[3] = 0.0f;
    for (int m = 0; m < 4; ++m) {
        pwm[m] = 0.5f + 0.05f * sinf(t + (float)m);
    }
    *bat = 3.9f;
    *nn = 2.0f * sinf(0.3f * t);
}

static void check_adapt(const ns2_adapt_t *a, const ns2_adapt_cfg_t *c, float nn, float out)
{
    check(isfinite(out) && isfinite(a->term_g), "adaptation output not finite");
    for (int i = 0; i < 3; ++i) {
        check(isfinite(a->P[i]), "P not finite");
    }
    check(c->gate_neighbours <= 1u || !ns2_adapt_cfg_ok(c), "gate_neighbours not 0 or 1 accepted");
    check(!(a->status & NS2_ADAPT_BAD_TRACK) || ((a->status & NS2_ADAPT_UPDATED) && c->track_gain > 0.0f),
          "tracking term skipped without an update with track_gain > 0");
    if (!ns2_adapt_cfg_ok(c) && isfinite(nn) && fabsf(nn) <= 1e30f) {
        check(a->status == NS2_ADAPT_BAD_PARAM, "bad parameters but no NS2_ADAPT_BAD_PARAM alone");
    }
    if (!ns2_adapt_cfg_ok(c) || !c->enable) {
        check(out == nn || !isfinite(nn) || fabsf(nn) > 1e30f, "adaptation off or bad parameters but f != NN");
        return;
    }
    if (isfinite(nn) && fabsf(nn) <= 1e30f) {
        check(fabsf(a->term_g) <= c->fa_max_g, "adapted term beyond fa_max_g");
    }
    if (a->status & NS2_ADAPT_UPDATED) {
        /* never learns where |NN| > wake_g, nor on a flagged tick with gate_neighbours = 1 */
        check(fabsf(a->nn[0]) <= c->wake_g, "updated on a tick with |NN| > wake_g");
        check(!(c->gate_neighbours && ((a->wake >> NS2_ADAPT_NN_DELAY) & 1u)),
              "updated on a tick with the wake flag and gate_neighbours = 1");
        check(fabsf(a->theta[0]) <= c->bias_max_g && fabsf(a->theta[1]) <= c->scale_max, "theta outside its set");
        check(a->P[0] >= NS2_ADAPT_P_MIN && a->P[2] >= NS2_ADAPT_P_MIN, "P diagonal below NS2_ADAPT_P_MIN");
        check(a->P[0] <= c->p_max + NS2_ADAPT_P_MIN && a->P[2] <= c->p_max + NS2_ADAPT_P_MIN, "P beyond p_max");
        check(a->P[1] * a->P[1] <= a->P[0] * a->P[2] * 1.0001f, "P not positive semi-definite");
    }
}

static void random_adapt_cfg(ns2_adapt_cfg_t *c, uint32_t p_bad)
{
    ns2_adapt_default_cfg(c);
    c->forget = uniform(0.9f, 1.0f);
    c->p_max = uniform(1.0f, 100.0f);
    c->p0 = uniform(0.01f, 1.0f);
    c->wake_g = uniform(0.0f, 20.0f);
    c->scale_max = below(2) ? 0.0f : uniform(0.0f, 1.0f);
    c->enable = (uint8_t)(below(8) != 0u);
    c->gate_neighbours = (uint8_t)below(2);
    c->track_gain = below(2) ? 0.0f : uniform(0.0f, 1.0e5f);
    if (below(100) < p_bad) {
        float *f[] = {&c->forget, &c->p0, &c->p_max, &c->bias_max_g, &c->scale_max, &c->fa_max_g,
                      &c->label_max_g, &c->wake_g, &c->track_gain};
        const uint32_t which = below(10);
        if (which == 9u) {
            c->gate_neighbours = (uint8_t)(2u + below(254)); /* not 0 or 1 */
        } else {
            *f[which] = below(2) ? special() : uniform(-10.0f, 10.0f);
        }
    }
}

static void fuzz_adapt(unsigned long long count)
{
#if NS2_HAVE_VEHICLES
    static ns2_label_t l, fresh;
    static ns2_adapt_t a;
    unsigned long long done = 0;
    for (input_index = 0; done < count; ++input_index) {
        const uint8_t rt = (uint8_t)below(NS2_NUM_ROBOT_TYPES);
        const float psi1[NS2_NUM_ROBOT_TYPES][5] = NS2_PSI1_INIT;
        ns2_label_cfg_t lc = {fz_veh[rt].mass_kg, fz_veh[rt].lambda, {0}, 0.01f, 0.1f, 0.866f};
        memcpy(lc.psi1, psi1[rt], sizeof lc.psi1);
        const int spoil_config = below(10) == 0u;
        if (spoil_config) {
            float *f[] = {&lc.mass_kg, &lc.lambda, &lc.h_s, &lc.psi1[below(5)], &lc.min_z_m};
            *f[below(5)] = special();
        }
        ns2_label_init(&l, &lc);
        /* a hostile value may still be a valid one (-0, FLT_MIN, random bits): judged by the label's own check */
        const int bad_config = !l.config_ok;
        check(spoil_config || !bad_config, "a good label configuration refused");
        ns2_adapt_cfg_t c;
        random_adapt_cfg(&c, 0u);
        ns2_adapt_reset(&a, &c);
        const uint32_t n_good = below(400), n_bad = 1u + below(20);
        uint32_t k = 0;
        float vz, z, q[4], pwm[4], bat, nn, s_h;
        for (uint32_t j = 0; j < n_good + n_bad; ++j, ++k, ++done) {
            good_label_in(&vz, &z, q, pwm, &bat, &nn, k);
            s_h = uniform(-0.01f, 0.01f); /* the composite tracking error times 10 ms, m */
            if (j >= n_good) {
                hostile(&vz, 1); hostile(&z, 1); hostile(q, 4); hostile(pwm, 4); hostile(&bat, 1); hostile(&nn, 1);
                hostile(&s_h, 1);
                if (below(4) == 0u) {
                    random_adapt_cfg(&c, 50u);
                }
                if (j + 1u == n_good + n_bad) {
                    vz = NAN; /* the burst ends with a bad sample: the label restarts */
                }
            }
            const uint32_t st = ns2_label_step(&l, vz, z, q, pwm, bat);
            check(isfinite(l.label_N) && isfinite(l.label_g), "label not finite");
            if (st & (NS2_LABEL_BAD_INPUT | NS2_LABEL_WARMUP | NS2_LABEL_BAD_CONFIG)) {
                check(l.label_N == 0.0f, "no label but label_N != 0");
            }
            const float out = ns2_adapt_step_track(&a, &c, nn, (int)below(2), l.label_g, st, s_h);
            check_adapt(&a, &c, nn, out);
        }
        /* good input and parameters again: the label equals a fresh one's on the same
         * ticks, labels within NS2_LABEL_STENCIL ticks, the adaptation leaves BAD_PARAM */
        random_adapt_cfg(&c, 0u);
        ns2_label_init(&fresh, &lc);
        for (uint32_t j = 0; j < 50u; ++j, ++k, ++done) {
            good_label_in(&vz, &z, q, pwm, &bat, &nn, k);
            const uint32_t st = ns2_label_step(&l, vz, z, q, pwm, bat);
            (void)ns2_label_step(&fresh, vz, z, q, pwm, bat);
            check(memcmp(&l.label_N, &fresh.label_N, sizeof l.label_N) == 0 && l.status == fresh.status,
                  "after bad input the label differs from a fresh one on the same good input");
            if (j + 1u >= NS2_LABEL_STENCIL) {
                check(bad_config ? st == NS2_LABEL_BAD_CONFIG : (st & (NS2_LABEL_BAD_INPUT | NS2_LABEL_WARMUP)) == 0u,
                      "no label NS2_LABEL_STENCIL ticks after good input returned");
            }
            const float out = ns2_adapt_step_track(&a, &c, nn, 0, l.label_g, st, uniform(-0.01f, 0.01f));
            check_adapt(&a, &c, nn, out);
            check((a.status & (NS2_ADAPT_BAD_PARAM | NS2_ADAPT_BAD_INPUT | NS2_ADAPT_BAD_TRACK)) == 0u,
                  "fault reported on good input");
        }
    }
    input_index = done;
#else
    (void)count;
    fail("the export has no vehicle parameters (NS2_HAVE_VEHICLES 0)");
#endif
}

/* ------------------------------------------------------------------ pilot (the app's per tick) */
#define PILOT_SWARM 20u        /* robots heard: more than the peer table holds */
#define PILOT_RECOVERY_MS 120u /* good milliseconds after the glitches before hover is required */
#define PILOT_HOVER_MS 40u     /* hover checked for that long */

/* A pilot after any call: motor commands and forces within the controller's range
 * (check_outputs), f_a finite, fa_hat_g within +-lim (lim: the fa_limit_g its last
 * finish read) for a finite lim >= 0, else exactly 0 (ns2_pilot.h). */
static void check_pilot(const ns2_pilot_t *pl, float lim, float f_max)
{
    check_outputs(&pl->ctrl, f_max);
    check(isfinite(pl->fa_hat_g) && isfinite(pl->fa_used_g), "pilot: f_a not finite");
    if (isfinite(lim) && lim >= 0.0f) {
        check(fabsf(pl->fa_hat_g) <= lim, "pilot: fa_hat_g beyond fa_limit_g");
    } else {
        check(pl->fa_hat_g == 0.0f, "pilot: fa_hat_g not 0 with fa_limit_g not a finite number >= 0");
    }
    check(pl->n_used <= NS2_MAX_NEIGHBORS, "pilot: more than NS2_MAX_NEIGHBORS used");
}

/* A live change of the PARAM group ns2 or of the adaptation's parameters (hostile with
 * probability p_bad in 100).  which: 4 those read at k = 0 only (the neighbour list, the
 * position loop) and the slicing, which may change at any millisecond; 6 also the
 * limit (read by the finish: k = 9 of ns2_pilot_step, k = 0 of ns2_pilot_tick) and the
 * robot type (read by the start: k = 1 against 0), the same for both at k = 9; 7 also
 * the inference path, which every phi evaluation reads (a job sliced on one path is
 * refused by the other: ns2_pilot_step and ns2_pilot_tick may differ until a reset). */
static void pilot_cfg_change(ns2_pilot_cfg_t *cfg, ns2_adapt_cfg_t *ac, uint32_t p_bad, uint32_t which)
{
    switch (below(which)) {
    case 0: cfg->phi_per_tick = (uint8_t)below(256); break;
    case 1: cfg->enable = (uint8_t)(below(8) ? below(2) : below(256)); break;
    case 2: cfg->max_age_ms = (uint16_t)(below(2) ? below(300) : rnd()); break;
    case 3: random_adapt_cfg(ac, p_bad); break;
    case 4: cfg->fa_limit_g = below(100) < p_bad ? (below(2) ? special() : uniform(-40.0f, 0.0f)) : uniform(0.0f, 40.0f);
        break;
    case 5: cfg->self_type = (uint8_t)(below(8) ? below(NS2_NUM_ROBOT_TYPES) : below(256)); break;
    default: cfg->fixed = (uint8_t)(below(8) ? below(2) : below(256)); break;
    }
}

/* Hover on good input near the setpoint after the glitches: no fault, the position
 * loop's collective thrust T_d within m g +- (fa_max_N + Kv_z Gv_z int_v_max + m g / 5):
 * the learned force and the integral term at their limits (ns2_controller.h) and the
 * tracking of the sane manoeuvre; once the controller was reset (wound-up integrators
 * may saturate a motor otherwise, as in fuzz_ctrl) every motor turning below full PWM. */
static void pilot_check_hover(const ns2_pilot_t *pl, const ns2_vehicle_t *veh, int was_reset)
{
    const ns2_ctrl_t *c = &pl->ctrl;
    const ns2_gains_t *g = &pl->gains;
    const float mg = veh->mass_kg * (float)NS2_G_MPS2;
    const float slack = g->fa_max_N + g->Kv[2] * g->Gv[2] * g->int_v_max + 0.2f * mg;
    check((c->status & (NS2_CTRL_BAD_STATE | NS2_CTRL_RESET | NS2_CTRL_BAD_SETPOINT | NS2_CTRL_RECOVERING)) == 0u,
          "pilot: controller fault on good input after the recovery time");
    for (int i = 0; i < 4 && was_reset; ++i) {
        check(c->pwm[i] > 0.0f && c->pwm[i] < 1.0f, "pilot: a motor off or at full PWM in hover");
    }
    check(fabsf(c->T_d - mg) <= slack, "pilot: collective thrust T_d beyond its bound in hover");
}

static void fuzz_pilot(unsigned long long count)
{
#if NS2_HAVE_VEHICLES
    static ns2_pilot_t A, B;
    static const float psi1[NS2_NUM_ROBOT_TYPES][5] = NS2_PSI1_INIT;
    unsigned long long done = 0;
    for (input_index = 0; done < count; ++input_index) {
        const uint8_t rt = (uint8_t)below(NS2_NUM_ROBOT_TYPES), self_id = (uint8_t)below(256);
        const ns2_vehicle_t *veh = &fz_veh[rt];
        ns2_pilot_cfg_t cfg;
        ns2_adapt_cfg_t ac;
        ns2_pilot_default_cfg(&cfg, rt);
        cfg.fixed = (uint8_t)below(2);
        cfg.phi_per_tick = (uint8_t)below(9);
        random_adapt_cfg(&ac, 0u);
        for (ns2_pilot_t *pl = &A; pl; pl = pl == &A ? &B : NULL) {
            ns2_pilot_init(pl, &cfg, veh, &fz_gains[rt]);
            ns2_pilot_set_psi1(pl, psi1[rt]);
            pl->adapt_cfg = ac;
            ns2_pilot_reset(pl, veh);
        }
        /* the swarm: robots on circles around the origin, any radio ids (the own one too) */
        uint8_t ids[PILOT_SWARM], types[PILOT_SWARM];
        float ang[PILOT_SWARM], rad[PILOT_SWARM];
        const uint32_t n_swarm = below(PILOT_SWARM + 1u);
        for (uint32_t i = 0; i < n_swarm; ++i) {
            ids[i] = (uint8_t)below(256);
            types[i] = (uint8_t)below(NS2_NUM_ROBOT_TYPES);
            ang[i] = uniform(0.0f, 6.2832f);
            rad[i] = uniform(0.2f, 1.0f);
        }
        /* good flight, glitches, then good input again from a millisecond k = 9 on (the
         * sane parameters set there); in a quarter of the runs ("chaos") the parameters
         * change at any millisecond and the glitches end with a reset on the ground */
        const uint32_t tick0 = (uint32_t)below(1u << 30), n_good = below(200);
        uint32_t end_bad = n_good + 1u + below(150);
        while ((tick0 + end_bad) % 10u != 9u) {
            ++end_bad;
        }
        const int chaos = below(4) == 0u;
        const uint32_t ending = chaos ? 2u : below(3); /* 0 nothing, 1 a non-finite state, 2 a reset */
        uint32_t now = (uint32_t)rnd();
        float lim_a = cfg.fa_limit_g, lim_b = cfg.fa_limit_g;
        int same = 1; /* A and B must agree */
        for (uint32_t j = 0; j < end_bad + PILOT_RECOVERY_MS + PILOT_HOVER_MS; ++j, ++done) {
            const uint32_t tick = tick0 + j, k = tick % 10u;
            const int bad = j >= n_good && j < end_bad;
            now += 1u;
            if (bad && below(64) == 0u) {
                now += below(2) ? (uint32_t)rnd() : below(5000); /* the clock jumps */
            }
            for (uint32_t m = below(4); m > 0u && n_swarm > 0u; --m) { /* positions received this ms */
                const uint32_t i = below(n_swarm);
                const float a = ang[i] + 1e-3f * (float)j;
                float p[3] = {rad[i] * cosf(a), rad[i] * sinf(a), 1.0f + 0.1f * (float)(i % 3u)};
                uint8_t id = ids[i], type = types[i];
                uint32_t t = now;
                if (bad && below(4) == 0u) {
                    hostile(p, 3);
                    id = below(2) ? (uint8_t)below(256) : id;
                    type = below(2) ? (uint8_t)below(256) : type;
                    t = below(2) ? (uint32_t)rnd() : t;
                }
                check(ns2_pilot_peer(&A, id, type, t, p) == ns2_pilot_peer(&B, id, type, t, p),
                      "pilot: the peer tables answer differently");
            }
            ns2_ctrl_state_t s;
            ns2_setpoint_t sp;
            float fa_unused[3], bat = uniform(3.6f, 4.2f);
            good_tick(&s, &sp, fa_unused, j / 2u); /* (its k: 500 Hz ticks) */
            if (j >= end_bad) {
                sp.yaw = 0.0f; /* hover: the state's yaw (a yaw manoeuvre open loop saturates the small robot) */
            }
            int reset = j == end_bad && ending == 2u; /* the first good millisecond */
            if (bad) {
                switch (below(10)) {
                case 0: hostile(s.p, 3); hostile(s.v, 3); break;
                case 1: hostile(s.q, 4); hostile(s.w, 3); break;
                case 2: { /* a quaternion not normalised */
                    const float f = below(2) ? uniform(0.6f, 1.8f) : uniform(0.0f, 4.0f);
                    for (int a = 0; a < 4; ++a) {
                        s.q[a] *= f;
                    }
                    break;
                }
                case 3: hostile(sp.p, 3); hostile(sp.v, 3); hostile(sp.a, 3); hostile(&sp.yaw, 1); break;
                case 4: sp.p[below(3)] = uniform(-1e3f, 1e3f); break; /* absurd but within the limits */
                case 5: bat = below(2) ? special() : uniform(-5.0f, 20.0f); break;
                case 6: reset = below(4) == 0u; break; /* on the ground, at any millisecond */
                default: break;
                }
                if (ending == 1u && j + 1u == end_bad) {
                    s.w[below(3)] = NAN;
                }
                if (below(8) == 0u) {
                    pilot_cfg_change(&cfg, &ac, 50u, chaos ? 7u : k == 9u ? 6u : 4u);
                    same = same && !chaos; /* from here on until a reset */
                }
            } else if (j < n_good && below(200) == 0u) {
                reset = 1;
            }
            if (j == end_bad) { /* sane parameters again (k = 9) */
                const uint8_t fixed = cfg.fixed; /* (the path changes only in chaos runs, before their reset) */
                ns2_pilot_default_cfg(&cfg, rt);
                cfg.fixed = fixed;
                cfg.phi_per_tick = (uint8_t)below(9);
                cfg.fa_limit_g = uniform(0.0f, 30.0f);
                random_adapt_cfg(&ac, 0u);
                ac.enable = 0u; /* the label of an open-loop state is no measurement: it would learn the mismatch */
            }
            if (reset) { /* the app resets and skips the pilot */
                ns2_pilot_reset(&A, veh);
                ns2_pilot_reset(&B, veh);
                same = 1;
            } else {
                A.cfg = B.cfg = cfg; /* live parameters, every millisecond as the app */
                A.adapt_cfg = B.adapt_cfg = ac;
                const int finishing = k == 9u && A.job_begun;
                lim_a = finishing ? cfg.fa_limit_g : lim_a;
                ns2_pilot_step(&A, &s, &sp, tick, self_id, now, bat);
                n_ok += finishing && A.status == NS2_OK && A.n_used > 0u;
                if (tick % 2u == 0u) {
                    if (k == 0u && B.job_begun) {
                        lim_b = cfg.fa_limit_g;
                    }
                    ns2_pilot_tick(&B, &s, &sp, k == 0u, self_id, now, bat);
                }
            }
            check_pilot(&A, lim_a, veh->f_max_N);
            check_pilot(&B, lim_b, veh->f_max_N);
            if (same && tick % 2u == 0u) {
                check(memcmp(A.ctrl.pwm, B.ctrl.pwm, sizeof A.ctrl.pwm) == 0 &&
                          bits_of(A.fa_hat_g) == bits_of(B.fa_hat_g) && A.n_used == B.n_used && A.status == B.status,
                      "pilot: ns2_pilot_step differs from ns2_pilot_tick");
            }
            if (j >= end_bad + PILOT_RECOVERY_MS) {
                pilot_check_hover(&A, veh, ending != 0u);
                pilot_check_hover(&B, veh, ending != 0u);
            }
        }
    }
    input_index = done;
#else
    (void)count;
    fail("the export has no vehicle parameters (NS2_HAVE_VEHICLES 0)");
#endif
}

/* ------------------------------------------------------------------ HIL parser */
static uint16_t last_pong_seq;
static int got_pong;
static unsigned long long frames_out;

static uint16_t le16(const uint8_t *p) { return (uint16_t)(p[0] | (uint16_t)(p[1] << 8)); }

static void hil_write(const uint8_t *d, uint16_t n)
{
    ++frames_out;
    check(n >= 9u && d[0] == NS2_HIL_SYNC0 && d[1] == NS2_HIL_SYNC1, "reply frame too short or unsynced");
    const uint16_t len = le16(&d[2]);
    check((uint32_t)len + 6u == n, "reply length field differs from the bytes sent");
    check(le16(&d[4u + len]) == ns2_hil_crc16(&d[2], (uint16_t)(len + 2u), 0xFFFFu), "reply CRC wrong");
    const uint8_t type = d[4];
    check(type == NS2_HIL_RESULT || type == NS2_HIL_PONG || type == NS2_HIL_ERROR, "unknown reply type");
    if (type == NS2_HIL_RESULT) {
        check(len == 3u + 18u, "RESULT body not 18 bytes");
        n_ok += len == 3u + 18u && le16(&d[7]) == 0u && le16(&d[9]) == 0u && le16(&d[17]) > 0u; /* NS2_OK, n_used */
    }
    if (type == NS2_HIL_PONG) {
        got_pong = 1;
        last_pong_seq = le16(&d[5]);
    }
}

static uint16_t make_frame(uint8_t *out, uint8_t type, uint16_t seq, const uint8_t *body, uint16_t n)
{
    const uint16_t len = (uint16_t)(3u + n);
    out[0] = NS2_HIL_SYNC0;
    out[1] = NS2_HIL_SYNC1;
    out[2] = (uint8_t)(len & 0xFFu);
    out[3] = (uint8_t)(len >> 8);
    out[4] = type;
    out[5] = (uint8_t)(seq & 0xFFu);
    out[6] = (uint8_t)(seq >> 8);
    memcpy(&out[7], body, n);
    const uint16_t crc = ns2_hil_crc16(&out[2], (uint16_t)(2u + len), 0xFFFFu);
    out[7u + n] = (uint8_t)(crc & 0xFFu);
    out[8u + n] = (uint8_t)(crc >> 8);
    return (uint16_t)(9u + n);
}

#define HIL_NB_BYTES (1u + 4u * NS2_INPUT_DIM)          /* u8 type, f32 rel[NS2_INPUT_DIM] */
#define HIL_PAST_BYTES (24u * NS2_HISTORY_LAGS)           /* f32 own_past[6 NS2_HISTORY_LAGS] */
#define HIL_FIT ((NS2_HIL_MAX_PAYLOAD - 8u - 26u - HIL_PAST_BYTES) / HIL_NB_BYTES) /* room for the padding */

static uint16_t predict_body(uint8_t *b)
{
    static ns2_neighbor_t nb[NB_CAP];
    uint8_t rt;
    float p[3], v[3];
    uint16_t n = random_query(&rt, p, v, nb, 8u);
    const uint16_t cap = NS2_HIL_MAX_NEIGHBORS < HIL_FIT ? NS2_HIL_MAX_NEIGHBORS : HIL_FIT;
    if (n > cap) {
        n = cap;
    }
    b[0] = rt;
    b[1] = (uint8_t)(below(16) == 0 ? below(256) : n); /* sometimes a lying count */
    memcpy(&b[2], p, 12);
    memcpy(&b[14], v, 12);
    for (uint16_t j = 0; j < n; ++j) {
        b[26u + HIL_NB_BYTES * j] = nb[j].type;
        memcpy(&b[27u + HIL_NB_BYTES * j], nb[j].rel, 4u * NS2_INPUT_DIM);
    }
#if NS2_HISTORY_LAGS > 0
    memcpy(&b[26u + HIL_NB_BYTES * n], fz_past, HIL_PAST_BYTES); /* NULL is not sent: the body carries one */
#endif
    uint16_t len = (uint16_t)(26u + HIL_NB_BYTES * n + HIL_PAST_BYTES);
    if (below(16) == 0) {
        len = (uint16_t)below(len + 8u); /* truncated or padded body */
    }
    return len;
}

static void fuzz_hil(unsigned long long count)
{
    static ns2_hil_t h;
    static uint8_t stream[4096], body[NS2_HIL_MAX_PAYLOAD];
    ns2_hil_init(&h, hil_write);
    for (input_index = 0; input_index < count; ++input_index) {
        uint16_t n = 0;
        const uint32_t pieces = 1u + below(4);
        for (uint32_t k = 0; k < pieces && n < sizeof stream - 1100u; ++k) {
            const uint32_t kind = below(8);
            if (kind <= 2u) { /* PING, any length the frame allows */
                const uint16_t m = (uint16_t)(below(4) == 0 ? below(NS2_HIL_MAX_PAYLOAD - 2u) : below(64));
                for (uint16_t i = 0; i < m; ++i) {
                    body[i] = (uint8_t)rnd();
                }
                n = (uint16_t)(n + make_frame(&stream[n], NS2_HIL_PING, (uint16_t)rnd(), body, m));
            } else if (kind <= 4u) {
                const uint16_t m = predict_body(body);
                n = (uint16_t)(n + make_frame(&stream[n], below(8) ? NS2_HIL_PREDICT : (uint8_t)rnd(),
                                              (uint16_t)rnd(), body, m));
            } else if (kind == 5u) { /* garbage, with sync bytes sprinkled in */
                const uint16_t m = (uint16_t)below(200);
                for (uint16_t i = 0; i < m; ++i) {
                    stream[n++] = below(8) == 0 ? (below(2) ? NS2_HIL_SYNC0 : NS2_HIL_SYNC1) : (uint8_t)rnd();
                }
            } else { /* a valid frame with flipped bits or a lying length */
                const uint16_t m = (uint16_t)below(40);
                for (uint16_t i = 0; i < m; ++i) {
                    body[i] = (uint8_t)rnd();
                }
                const uint16_t fl = make_frame(&stream[n], NS2_HIL_PING, (uint16_t)rnd(), body, m);
                if (below(2)) {
                    stream[n + below(fl)] ^= (uint8_t)(1u << below(8));
                } else {
                    stream[n + 2u + below(2)] = (uint8_t)rnd();
                }
                n = (uint16_t)(n + fl);
            }
        }
        for (uint16_t i = 0; i < n; ++i) {
            ns2_hil_feed(&h, stream[i]);
        }
        if (input_index % 16u == 0u) { /* recovery: a good PING is answered within a bounded stream */
            uint8_t ping[16];
            const uint16_t seq = (uint16_t)(0x4000u + (input_index & 0x3FFFu));
            const uint16_t fl = make_frame(ping, NS2_HIL_PING, seq, (const uint8_t *)"recover", 7u);
            got_pong = 0;
            int answered = 0;
            /* a pending frame waits for at most 6 + MAX_PAYLOAD bytes, then resynchronizes */
            for (uint32_t rep = 0; rep < (6u + NS2_HIL_MAX_PAYLOAD) / fl + 3u && !answered; ++rep) {
                for (uint16_t i = 0; i < fl; ++i) {
                    ns2_hil_feed(&h, ping[i]);
                }
                answered = got_pong && last_pong_seq == seq;
            }
            check(answered, "parser did not recover: no PONG to a good PING");
        }
    }
    check(frames_out > 0u, "no reply at all");
}

/* ------------------------------------------------------------------ regressions */
/* The smallest triggers of issue 17 (D1-D3), run once each. */
static void regress(void)
{
    static ns2_hil_t h;
    uint8_t body[40], fr[64];
    target_name = "regress-D1";
    for (uint16_t m = 30; m <= 40; ++m) { /* PING bodies of 33-34 and >= 35 bytes */
        memset(body, 0x5A, sizeof body);
        ns2_hil_init(&h, hil_write);
        got_pong = 0;
        const uint16_t fl = make_frame(fr, NS2_HIL_PING, 77u, body, m);
        for (uint16_t i = 0; i < fl; ++i) {
            ns2_hil_feed(&h, fr[i]);
        }
        check(got_pong && last_pong_seq == 77u, "no PONG to a long PING");
    }
#if NS2_HAVE_VEHICLES
    static ns2_ctrl_t c;
    ns2_ctrl_state_t s;
    ns2_setpoint_t sp;
    float fa[3];
    for (int trig = 0; trig < 4; ++trig) {
        target_name = "regress-D2";
        ns2_ctrl_init(&c, &fz_veh[0], &fz_gains[0]);
        for (uint32_t k = 0; k < 5u * 200u; ++k) {
            good_tick(&s, &sp, fa, k);
            float dt_att = 0.002f;
            if (k == 500u) {
                if (trig == 0) sp.yaw = 1e12f;
                if (trig == 1) dt_att = INFINITY;
                if (trig == 2) s.w[0] = 1e38f;
                if (trig == 3) sp.p[0] = 1e20f;
            }
            if (k % 5u == 0u) {
                ns2_ctrl_position(&c, &s, &sp, fa, 0.01f);
            }
            ns2_ctrl_attitude(&c, &s, dt_att, 3.9f);
            check_outputs(&c, fz_veh[0].f_max_N);
            if (k > 600u) {
                check((c.status & ~(uint32_t)NS2_CTRL_SATURATED) == 0u && c.pwm[0] > 0.0f,
                      "controller did not recover within 0.2 s");
            }
        }
    }
#endif
    target_name = "regress-D3";
    static ns2_peers_t ps;
    ns2_peers_init(&ps, 0.5f);
    float p[3] = {0.0f, 0.0f, 1.0f};
    check(ns2_peers_update(&ps, 3u, 0u, 1000u, p) == NS2_PEERS_OK, "first sample");
    p[0] = 1e37f;
    check(ns2_peers_update(&ps, 3u, 0u, 1010u, p) == NS2_PEERS_REJECTED, "x = 1e37 m accepted");
    for (uint32_t k = 0; k < 1000u; ++k) { /* 10 s of good samples, 0.5 m/s in x */
        p[0] = 0.005f * (float)(k + 1u);
        (void)ns2_peers_update(&ps, 3u, 0u, 1010u + 10u * k, p);
    }
    check(isfinite(ps.peer[0].v[0]) && fabsf(ps.peer[0].v[0] - 0.5f) < 1e-3f, "velocity not recovered");
    ns2_neighbor_t out[4];
    const float z[3] = {0.0f, 0.0f, 0.0f};
    check(ns2_peers_neighbors(&ps, 9u, z, z, 11000u, 100u, out, 4u) == 1u, "peer missing");
    ns2_info_t info;
#if NS2_HISTORY_LAGS > 0
    const float own[6u * NS2_HISTORY_LAGS] = {0.0f};
    (void)ns2_predict_f32_hist(0u, z, z, own, out, 1u, &info);
#else
    (void)ns2_predict_f32(0u, z, z, out, 1u, &info);
#endif
    check(info.status == NS2_OK && info.n_invalid == 0u, "peer counted invalid by the prediction");
    input_index = 1;
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: %s infer|sliced|peers|ctrl|adapt|pilot|hil|regress COUNT SEED\n", argv[0]);
        return 2;
    }
    target_name = argv[1];
    const unsigned long long count = strtoull(argv[2], NULL, 10);
    rng_state = strtoull(argv[3], NULL, 10) * 0x2545F4914F6CDD1Dull + 1u;
    if (strcmp(argv[1], "infer") == 0) {
        fuzz_infer(count);
    } else if (strcmp(argv[1], "sliced") == 0) {
        fuzz_sliced(count);
    } else if (strcmp(argv[1], "peers") == 0) {
        fuzz_peers(count);
    } else if (strcmp(argv[1], "ctrl") == 0) {
        fuzz_ctrl(count);
    } else if (strcmp(argv[1], "adapt") == 0) {
        fuzz_adapt(count);
    } else if (strcmp(argv[1], "pilot") == 0) {
        fuzz_pilot(count);
    } else if (strcmp(argv[1], "hil") == 0) {
        fuzz_hil(count);
    } else if (strcmp(argv[1], "regress") == 0) {
        regress();
    } else {
        fprintf(stderr, "unknown target %s\n", argv[1]);
        return 2;
    }
    printf("{\"target\": \"%s\", \"inputs\": %llu, \"checks\": %llu, \"input_dim\": %d, \"predictions_ok\": %llu}\n",
           argv[1], input_index, n_checks, (int)NS2_INPUT_DIM, n_ok);
    return 0;
}
