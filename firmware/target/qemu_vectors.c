/*
 * qemu_vectors.c - test image: reads query vectors from ns2_in.bin through
 * semihosting, runs the float and fixed-point inference on the (emulated)
 * STM32F405, one-shot (ns2_predict_*) and in slices (ns2_job_*, 1 + k mod 5 phi
 * evaluations per step for query k), and writes the results to ns2_out.bin.
 * A model with wake memory reads the robot's own past after the neighbours and
 * runs the *_hist entry points.  Formats: host/target.py.
 */
#include <stdio.h>
#include <string.h>

#include "ns2_deepset.h"

#define MAX_GIVEN 64u

typedef struct {
    uint8_t robot_type;
    uint8_t pad;
    uint16_t n;
    float p[3];
    float v[3];
} query_t;

typedef struct {
    float f32;
    int16_t q15;
    uint16_t pad;
    ns2_info_t info_f32;
    ns2_info_t info_q15;
    float f32_sliced;
    int16_t q15_sliced;
    uint16_t pad2;
} result_t;

static ns2_neighbor_t neighbors[MAX_GIVEN];
static ns2_job_t job;
static float own_past[6u * NS2_HISTORY_LAGS + 1u]; /* [p; v] at each lag (not read without history) */

/* The sliced API with `slice` phi evaluations per step; the job is begun again
 * for each path. */
static void run_sliced(const query_t *q, uint16_t slice, result_t *r)
{
    (void)ns2_job_begin_hist(&job, q->robot_type, q->p, q->v, own_past, neighbors, q->n);
    while (ns2_job_step_f32(&job, slice) > 0u) {
    }
    r->f32_sliced = ns2_job_finish_f32(&job, NULL);
    (void)ns2_job_begin_hist(&job, q->robot_type, q->p, q->v, own_past, neighbors, q->n);
    while (ns2_job_step_q15(&job, slice) > 0u) {
    }
    r->q15_sliced = ns2_job_finish_q15(&job, NULL);
}

int main(void)
{
    FILE *in = fopen("ns2_in.bin", "rb");
    FILE *out = fopen("ns2_out.bin", "wb");
    char magic[4];
    uint32_t count = 0;
    if (in == NULL || out == NULL || fread(magic, 1, 4, in) != 4 || memcmp(magic, "NS2V", 4) != 0 ||
        fread(&count, sizeof count, 1, in) != 1) {
        return 2;
    }
    for (uint32_t k = 0; k < count; ++k) {
        query_t q;
        result_t r;
        if (fread(&q, sizeof q, 1, in) != 1 || q.n > MAX_GIVEN ||
            (q.n > 0 && fread(neighbors, sizeof neighbors[0], q.n, in) != q.n) ||
            fread(own_past, sizeof own_past[0], 6u * NS2_HISTORY_LAGS, in) != 6u * NS2_HISTORY_LAGS) {
            return 4;
        }
        memset(&r, 0, sizeof r);
#if NS2_HISTORY_LAGS > 0
        r.f32 = ns2_predict_f32_hist(q.robot_type, q.p, q.v, own_past, neighbors, q.n, &r.info_f32);
        r.q15 = ns2_predict_q15_hist(q.robot_type, q.p, q.v, own_past, neighbors, q.n, &r.info_q15);
#else
        r.f32 = ns2_predict_f32(q.robot_type, q.p, q.v, neighbors, q.n, &r.info_f32);
        r.q15 = ns2_predict_q15(q.robot_type, q.p, q.v, neighbors, q.n, &r.info_q15);
#endif
        run_sliced(&q, (uint16_t)(1u + k % 5u), &r);
        if (fwrite(&r, sizeof r, 1, out) != 1) {
            return 5;
        }
    }
    fclose(out);
    fclose(in);
    return 0;
}
