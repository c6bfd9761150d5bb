/*
 * ns2_select.c - neighbour selection shared by the float and fixed-point paths:
 * interaction volume V (paper, "Heterogeneous Swarm Dynamics"), the neighbour
 * limit and the input box.
 */
#include <float.h>
#include <stddef.h>

#include "ns2_internal.h"

/* x * 0 is +-0 for a finite x and NaN for an infinite or NaN one, and a sum of
 * +-0 is +-0: one multiply and one add per value, no branch (a NaN or an
 * infinity anywhere makes the sum NaN, which is not 0). */
static int all_finite(const float *x, int n)
{
    float z = 0.0f;
    for (int i = 0; i < n; ++i) {
        z += x[i] * 0.0f;
    }
    return z == 0.0f;
}

/* p_j - p_i inside the cuboid V(robot type, neighbour type); false for NaN. */
static int in_volume(uint8_t robot_type, uint8_t nbr_type, const float rel[6])
{
    const float(*v)[3] = ns2_volume[robot_type][nbr_type];
    for (int a = 0; a < 3; ++a) {
        if (!(rel[a] >= v[0][a] && rel[a] <= v[1][a])) {
            return 0;
        }
    }
    return 1;
}

uint16_t ns2_select_neighbors(uint8_t robot_type, const ns2_neighbor_t *neighbors,
                              uint16_t n_neighbors, uint16_t idx[NS2_MAX_NEIGHBORS],
                              ns2_info_t *info)
{
    uint16_t used = 0;
    info->n_used = 0;
    info->n_invalid = 0;
    info->n_outside = 0;
    info->n_truncated = 0;
    if (robot_type >= NS2_NUM_ROBOT_TYPES || neighbors == NULL) {
        return 0;
    }
    for (uint16_t j = 0; j < n_neighbors; ++j) {
        const ns2_neighbor_t *nb = &neighbors[j];
        if (nb->type >= NS2_NUM_ROBOT_TYPES || !all_finite(nb->rel, NS2_INPUT_DIM)) {
            info->n_invalid++;
        } else if (!in_volume(robot_type, nb->type, nb->rel)) {
            info->n_outside++;
        } else if (used >= NS2_MAX_NEIGHBORS) {
            info->n_truncated++;
        } else {
            idx[used++] = j;
        }
    }
    info->n_used = used;
    return used;
}

/* o = x clamped to [lo, hi] as ns2_clamp_input does, for a finite x; bad set for
 * an infinite or NaN x (only tested outside the box: x >= lo is false for NaN).
 * A macro: -Os would call a function per value. */
#define NS2_CLAMP_CHK(o, x, lo, hi, bad)                                                                       \
    do {                                                                                                       \
        const float x_ = (x);                                                                                  \
        if (x_ >= (lo)) {                                                                                      \
            if (x_ > (hi)) {                                                                                   \
                (bad) |= x_ > FLT_MAX; /* +inf */                                                              \
                (o) = (hi);                                                                                    \
            } else {                                                                                           \
                (o) = x_;                                                                                      \
            }                                                                                                  \
        } else {                                                                                               \
            (bad) |= !(x_ >= -FLT_MAX); /* NaN or -inf */                                                      \
            (o) = (lo);                                                                                        \
        }                                                                                                      \
    } while (0)

/* ns2_clamp_input into out, and whether every input is finite: one pass, the box
 * read once (not per 6-block); out is meaningless for an input that is not finite */
static int clamp_finite(uint8_t t, const float in[NS2_INPUT_DIM], float out[NS2_INPUT_DIM])
{
    const float(*box)[2] = ns2_input_box[t < NS2_NUM_NEIGHBOR_TYPES ? t : NS2_ENV_TYPE];
    const float l0 = box[0][0], h0 = box[0][1], l1 = box[1][0], h1 = box[1][1], l2 = box[2][0], h2 = box[2][1];
    const float l3 = box[3][0], h3 = box[3][1], l4 = box[4][0], h4 = box[4][1], l5 = box[5][0], h5 = box[5][1];
    int bad = 0;
    for (int k = 0; k < NS2_INPUT_DIM; k += 6) { /* now, then each history lag: the same box */
        const float *x = &in[k];
        float *o = &out[k];
        NS2_CLAMP_CHK(o[0], x[0], l0, h0, bad);
        NS2_CLAMP_CHK(o[1], x[1], l1, h1, bad);
        NS2_CLAMP_CHK(o[2], x[2], l2, h2, bad);
        NS2_CLAMP_CHK(o[3], x[3], l3, h3, bad);
        NS2_CLAMP_CHK(o[4], x[4], l4, h4, bad);
        NS2_CLAMP_CHK(o[5], x[5], l5, h5, bad);
    }
    return !bad;
}

void ns2_clamp_input(uint8_t t, const float in[NS2_INPUT_DIM], float out[NS2_INPUT_DIM])
{
    const float(*box)[2] = ns2_input_box[t < NS2_NUM_NEIGHBOR_TYPES ? t : NS2_ENV_TYPE];
    for (int k = 0; k < NS2_INPUT_DIM; k += 6) { /* now, then each history lag: the same box */
        for (int a = 0; a < 6; ++a) {
            const float x = in[k + a];
            out[k + a] = x < box[a][0] ? box[a][0] : (x > box[a][1] ? box[a][1] : x);
        }
    }
}

/* own_past usable: not read without history, else present and finite */
static int own_past_ok(const float *own_past)
{
#if NS2_HISTORY_LAGS > 0
    return own_past != NULL && all_finite(own_past, 6 * NS2_HISTORY_LAGS);
#else
    (void)own_past;
    return 1;
#endif
}

/* Validate the query and build the clamped x_env (the part of ns2_prepare before
 * the selection); zeroes info's counters.  Returns info->status. */
static int32_t prepare_env(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                           const ns2_neighbor_t *neighbors, uint16_t n_neighbors, float x_env[NS2_INPUT_DIM],
                           ns2_info_t *info)
{
    info->status = NS2_OK;
    info->n_used = 0;
    info->n_invalid = 0;
    info->n_outside = 0;
    info->n_truncated = 0;
    if (robot_type >= NS2_NUM_ROBOT_TYPES) {
        info->status = NS2_ERR_ROBOT_TYPE;
    } else if (p == NULL || v == NULL || !all_finite(p, 3) || !all_finite(v, 3) || !own_past_ok(own_past)) {
        info->status = NS2_ERR_STATE;
    } else if (n_neighbors > 0 && neighbors == NULL) {
        info->status = NS2_ERR_NULL;
    } else {
        float env[NS2_INPUT_DIM] = {-p[0], -p[1], -p[2], -v[0], -v[1], -v[2]};
#if NS2_HISTORY_LAGS > 0
        for (int k = 6; k < NS2_INPUT_DIM; ++k) { /* the own past, [p; v] at each lag */
            env[k] = -own_past[k - 6];
        }
#endif
        ns2_clamp_input(NS2_ENV_TYPE, env, x_env);
    }
    return info->status;
}

/* Shared prologue of both predict functions: validate, build x_env, select. */
int32_t ns2_prepare(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                    const ns2_neighbor_t *neighbors, uint16_t n_neighbors,
                    float x_env[NS2_INPUT_DIM], uint16_t idx[NS2_MAX_NEIGHBORS], uint16_t *n_used,
                    ns2_info_t *info)
{
    *n_used = 0;
    if (prepare_env(robot_type, p, v, own_past, neighbors, n_neighbors, x_env, info) == NS2_OK) {
        *n_used = ns2_select_neighbors(robot_type, neighbors, n_neighbors, idx, info);
    }
    return info->status;
}

int32_t ns2_job_begin(ns2_job_t *job, uint8_t robot_type, const float p[3], const float v[3],
                      const ns2_neighbor_t *neighbors, uint16_t n_neighbors)
{
    return ns2_job_begin_hist(job, robot_type, p, v, NULL, neighbors, n_neighbors);
}

/* ns2_prepare and the copy of the selected inputs in one pass: each neighbour's
 * inputs are checked while they are clamped into the job's next row (a neighbour
 * left out is overwritten by the next one); the same selection, counters and
 * clamped inputs as ns2_select_neighbors followed by ns2_clamp_input. */
int32_t ns2_job_begin_hist(ns2_job_t *job, uint8_t robot_type, const float p[3], const float v[3],
                           const float *own_past, const ns2_neighbor_t *neighbors, uint16_t n_neighbors)
{
    uint16_t used = 0;
    if (job == NULL) {
        return NS2_ERR_JOB;
    }
    job->robot_type = robot_type;
    job->next = 0;
    job->n_inputs = 0;
    job->path = NS2_JOB_NONE;
    if (prepare_env(robot_type, p, v, own_past, neighbors, n_neighbors, job->x[0], &job->info) != NS2_OK) {
        return job->info.status;
    }
    job->type[0] = NS2_ENV_TYPE;
    for (uint16_t j = 0; j < n_neighbors; ++j) {
        const ns2_neighbor_t *nb = &neighbors[j];
        if (nb->type >= NS2_NUM_ROBOT_TYPES) {
            job->info.n_invalid++;
            continue;
        }
        const int finite = used < NS2_MAX_NEIGHBORS ? clamp_finite(nb->type, nb->rel, job->x[used + 1u])
                                                    : all_finite(nb->rel, NS2_INPUT_DIM);
        if (!finite) {
            job->info.n_invalid++;
        } else if (!in_volume(robot_type, nb->type, nb->rel)) {
            job->info.n_outside++;
        } else if (used >= NS2_MAX_NEIGHBORS) {
            job->info.n_truncated++;
        } else {
            job->type[used + 1u] = nb->type;
            used++;
        }
    }
    job->info.n_used = used;
    job->n_inputs = (uint16_t)(used + 1u);
    job->path = NS2_JOB_FRESH;
    return NS2_OK;
}

int ns2_job_claim(ns2_job_t *job, uint8_t path)
{
    if (job == NULL || job->path == NS2_JOB_NONE) {
        return 0;
    }
    if (job->path == NS2_JOB_FRESH) {
        job->path = path;
    }
    return job->path == path;
}

void ns2_job_info(const ns2_job_t *job, int claimed, ns2_info_t *info)
{
    if (info == NULL) {
        return;
    }
    if (job == NULL) {
        const ns2_info_t none = {NS2_ERR_JOB, 0, 0, 0, 0};
        *info = none;
        return;
    }
    *info = job->info;
    if (!claimed && info->status == NS2_OK) {
        info->status = NS2_ERR_JOB; /* never begun, or stepped by the other path */
    }
}
