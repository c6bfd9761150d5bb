/*
 * ns2_adapt.h - on-board adaptation on top of the frozen deep set (issue 53
 * item 2, docs/adaptation.md):
 *
 *   f = NN(x) + sat(theta^T psi(x)),  psi = [1, NN(x)]  (a bias in g and a scale),
 *
 * theta by recursive least squares with exponential forgetting on the robot's own
 * label y (ns2_label.h, of the sample NS2_LABEL_DELAY position ticks back, paired
 * with the NN value used then):
 *
 *   e = y - NN - theta^T psi,  k = P psi / (lambda + psi^T P psi),
 *   theta <- proj(theta + k e),  P <- (P - k psi^T P) / lambda,
 *
 * proj clamps theta to |theta_0| <= bias_max_g, |theta_1| <= scale_max (scale_max = 0,
 * the default: psi = [1, 0], the bias alone); P stays symmetric positive
 * semi-definite, its diagonal in [NS2_ADAPT_P_MIN, p_max] (no covariance wind-up of
 * a direction nothing excites);
 * sat limits the adapted term to +-fa_max_g.  float32, no dynamic memory, no
 * libm; bit for bit the reference ns2codegen.onboard.adapt_f32.
 *
 * No update (theta and P held) when the label is not sane (any NS2_LABEL_* flag:
 * warm-up, bad input, ground contact, tilt, a saturated motor), |y| > label_max_g,
 * or the labelled sample was in a wake: |NN| > wake_g always, and with
 * gate_neighbours = 1 also the caller's wake flag (the pilot: a robot neighbour
 * inside the interaction volume).  There the network is in charge: the adaptation
 * does not learn, it only applies the bias and scale it has.  gate_neighbours = 0 is
 * the default: chosen on the real flights' held-out flights and judged on the
 * collections left out (docs/adaptation.md, "Judged on real flights"), the flag
 * stopped most updates (it is up on 62-70 % of the samples and for whole swap
 * flights of the bottom robot), and without it the law lowers the MSE by 30-55 % on
 * every collection left out, also in the wake; with it 14-22 %.
 *
 * The composite law (Neural-Fly's, O'Connell et al. 2022, with the tracking error): with
 * track_gain > 0 an update also moves theta along P psi by the controller's composite
 * tracking error s (velocity error + Lp position error, m/s) integrated over the tick,
 * s h (m), as ns2_adapt_step_track's s_h:
 *
 *   theta <- proj(theta + k e + track_gain (s h) P psi),
 *
 * P psi of the update (before P's own update), on the same gated ticks (no update: no
 * tracking term either); track_gain in g per (m/s) per s at P = 1 (at the default
 * forgetting P00 settles near 1 - lambda = 0.005 with an update every tick).  track_gain
 * = 0 (the default) is the law above bit for bit; a non-finite s_h or |s_h| > 1 m skips
 * the tracking term (NS2_ADAPT_BAD_TRACK).  ns2_adapt_step is ns2_adapt_step_track with
 * s_h = 0.
 *
 * Safety: a configuration out of its ranges (NaN, forgetting outside
 * [NS2_ADAPT_FORGET_MIN, 1], negative or absurd limits, gate_neighbours not 0 or 1) gives f = NN with
 * NS2_ADAPT_BAD_PARAM and theta held, until a good one returns; enable = 0 gives
 * f = NN exactly (theta held); a non-finite NN gives f = 0 and NS2_ADAPT_BAD_INPUT
 * (the NN history restarts); theta or P ever non-finite: reset to the initial
 * state (NS2_ADAPT_RESET).  |f - NN| <= fa_max_g always.
 */
#ifndef NS2_ADAPT_H
#define NS2_ADAPT_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NS2_ADAPT_UPDATED 1u     /* theta updated this step */
#define NS2_ADAPT_OFF 2u         /* enable = 0 */
#define NS2_ADAPT_BAD_PARAM 4u   /* configuration out of range: f = NN */
#define NS2_ADAPT_BAD_INPUT 8u   /* NN non-finite: f = 0 */
#define NS2_ADAPT_LABEL 16u      /* label not sane (its NS2_LABEL_* flags): no update */
#define NS2_ADAPT_LABEL_BOUND 32u /* |label| > label_max_g: no update */
#define NS2_ADAPT_WAKE 64u       /* the labelled sample in a wake (|NN| > wake_g, or the caller's
                                  * flag with gate_neighbours = 1): no update */
#define NS2_ADAPT_RESET 128u     /* non-finite memory was reset */
#define NS2_ADAPT_CLAMPED 256u   /* theta projected or the adapted term limited */
#define NS2_ADAPT_BAD_TRACK 512u /* track_gain > 0 and s_h non-finite or beyond NS2_ADAPT_TRACK_SH_MAX:
                                  * the tracking term skipped */

#define NS2_ADAPT_FORGET_MIN 0.5f
#define NS2_ADAPT_P_MIN 1.0e-6f
#define NS2_ADAPT_LIMIT_MAX 1.0e3f /* upper bound of every limit of the configuration */
#define NS2_ADAPT_NN_DELAY 2u      /* = NS2_LABEL_DELAY */
#define NS2_ADAPT_TRACK_GAIN_MAX 1.0e6f /* upper bound of track_gain, g/(m/s)/s */
#define NS2_ADAPT_TRACK_SH_MAX 1.0f     /* |s h| beyond (m): the tracking term skipped */

typedef struct {
    uint8_t enable;
    uint8_t gate_neighbours; /* 0 (default) or 1: the caller's wake flag also stops updates */
    float forget;       /* lambda in [NS2_ADAPT_FORGET_MIN, 1]: 0.995 = a 2 s memory at 100 Hz */
    float p0;           /* initial P = p0 I, (0, p_max] */
    float p_max;        /* each diagonal element of P at most this */
    float bias_max_g;   /* |theta_0| */
    float scale_max;    /* |theta_1|; 0: the bias alone */
    float fa_max_g;     /* |theta^T psi| */
    float label_max_g;  /* |label| beyond: no update */
    float wake_g;       /* |NN| beyond: a wake, no update (whatever gate_neighbours) */
    float track_gain;   /* the composite law's tracking gain, g/(m/s)/s at P = 1, in
                         * [0, NS2_ADAPT_TRACK_GAIN_MAX]; 0 (default): RLS alone */
} ns2_adapt_cfg_t;

typedef struct {
    float theta[2];     /* bias (g), scale */
    float P[3];         /* P00, P01, P11 */
    float nn[NS2_ADAPT_NN_DELAY + 1u]; /* NN of the last position ticks, oldest first, g */
    uint8_t wake;       /* bit i: the caller's wake flag of the tick i ticks back */
    uint8_t n_nn;       /* ticks of NN history, up to NS2_ADAPT_NN_DELAY + 1 */
    float term_g;       /* the adapted term of the last step, g */
    float out_g;        /* f of the last step, g */
    uint32_t status;
    uint32_t updates;   /* updates since the last reset */
} ns2_adapt_t;

void ns2_adapt_default_cfg(ns2_adapt_cfg_t *cfg);
/* 1 if every field is in range (else a step reports NS2_ADAPT_BAD_PARAM). */
int ns2_adapt_cfg_ok(const ns2_adapt_cfg_t *cfg);
/* theta = 0, P = p0 I (p0 of cfg when in range, else 1), history emptied. */
void ns2_adapt_reset(ns2_adapt_t *a, const ns2_adapt_cfg_t *cfg);
/* One position tick: nn_g the network's f_a,z now, wake nonzero when this tick is
 * in a wake (it stops updates only with gate_neighbours = 1), label_g /
 * label_status those of ns2_label_step at this tick (the
 * sample NS2_LABEL_DELAY ticks back).  Returns f in g (also a->out_g). */
float ns2_adapt_step(ns2_adapt_t *a, const ns2_adapt_cfg_t *cfg, float nn_g, int wake, float label_g,
                     uint32_t label_status);
/* The same with the composite law's tracking term: s_h the controller's composite
 * tracking error in z at this tick times the position period (m; ns2_pilot: (v_z -
 * v_z,d + Lp_z (z - z_d)) h).  Used only when cfg->track_gain > 0. */
float ns2_adapt_step_track(ns2_adapt_t *a, const ns2_adapt_cfg_t *cfg, float nn_g, int wake, float label_g,
                           uint32_t label_status, float s_h);
/* trace of P */
float ns2_adapt_trace(const ns2_adapt_t *a);

#ifdef __cplusplus
}
#endif

#endif /* NS2_ADAPT_H */
