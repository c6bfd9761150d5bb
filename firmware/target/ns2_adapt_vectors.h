/* ns2_adapt_vectors.h - on-board label and adaptation test vectors: one step =
 * one position tick of the pilot (ns2_label_step, then ns2_adapt_step_track with its
 * label).  Shared by the QEMU image and the host build so that both run the very
 * same loop. */
#ifndef NS2_ADAPT_VECTORS_H
#define NS2_ADAPT_VECTORS_H

#include <stdint.h>

#include "ns2_adapt.h"
#include "ns2_label.h"

#define NS2_ADAPT_STEP_RESET 1u /* ns2_adapt_reset before the step (take-off, PARAM) */
#define NS2_ADAPT_STEP_WAKE 2u  /* the tick is in a wake (the caller's flag) */

typedef struct {
    float vz, z, q[4], pwm[4], battery_V;
    float nn_g;             /* the network's f_a,z at this tick, g */
    float s_h;              /* the composite tracking error times the period, m (ns2_adapt_step_track) */
    ns2_adapt_cfg_t cfg;    /* the parameters at this tick */
    uint32_t flags;
} ns2_adapt_in_t;

typedef struct {
    float label_N, label_g;
    float out_g, term_g;
    float theta[2];
    float P[3];
    uint32_t label_status, adapt_status, updates;
} ns2_adapt_out_t;

void ns2_adapt_run_steps(ns2_label_t *l, ns2_adapt_t *a, const ns2_adapt_in_t *in, ns2_adapt_out_t *out,
                         uint32_t n);

#endif /* NS2_ADAPT_VECTORS_H */
