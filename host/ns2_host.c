/* ns2_host.c - see ns2_host.h. */
#define _POSIX_C_SOURCE 199309L
#include <time.h>

#include "ns2_host.h"

/* One query through the sliced API: begin, steps of `slice` phi evaluations, finish. */
static void predict_sliced(int fixed, uint16_t slice, uint8_t robot_type, const float p[3], const float v[3],
                           const float *past, const ns2_neighbor_t *nb, uint16_t n, float *out_f, int16_t *out_q,
                           ns2_info_t *info)
{
    ns2_job_t job;
    if (past != (const float *)0) {
        (void)ns2_job_begin_hist(&job, robot_type, p, v, past, nb, n);
    } else {
        (void)ns2_job_begin(&job, robot_type, p, v, nb, n);
    }
    if (fixed) {
        while (ns2_job_step_q15(&job, slice) > 0u) {
        }
        *out_q = ns2_job_finish_q15(&job, info);
    } else {
        while (ns2_job_step_f32(&job, slice) > 0u) {
        }
        *out_f = ns2_job_finish_f32(&job, info);
    }
}

void ns2_host_predict_batch(int fixed, uint16_t slice, uint32_t n_queries, const uint8_t *robot_type,
                            const float *p, const float *v, const float *past, const uint32_t *offsets,
                            const ns2_neighbor_t *neighbors, float *out_f, int16_t *out_q,
                            ns2_info_t *infos)
{
    for (uint32_t q = 0; q < n_queries; ++q) {
        const uint16_t n = (uint16_t)(offsets[q + 1] - offsets[q]);
        const ns2_neighbor_t *nb = n ? &neighbors[offsets[q]] : (const ns2_neighbor_t *)0;
        const float *pq = past != (const float *)0 ? &past[6u * NS2_HISTORY_LAGS * q] : (const float *)0;
        if (slice > 0u) {
            predict_sliced(fixed, slice, robot_type[q], &p[3 * q], &v[3 * q], pq, nb, n, &out_f[q], &out_q[q],
                           &infos[q]);
        } else if (pq != (const float *)0 && fixed) {
            out_q[q] = ns2_predict_q15_hist(robot_type[q], &p[3 * q], &v[3 * q], pq, nb, n, &infos[q]);
        } else if (pq != (const float *)0) {
            out_f[q] = ns2_predict_f32_hist(robot_type[q], &p[3 * q], &v[3 * q], pq, nb, n, &infos[q]);
        } else if (fixed) {
            out_q[q] = ns2_predict_q15(robot_type[q], &p[3 * q], &v[3 * q], nb, n, &infos[q]);
        } else {
            out_f[q] = ns2_predict_f32(robot_type[q], &p[3 * q], &v[3 * q], nb, n, &infos[q]);
        }
    }
}

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

double ns2_host_ns_per_call(int fixed, uint32_t reps, uint8_t robot_type, const float p[3],
                            const float v[3], const ns2_neighbor_t *neighbors, uint16_t n)
{
    volatile float sink_f = 0.0f;
    volatile int16_t sink_q = 0;
    const double t0 = now_ns();
    for (uint32_t r = 0; r < reps; ++r) {
        if (fixed) {
            sink_q = ns2_predict_q15(robot_type, p, v, neighbors, n, (ns2_info_t *)0);
        } else {
            sink_f = ns2_predict_f32(robot_type, p, v, neighbors, n, (ns2_info_t *)0);
        }
    }
    (void)sink_f;
    (void)sink_q;
    return (now_ns() - t0) / (double)(reps ? reps : 1u);
}

void ns2_host_ctrl_tick(ns2_ctrl_t *ctrls, uint32_t n, const ns2_ctrl_state_t *states,
                        const ns2_setpoint_t *setpoints, const float *fa, int do_pos, float dt_pos,
                        float dt_att, float battery_V, float *pwm_out)
{
    for (uint32_t i = 0; i < n; ++i) {
        if (do_pos) {
            ns2_ctrl_position(&ctrls[i], &states[i], &setpoints[i], fa ? &fa[3 * i] : (const float *)0, dt_pos);
        }
        ns2_ctrl_attitude(&ctrls[i], &states[i], dt_att, battery_V);
        for (int m = 0; m < 4; ++m) {
            pwm_out[4 * i + (uint32_t)m] = ctrls[i].pwm[m];
        }
    }
}
