/* ns2_peers.c - see ns2_peers.h. */
#include <math.h>
#include <stddef.h>

#include "ns2_peers.h"

void ns2_peers_init(ns2_peers_t *s, float alpha)
{
    s->count = 0;
    s->alpha = (alpha > 0.0f && alpha <= 1.0f) ? alpha : 1.0f;
    for (uint8_t i = 0; i < NS2_PEERS_MAX; ++i) {
        s->peer[i].samples = 0;
    }
}

int32_t ns2_peers_update(ns2_peers_t *s, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3])
{
    if (p == NULL || !isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) {
        return -1;
    }
    ns2_peer_t *e = NULL;
    for (uint8_t i = 0; i < s->count; ++i) {
        if (s->peer[i].id == id) {
            e = &s->peer[i];
            break;
        }
    }
    if (e == NULL) {
        if (s->count >= NS2_PEERS_MAX) {
            return -1;
        }
        e = &s->peer[s->count++];
        e->id = id;
        e->samples = 0;
        e->v[0] = e->v[1] = e->v[2] = 0.0f;
    }
    e->type = type;
    if (e->samples > 0u) {
        if (t_ms <= e->t_ms) {
            return t_ms == e->t_ms ? 0 : -1; /* duplicate or out of order */
        }
        const float dt = (float)(t_ms - e->t_ms) * 1e-3f;
        for (int a = 0; a < 3; ++a) {
            const float v_new = (p[a] - e->p[a]) / dt;
            e->v[a] = e->samples > 1u ? e->v[a] + s->alpha * (v_new - e->v[a]) : v_new;
        }
    }
    e->samples = (uint8_t)(e->samples < 2u ? e->samples + 1u : 2u);
    e->t_ms = t_ms;
    e->p[0] = p[0];
    e->p[1] = p[1];
    e->p[2] = p[2];
    return 0;
}

uint16_t ns2_peers_neighbors(const ns2_peers_t *s, uint8_t self_id, const float p[3], const float v[3],
                             uint32_t now_ms, uint32_t max_age_ms, ns2_neighbor_t *out, uint16_t max)
{
    float dist2[NS2_PEERS_MAX];
    uint16_t n = 0;
    if (out == NULL || p == NULL || v == NULL) {
        return 0;
    }
    if (max > NS2_PEERS_MAX) {
        max = NS2_PEERS_MAX;
    }
    for (uint8_t i = 0; i < s->count; ++i) {
        const ns2_peer_t *e = &s->peer[i];
        if (e->id == self_id || e->samples == 0u || now_ms - e->t_ms > max_age_ms) {
            continue;
        }
        /* insertion sort by squared distance (stable: ties keep table order) */
        ns2_neighbor_t nb;
        nb.type = e->type;
        float d2 = 0.0f;
        for (int a = 0; a < 3; ++a) {
            nb.rel[a] = e->p[a] - p[a];
            nb.rel[a + 3] = (e->samples > 1u ? e->v[a] : 0.0f) - v[a];
            d2 += nb.rel[a] * nb.rel[a];
        }
        uint16_t k = n < max ? n : max;
        while (k > 0u && dist2[k - 1u] > d2) {
            if (k < max) {
                out[k] = out[k - 1u];
                dist2[k] = dist2[k - 1u];
            }
            --k;
        }
        if (k < max) {
            out[k] = nb;
            dist2[k] = d2;
            if (n < max) {
                ++n;
            }
        }
    }
    return n;
}
