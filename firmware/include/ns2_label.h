/*
 * ns2_label.h - the robot's own interaction force f_a,z, measured on board
 * (issue 53 item 1), as the data pipeline labels logs (ns2codegen/data/labels.py):
 *
 *   f_a,z = m v_dot_z + m g - R33 T,   R33 = 1 - 2 (qx^2 + qy^2),
 *   v_dot_z = (-v[k+2] + 8 v[k+1] - 8 v[k-1] + v[k-2]) / (12 h)   (five-point stencil),
 *   T = sum of the motor forces: psi_1 (Table cfprops, grams) of each motor's PWM
 *       and V / 4.2, zero for a stopped motor, through the first-order motor delay
 *       u[k+1] = a u[k] + (1 - a) u_c[k],  a = exp(-lambda h),  u = u_c at a start.
 *
 * Causal: ns2_label_step is given the sample k (vertical velocity, height,
 * attitude, the motor PWM commanded and the battery voltage) and returns the
 * label of sample k - NS2_LABEL_DELAY (the same central stencil two samples
 * late, 20 ms at 100 Hz): bit for bit the float32 reference
 * ns2codegen.onboard.label_f32 of the same inputs.  float32 only, no dynamic
 * memory, no libm (exp(-lambda h) by scaling and squaring of a Taylor series,
 * the same operations in the reference).
 *
 * Safety (defined outputs, never undefined behaviour):
 *   - input non-finite or beyond the limits (|v_z| > NS2_CTRL_V_MAX_MS, |z| >
 *     NS2_CTRL_P_MAX_M, |q|^2 outside [0.25, 4], a PWM outside [0, 1], battery
 *     voltage outside [0, NS2_CTRL_BAT_MAX_V]): label 0, NS2_LABEL_BAD_INPUT, the
 *     history restarts (as a new log piece: the next label comes NS2_LABEL_STENCIL
 *     good samples later, NS2_LABEL_WARMUP until then);
 *   - configuration that cannot label (mass outside (0, 100] kg, lambda outside
 *     [0, 1e4] 1/s, h outside [1e-4, 1] s, psi_1 non-finite or beyond 1e6):
 *     label 0, NS2_LABEL_BAD_CONFIG, always;
 *   - sanity flags of the labelled sample (the label is given, its user decides):
 *     NS2_LABEL_GROUND (height below min_z_m), NS2_LABEL_TILTED (R33 below
 *     min_r33), NS2_LABEL_SATURATED (a motor at PWM 0 or 1 in the stencil's five
 *     samples).
 */
#ifndef NS2_LABEL_H
#define NS2_LABEL_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NS2_LABEL_OK 0u
#define NS2_LABEL_BAD_INPUT 1u  /* this sample unusable: label 0, history restarted */
#define NS2_LABEL_WARMUP 2u     /* fewer than NS2_LABEL_STENCIL good samples in a row */
#define NS2_LABEL_GROUND 4u     /* the labelled sample below min_z_m */
#define NS2_LABEL_TILTED 8u     /* R33 of the labelled sample below min_r33 */
#define NS2_LABEL_SATURATED 16u /* a motor at PWM 0 or 1 within the stencil */
#define NS2_LABEL_BAD_CONFIG 32u

#define NS2_LABEL_STENCIL 5u /* samples of the velocity stencil */
#define NS2_LABEL_DELAY 2u   /* the label of sample k comes with sample k + 2 */

typedef struct {
    float mass_kg;
    float lambda;   /* motor delay constant, 1/s */
    float psi1[5];  /* force (g) from (PWM, V/4.2): 1, p, v, p^2, p v */
    float h_s;      /* sample period (0.01 at 100 Hz) */
    float min_z_m;  /* below: NS2_LABEL_GROUND */
    float min_r33;  /* below (tilt): NS2_LABEL_TILTED */
} ns2_label_cfg_t;

typedef struct {
    ns2_label_cfg_t cfg;
    float a;           /* exp(-lambda h) */
    float vz[NS2_LABEL_STENCIL];  /* the last five vertical velocities, oldest first */
    float ft[NS2_LABEL_DELAY + 1u]; /* R33 T of the last three samples, oldest first */
    float z[NS2_LABEL_DELAY + 1u];
    float r33[NS2_LABEL_DELAY + 1u];
    float u[4];        /* delayed motor forces at the last sample, N */
    float uc[4];       /* commanded motor forces of the last sample, N */
    uint8_t sat;       /* bit i: sample k - i had a motor at PWM 0 or 1 */
    uint8_t n_good;    /* good samples in a row, up to NS2_LABEL_STENCIL */
    uint8_t config_ok;
    float label_N;     /* f_a,z of sample k - NS2_LABEL_DELAY, N (0 when none) */
    float label_g;     /* the same in grams (label_N 1000 / g) */
    uint32_t status;   /* NS2_LABEL_* of the last step */
} ns2_label_t;

/* exp(-x) for x in [0, 1e4] as the label computes it (0 beyond, 1 for x <= 0). */
float ns2_label_exp_neg(float x);
void ns2_label_init(ns2_label_t *l, const ns2_label_cfg_t *cfg);
/* Restart the history (the next label NS2_LABEL_STENCIL samples later). */
void ns2_label_restart(ns2_label_t *l);
/* Sample k; returns the status, the label of sample k - 2 in l->label_N / label_g. */
uint32_t ns2_label_step(ns2_label_t *l, float vz, float z, const float q[4], const float pwm[4], float battery_V);

#ifdef __cplusplus
}
#endif

#endif /* NS2_LABEL_H */
