/* ns2_peers.c - see ns2_peers.h. */
#include <math.h>
#include <stddef.h>

#include "ns2_peers.h"

#if NS2_HISTORY_LAGS > 0
/* ring slot of the history tick k ticks before the latest (k < NS2_PEERS_HIST) */
static uint32_t hist_slot(const ns2_peers_t *s, uint32_t k)
{
    const uint32_t j = (uint32_t)s->hist_head + NS2_PEERS_HIST - k; /* < 2 NS2_PEERS_HIST */
    return j < NS2_PEERS_HIST ? j : j - NS2_PEERS_HIST;
}

/* the tick of lag l for a history of `count` ticks: the oldest where younger */
static uint32_t hist_lag(const ns2_peers_t *s, int l, uint8_t count)
{
    const uint32_t k = s->lag_ticks[l];
    return k < count ? k : (uint32_t)count - 1u;
}
#endif

void ns2_peers_init(ns2_peers_t *s, float alpha)
{
    if (s == NULL) {
        return;
    }
    s->count = 0;
    s->alpha = (alpha > 0.0f && alpha <= 1.0f) ? alpha : 1.0f;
    for (uint8_t i = 0; i < NS2_PEERS_MAX; ++i) {
        s->peer[i].samples = 0;
#if NS2_HISTORY_LAGS > 0
        s->peer[i].hist_count = 0;
#endif
    }
#if NS2_HISTORY_LAGS > 0
    s->hist_head = 0;
    s->own_count = 0;
    for (int l = 0; l < NS2_HISTORY_LAGS; ++l) {
        const uint32_t k = ((uint32_t)ns2_history_ms[l] + NS2_PEERS_HIST_PERIOD_MS / 2u) / NS2_PEERS_HIST_PERIOD_MS;
        s->lag_ticks[l] = (uint8_t)(k > 0u ? k : 1u); /* <= NS2_PEERS_HIST - 1 */
    }
#endif
}

static int within3(const float x[3], float lim)
{
    return fabsf(x[0]) <= lim && fabsf(x[1]) <= lim && fabsf(x[2]) <= lim; /* false for NaN/Inf */
}

/* The entry of the full table whose last sample lies furthest back from t_ms
 * (modulo 2^32) among those stale at t_ms: more than NS2_PEERS_STALE_MS before it,
 * or more than NS2_PEERS_REORDER_MS after it.  NULL: every peer is live. */
static ns2_peer_t *stalest(ns2_peers_t *s, uint32_t t_ms)
{
    ns2_peer_t *out = NULL;
    uint32_t worst = 0u;
    for (uint8_t i = 0; i < s->count; ++i) {
        ns2_peer_t *e = &s->peer[i];
        const uint32_t ahead = t_ms - e->t_ms; /* modulo 2^32 */
        const int stale = (uint32_t)(e->t_ms - t_ms) > NS2_PEERS_REORDER_MS && ahead > NS2_PEERS_STALE_MS;
        if (stale && (out == NULL || ahead > worst)) {
            out = e;
            worst = ahead;
        }
    }
    return out;
}

int32_t ns2_peers_update(ns2_peers_t *s, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3])
{
    if (s == NULL || p == NULL || !within3(p, NS2_PEERS_P_MAX_M)) {
        return NS2_PEERS_REJECTED;
    }
    ns2_peer_t *e = NULL;
    for (uint8_t i = 0; i < s->count; ++i) {
        if (s->peer[i].id == id) {
            e = &s->peer[i];
            break;
        }
    }
    int32_t ret = NS2_PEERS_OK;
    if (e == NULL) {
        if (s->count < NS2_PEERS_MAX) {
            e = &s->peer[s->count++];
        } else {
            e = stalest(s, t_ms); /* a peer that disappeared gives its slot */
            if (e == NULL) {
                return NS2_PEERS_REJECTED; /* NS2_PEERS_MAX live peers */
            }
        }
        e->id = id;
        e->samples = 0;
        e->v[0] = e->v[1] = e->v[2] = 0.0f;
#if NS2_HISTORY_LAGS > 0
        e->hist_count = 0; /* a new track: a new history */
#endif
    }
    if (e->samples > 0u) {
        const uint32_t ahead = t_ms - e->t_ms; /* modulo 2^32 */
        if (ahead == 0u) {
            return NS2_PEERS_OK; /* duplicate */
        }
        if ((uint32_t)(e->t_ms - t_ms) <= NS2_PEERS_REORDER_MS) {
            return NS2_PEERS_REJECTED; /* late, out of order */
        }
        float v_new[3] = {0.0f, 0.0f, 0.0f};
        int glitch = ahead > NS2_PEERS_GAP_MS;
        if (!glitch) {
            const float dt = (float)ahead * 1e-3f;
            for (int a = 0; a < 3; ++a) {
                v_new[a] = (p[a] - e->p[a]) / dt;
            }
            glitch = !within3(v_new, NS2_PEERS_V_MAX_MS);
        }
        if (glitch) {
            /* a jump in time or space (clock reset, relocalization, corrupt sample):
             * the track restarts from this sample, velocity unknown until the next */
            e->samples = 0;
            e->v[0] = e->v[1] = e->v[2] = 0.0f;
#if NS2_HISTORY_LAGS > 0
            e->hist_count = 0;
#endif
            ret = NS2_PEERS_RESTARTED;
        } else {
            for (int a = 0; a < 3; ++a) {
                e->v[a] = e->samples > 1u ? e->v[a] + s->alpha * (v_new[a] - e->v[a]) : v_new[a];
            }
        }
    }
    e->type = type;
    e->samples = (uint8_t)(e->samples < 2u ? e->samples + 1u : 2u);
    e->t_ms = t_ms;
    e->p[0] = p[0];
    e->p[1] = p[1];
    e->p[2] = p[2];
    return ret;
}

uint8_t ns2_type_table_get(const uint32_t table[NS2_TYPE_TABLE_WORDS], uint8_t id, uint8_t n_types)
{
    if (table == NULL) {
        return 0u;
    }
    const uint32_t per_word = 32u / NS2_TYPE_BITS;
    const uint32_t shift = NS2_TYPE_BITS * ((uint32_t)id % per_word);
    const uint8_t type = (uint8_t)((table[(uint32_t)id / per_word] >> shift) & ((1u << NS2_TYPE_BITS) - 1u));
    return type < n_types ? type : 0u;
}

#if NS2_HISTORY_LAGS > 0
/* o = x - y, six floats, written out (a loop is register-starved at -Os) */
static void sub6(float *o, const float *x, const float *y)
{
    o[0] = x[0] - y[0];
    o[1] = x[1] - y[1];
    o[2] = x[2] - y[2];
    o[3] = x[3] - y[3];
    o[4] = x[4] - y[4];
    o[5] = x[5] - y[5];
}
#endif

/* x_ij now of peer e from p, v: [p_j - p; v_j - v], v_j = 0 until two samples */
static void present6(const ns2_peer_t *e, const float p[3], const float v[3], float *o)
{
    o[0] = e->p[0] - p[0];
    o[1] = e->p[1] - p[1];
    o[2] = e->p[2] - p[2];
    if (e->samples > 1u) {
        o[3] = e->v[0] - v[0];
        o[4] = e->v[1] - v[1];
        o[5] = e->v[2] - v[2];
    } else {
        o[3] = 0.0f - v[0];
        o[4] = 0.0f - v[1];
        o[5] = 0.0f - v[2];
    }
}

/* Fill *nb from peer e as seen from p, v: x_ij now, then, with wake memory, x_ij
 * of the tick of each lag; slot_full[l]: the ring slot of lag l for a peer
 * recorded for longer than the lag. */
static void neighbor_fill(const ns2_peers_t *s, const ns2_peer_t *e, const float p[3], const float v[3],
                          const uint32_t *slot_full, ns2_neighbor_t *nb)
{
    nb->type = e->type;
    present6(e, p, v, nb->rel);
#if NS2_HISTORY_LAGS > 0
    for (int l = 0; l < NS2_HISTORY_LAGS; ++l) { /* x_ij of the tick of each lag */
        float *past = &nb->rel[6 * (l + 1)];
        if (e->hist_count == 0u) {
            present6(e, p, v, past); /* not recorded yet: the present (computed again, not copied) */
        } else {
            const uint32_t slot =
                s->lag_ticks[l] < e->hist_count ? slot_full[l] : hist_slot(s, hist_lag(s, l, e->hist_count));
            sub6(past, e->hist[slot], s->own[slot]);
        }
    }
#else
    (void)s;
    (void)slot_full;
#endif
}

uint16_t ns2_peers_neighbors(const ns2_peers_t *s, uint8_t self_id, const float p[3], const float v[3],
                             uint32_t now_ms, uint32_t max_age_ms, ns2_neighbor_t *out, uint16_t max)
{
    float dist2[NS2_PEERS_MAX];
    uint8_t order[NS2_PEERS_MAX]; /* table index of each kept peer, nearest first */
    uint16_t n = 0;
    if (s == NULL || out == NULL || p == NULL || v == NULL || !within3(p, NS2_PEERS_P_MAX_M) ||
        !within3(v, NS2_PEERS_V_MAX_MS)) {
        return 0;
    }
    if (max > NS2_PEERS_MAX) {
        max = NS2_PEERS_MAX;
    }
    /* the nearest max peers by table index: only these get their inputs (and past) computed */
    for (uint8_t i = 0; i < s->count; ++i) {
        const ns2_peer_t *e = &s->peer[i];
        if (e->id == self_id || e->samples == 0u || now_ms - e->t_ms > max_age_ms) {
            continue;
        }
        const float r0 = e->p[0] - p[0], r1 = e->p[1] - p[1], r2 = e->p[2] - p[2];
        const float d2 = ((0.0f + r0 * r0) + r1 * r1) + r2 * r2; /* the order of x_ij's sum */
        /* insertion sort by squared distance (stable: ties keep table order) */
        uint16_t k = n < max ? n : max;
        while (k > 0u && dist2[k - 1u] > d2) {
            if (k < max) {
                order[k] = order[k - 1u];
                dist2[k] = dist2[k - 1u];
            }
            --k;
        }
        if (k < max) {
            order[k] = i;
            dist2[k] = d2;
            if (n < max) {
                ++n;
            }
        }
    }
#if NS2_HISTORY_LAGS > 0
    uint32_t slot_full[NS2_HISTORY_LAGS];
    for (int l = 0; l < NS2_HISTORY_LAGS; ++l) {
        slot_full[l] = hist_slot(s, s->lag_ticks[l]);
    }
#else
    const uint32_t *slot_full = NULL;
#endif
    for (uint16_t k = 0; k < n; ++k) {
        neighbor_fill(s, &s->peer[order[k]], p, v, slot_full, &out[k]);
    }
    return n;
}

void ns2_peers_record(ns2_peers_t *s, const float p[3], const float v[3])
{
#if NS2_HISTORY_LAGS > 0
    if (s == NULL) {
        return;
    }
    if (p == NULL || v == NULL || !within3(p, NS2_PEERS_P_MAX_M) || !within3(v, NS2_PEERS_V_MAX_MS)) {
        s->own_count = 0; /* no own state: every history restarts */
        for (uint8_t i = 0; i < s->count; ++i) {
            s->peer[i].hist_count = 0;
        }
        return;
    }
    s->hist_head = (uint8_t)((s->hist_head + 1u) % NS2_PEERS_HIST);
    /* element by element, no copy loops: -Os makes those calls to a byte-wise memmove */
    float *own = s->own[s->hist_head];
    own[0] = p[0];
    own[1] = p[1];
    own[2] = p[2];
    own[3] = v[0];
    own[4] = v[1];
    own[5] = v[2];
    s->own_count = (uint8_t)(s->own_count < NS2_PEERS_HIST ? s->own_count + 1u : NS2_PEERS_HIST);
    for (uint8_t i = 0; i < s->count; ++i) {
        ns2_peer_t *e = &s->peer[i];
        if (e->samples == 0u) {
            e->hist_count = 0;
            continue;
        }
        float *h = e->hist[s->hist_head];
        const int moving = e->samples > 1u;
        h[0] = e->p[0];
        h[1] = e->p[1];
        h[2] = e->p[2];
        h[3] = moving ? e->v[0] : 0.0f; /* as the neighbour list */
        h[4] = moving ? e->v[1] : 0.0f;
        h[5] = moving ? e->v[2] : 0.0f;
        e->hist_count = (uint8_t)(e->hist_count < NS2_PEERS_HIST ? e->hist_count + 1u : NS2_PEERS_HIST);
    }
#else
    (void)s;
    (void)p;
    (void)v;
#endif
}

void ns2_peers_own_past(const ns2_peers_t *s, const float p[3], const float v[3], float *own_past)
{
#if NS2_HISTORY_LAGS > 0
    if (s == NULL || p == NULL || v == NULL || own_past == NULL) {
        return;
    }
    for (int l = 0; l < NS2_HISTORY_LAGS; ++l) {
        float *out = &own_past[6 * l];
        if (s->own_count == 0u) {
            for (int a = 0; a < 3; ++a) {
                out[a] = p[a];
                out[a + 3] = v[a];
            }
        } else {
            const uint32_t slot = hist_slot(s, hist_lag(s, l, s->own_count));
            for (int a = 0; a < 6; ++a) {
                out[a] = s->own[slot][a];
            }
        }
    }
#else
    (void)s;
    (void)p;
    (void)v;
    (void)own_past;
#endif
}
