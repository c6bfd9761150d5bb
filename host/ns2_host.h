/* ns2_host.h - host-only batch and timing helpers around the firmware library
 * (not part of the firmware; they only loop over the firmware's own calls). */
#ifndef NS2_HOST_H
#define NS2_HOST_H

#include <stdint.h>

#include "ns2_controller.h"
#include "ns2_deepset.h"

/* Run n_queries predictions; query q uses neighbors[offsets[q] .. offsets[q+1]).
 * fixed = 0: float into out_f; fixed = 1: fixed point into out_q.  slice = 0:
 * ns2_predict_*; slice > 0: the sliced API (ns2_job_*), slice phi per step.
 * past NULL: the plain entry points; else the *_hist ones with own_past
 * &past[6 NS2_HISTORY_LAGS q]. */
void ns2_host_predict_batch(int fixed, uint16_t slice, uint32_t n_queries, const uint8_t *robot_type,
                            const float *p, const float *v, const float *past, const uint32_t *offsets,
                            const ns2_neighbor_t *neighbors, float *out_f, int16_t *out_q,
                            ns2_info_t *infos);

/* Mean wall time in ns of one call of query 0, over reps calls (CLOCK_MONOTONIC). */
double ns2_host_ns_per_call(int fixed, uint32_t reps, uint8_t robot_type, const float p[3],
                            const float v[3], const ns2_neighbor_t *neighbors, uint16_t n);

/* One 500 Hz tick of n controllers (simulator): the position loop first when
 * do_pos, then the attitude loop; fa is [n][3] (N) or NULL (baseline);
 * pwm_out receives [n][4]. */
void ns2_host_ctrl_tick(ns2_ctrl_t *ctrls, uint32_t n, const ns2_ctrl_state_t *states,
                        const ns2_setpoint_t *setpoints, const float *fa, int do_pos, float dt_pos,
                        float dt_att, float battery_V, float *pwm_out);

#endif /* NS2_HOST_H */
