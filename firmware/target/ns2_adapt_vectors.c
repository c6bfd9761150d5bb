/* ns2_adapt_vectors.c - see ns2_adapt_vectors.h. */
#include "ns2_adapt_vectors.h"

#include <string.h>

void ns2_adapt_run_steps(ns2_label_t *l, ns2_adapt_t *a, const ns2_adapt_in_t *in, ns2_adapt_out_t *out,
                         uint32_t n)
{
    for (uint32_t k = 0; k < n; ++k) {
        const ns2_adapt_in_t *s = &in[k];
        ns2_adapt_out_t *o = &out[k];
        if (s->flags & NS2_ADAPT_STEP_RESET) {
            ns2_adapt_reset(a, &s->cfg);
        }
        o->label_status = ns2_label_step(l, s->vz, s->z, s->q, s->pwm, s->battery_V);
        o->label_N = l->label_N;
        o->label_g = l->label_g;
        uint32_t s_h_bits;
        memcpy(&s_h_bits, &s->s_h, sizeof s_h_bits);
        /* s_h = +0: ns2_adapt_step (by definition ns2_adapt_step_track with s_h = +0), so that
         * both entry points are in the image and tested */
        if (s_h_bits == 0u) {
            o->out_g = ns2_adapt_step(a, &s->cfg, s->nn_g, (s->flags & NS2_ADAPT_STEP_WAKE) != 0u, l->label_g,
                                      o->label_status);
        } else {
            o->out_g = ns2_adapt_step_track(a, &s->cfg, s->nn_g, (s->flags & NS2_ADAPT_STEP_WAKE) != 0u,
                                            l->label_g, o->label_status, s->s_h);
        }
        o->term_g = a->term_g;
        o->theta[0] = a->theta[0];
        o->theta[1] = a->theta[1];
        o->P[0] = a->P[0];
        o->P[1] = a->P[1];
        o->P[2] = a->P[2];
        o->adapt_status = a->status;
        o->updates = a->updates;
    }
}
