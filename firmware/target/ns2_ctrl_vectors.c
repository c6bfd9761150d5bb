/* ns2_ctrl_vectors.c - see ns2_ctrl_vectors.h. */
#include <stddef.h>

#include "ns2_ctrl_vectors.h"

void ns2_ctrl_run_steps(ns2_ctrl_t *c, const ns2_step_in_t *in, ns2_step_out_t *out, uint32_t n)
{
    for (uint32_t k = 0; k < n; ++k) {
        const ns2_step_in_t *x = &in[k];
        if (x->flags & NS2_STEP_POSITION) {
            ns2_ctrl_position(c, &x->s, &x->sp, (x->flags & NS2_STEP_NO_FA) ? NULL : x->fa, x->dt_pos);
        }
        ns2_ctrl_attitude(c, &x->s, x->dt_att, x->battery_V);
        for (int i = 0; i < 4; ++i) {
            out[k].u[i] = c->u[i];
            out[k].pwm[i] = c->pwm[i];
        }
        out[k].T_d = c->T_d;
        out[k].T_d_dot = c->T_d_dot;
        out[k].status = c->status;
    }
}
