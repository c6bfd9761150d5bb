/*
 * ns2_deepset.h - heterogeneous deep-set inference of the interaction force f_a,z
 * (Neural-Swarm2, eq. learningmodel-hetero) in float and in fixed point.
 *
 *   f_a,z(i) = rho_{I(i)}( phi_env(x_env) + sum_j phi_{I(j)}(x_ij) )
 *
 * x_ij = [p_j - p_i; v_j - v_i] (m, m/s, world frame); the environment is the
 * neighbour with p_j = v_j = 0, i.e. x_env = [-p_i; -v_i], and is always present.
 *
 * Wake memory (model.history_ms, a model exported with NS2_HISTORY_LAGS > 0): phi
 * also sees each neighbour's x_ij at the lags ns2_history_ms[] (ms) before now,
 * NS2_INPUT_DIM = 6 (1 + NS2_HISTORY_LAGS) inputs: rel[] holds x_ij now, then
 * x_ij at each lag in the order of ns2_history_ms[]; the environment likewise
 * sees the robot's own past, given to the *_hist entry points as own_past[]
 * ([p; v] at each lag, 6 floats per lag).  The selection (type, volume, order)
 * is decided on the present state alone; a past value that is not finite makes
 * the neighbour invalid (a non-finite own past: NS2_ERR_STATE).  Without history
 * NS2_INPUT_DIM is 6 and the API is the plain one.
 *
 * Neighbour handling (identical for both paths, see ns2_select_neighbors):
 *   - a neighbour with a type >= NS2_NUM_ROBOT_TYPES or a non-finite state is
 *     ignored (counted in n_invalid);
 *   - a neighbour outside the interaction volume V(robot type, neighbour type),
 *     a cuboid on p_j - p_i, is ignored (n_outside);
 *   - the first NS2_MAX_NEIGHBORS accepted neighbours in array order are used,
 *     later ones are ignored (n_truncated): pass them sorted by priority;
 *   - every phi input is clamped to the declared input box of its type (past
 *     states to the same box as present ones).
 * Float sums run in a fixed order: environment first, then accepted neighbours
 * in array order.  Invalid robot type or non-finite own state: result 0.0 and
 * info->status < 0.
 *
 * No dynamic memory, no recursion; stack use is bounded by NS2_MAX_WIDTH.
 */
#ifndef NS2_DEEPSET_H
#define NS2_DEEPSET_H

#include <stdint.h>

#include "ns2_model_config.h"

/* a model without wake memory: its generated config defines neither */
#ifndef NS2_HISTORY_LAGS
#define NS2_HISTORY_LAGS 0
#define NS2_HISTORY_MAX_MS 0
#endif

#ifdef __cplusplus
extern "C" {
#endif

#define NS2_OK 0
#define NS2_ERR_ROBOT_TYPE (-1) /* robot_type >= NS2_NUM_ROBOT_TYPES */
#define NS2_ERR_STATE (-2)      /* own position/velocity (or own past) NULL or not finite */
#define NS2_ERR_NULL (-3)       /* n_neighbors > 0 but neighbors == NULL */
#define NS2_ERR_JOB (-4)        /* job NULL, not begun, or stepped by the other path */

typedef struct {
    uint8_t type;   /* robot type of the neighbour, 0 .. NS2_NUM_ROBOT_TYPES-1 */
    float rel[NS2_INPUT_DIM]; /* [p_j - p_i (m); v_j - v_i (m/s)], world frame; then the
                                 same at each history lag (NS2_HISTORY_LAGS > 0) */
} ns2_neighbor_t;

typedef struct {
    int32_t status;       /* NS2_OK or NS2_ERR_* */
    uint16_t n_used;      /* robot neighbours fed to phi (the environment not counted) */
    uint16_t n_invalid;   /* bad type or non-finite state */
    uint16_t n_outside;   /* outside the interaction volume */
    uint16_t n_truncated; /* accepted but beyond NS2_MAX_NEIGHBORS */
} ns2_info_t;

/* Indices (into neighbors[]) of the neighbours that take part, in order.
 * Returns their number (<= NS2_MAX_NEIGHBORS); fills the counters of info. */
uint16_t ns2_select_neighbors(uint8_t robot_type, const ns2_neighbor_t *neighbors,
                              uint16_t n_neighbors, uint16_t idx[NS2_MAX_NEIGHBORS],
                              ns2_info_t *info);

/* Clamp a phi input (NS2_INPUT_DIM values: 6 per time) to the input box of
 * neighbour type t (t may be NS2_ENV_TYPE); every 6-block to the same box. */
void ns2_clamp_input(uint8_t t, const float in[NS2_INPUT_DIM], float out[NS2_INPUT_DIM]);

/* f_a,z (g) of a robot of type robot_type at position p (m) with velocity v (m/s).
 * info may be NULL. */
float ns2_predict_f32(uint8_t robot_type, const float p[3], const float v[3],
                      const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);

/* Fixed-point inference (int16 weights/activations, int32 accumulators).
 * Returns f_a,z in Q format NS2_Q_OUT_FRAC (grams * 2^NS2_Q_OUT_FRAC), saturated
 * to int16; 0 on error. */
int16_t ns2_predict_q15(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);

/* ns2_predict_q15 converted to grams (exact: q * 2^-NS2_Q_OUT_FRAC). */
float ns2_predict_q15_g(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);

/* The same with the robot's own past for a model with wake memory: own_past holds
 * 6 NS2_HISTORY_LAGS floats, [p; v] (m, m/s) at each lag of ns2_history_ms[]; it
 * is not read (and may be NULL) when NS2_HISTORY_LAGS is 0.  The plain entry
 * points are these with own_past NULL: for a model with wake memory they return
 * 0 with NS2_ERR_STATE. */
float ns2_predict_f32_hist(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                           const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);
int16_t ns2_predict_q15_hist(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                             const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);

/*
 * Prediction in slices, to spread one prediction over several control ticks
 * (e.g. the five 500 Hz attitude ticks of one 100 Hz position period):
 *
 *   ns2_job_begin(&job, type, p, v, nb, n);        selects and copies the inputs
 *   ns2_job_step_q15(&job, 4);                      up to 4 phi evaluations per call
 *   ...
 *   int16_t fa = ns2_job_finish_q15(&job, &info);   remaining phi, then rho
 *
 * The neighbour array is only read by ns2_job_begin (the clamped phi inputs
 * are copied into the job).  The result is bit for bit that of
 * ns2_predict_q15/_f32 on the same arguments, however the work is sliced: the
 * same operations run in the same order.  A job is stepped and finished by one
 * path (_f32 or _q15); the other path's calls return NS2_ERR_JOB (result 0),
 * as do the calls on a job that was never begun but zero-initialized (static).
 * ns2_job_step_* returns the number of phi evaluations still to do (0 when the
 * job failed, is finished or is not begun).
 */
typedef struct {
    ns2_info_t info;
    uint8_t robot_type;
    uint8_t path;                                /* internal: not begun, f32, q15 or fresh */
    uint16_t n_inputs;                           /* phi inputs: the environment + info.n_used */
    uint16_t next;                               /* next phi input to evaluate */
    uint8_t type[NS2_MAX_NEIGHBORS + 1];         /* neighbour type of each phi input */
    float x[NS2_MAX_NEIGHBORS + 1][NS2_INPUT_DIM]; /* clamped phi inputs, environment first */
    float h_f32[NS2_HIDDEN];                     /* latent sum, float path */
    int32_t h_q15[(NS2_HIDDEN + 3) / 4 * 4];     /* latent sum, fixed-point path (rows padded to 4) */
} ns2_job_t;

/* Returns info.status (NS2_OK or NS2_ERR_*); on error the job finishes with 0. */
int32_t ns2_job_begin(ns2_job_t *job, uint8_t robot_type, const float p[3], const float v[3],
                      const ns2_neighbor_t *neighbors, uint16_t n_neighbors);
/* ns2_job_begin with the robot's own past (see ns2_predict_f32_hist) */
int32_t ns2_job_begin_hist(ns2_job_t *job, uint8_t robot_type, const float p[3], const float v[3],
                           const float *own_past, const ns2_neighbor_t *neighbors, uint16_t n_neighbors);
uint16_t ns2_job_step_f32(ns2_job_t *job, uint16_t max_phi);
uint16_t ns2_job_step_q15(ns2_job_t *job, uint16_t max_phi);
/* f_a,z in grams (float) or in Q NS2_Q_OUT_FRAC (fixed); info (may be NULL)
 * receives the job's counters and status. */
float ns2_job_finish_f32(ns2_job_t *job, ns2_info_t *info);
int16_t ns2_job_finish_q15(ns2_job_t *job, ns2_info_t *info);

#ifdef __cplusplus
}
#endif

#endif /* NS2_DEEPSET_H */
