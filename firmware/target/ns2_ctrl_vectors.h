/* ns2_ctrl_vectors.h - controller test vectors: one step = optional position
 * update (100 Hz) then an attitude update (500 Hz).  Shared by the QEMU image
 * and the host build so that both run the very same loop. */
#ifndef NS2_CTRL_VECTORS_H
#define NS2_CTRL_VECTORS_H

#include <stdint.h>

#include "ns2_controller.h"

#define NS2_STEP_POSITION 1u
#define NS2_STEP_NO_FA 2u /* baseline: fa_hat = NULL */

typedef struct {
    ns2_ctrl_state_t s;
    ns2_setpoint_t sp;
    float fa[3];
    float dt_pos, dt_att, battery_V;
    uint32_t flags;
} ns2_step_in_t;

typedef struct {
    float u[4];
    float pwm[4];
    float T_d, T_d_dot;
    uint32_t status;
} ns2_step_out_t;

void ns2_ctrl_run_steps(ns2_ctrl_t *c, const ns2_step_in_t *in, ns2_step_out_t *out, uint32_t n);

#endif /* NS2_CTRL_VECTORS_H */
