/*
 * ns2_peers.h - neighbour tracking for the on-board deep set: positions of other
 * robots (e.g. from the Crazyflie's peer localization, mocap broadcasts), their
 * velocity by finite differences, and the neighbour list of ns2_predict_*.
 *
 * Velocity: v = (p_k - p_{k-1}) / (t_k - t_{k-1}) between the two most recent
 * samples with distinct timestamps, low-pass filtered with weight alpha
 * (v <- v + alpha (v_new - v)); zero until two samples have arrived.
 *
 * Hostile input (every case gives defined, finite outputs):
 *   - a position not finite or beyond NS2_PEERS_P_MAX_M per axis is rejected;
 *   - a sample up to NS2_PEERS_REORDER_MS older than the last one is rejected
 *     (out of order), one with the same timestamp is ignored (duplicate);
 *   - a jump (an implied speed beyond NS2_PEERS_V_MAX_MS, a gap of more than
 *     NS2_PEERS_GAP_MS, or a timestamp further back than NS2_PEERS_REORDER_MS,
 *     e.g. a rebooted peer) restarts that peer's track from the new sample:
 *     status NS2_PEERS_RESTARTED, velocity 0 until the next sample, so the
 *     velocity is valid again two good samples after any glitch.
 * The own state given to ns2_peers_neighbors must be finite and within the same
 * limits, else the list is empty.  Peers not
 * updated for longer than max_age_ms are left out of the neighbour list, which
 * is sorted nearest first so that the NS2_MAX_NEIGHBORS limit keeps the
 * nearest robots.  No dynamic memory.
 *
 * Bookkeeping: the table holds NS2_PEERS_MAX robots of any radio id 0..255, one
 * entry per id.  A sample of a new id when the table is full takes the slot of the
 * stalest peer, one not heard from for more than NS2_PEERS_STALE_MS before that
 * sample (or stamped more than NS2_PEERS_REORDER_MS after it: a clock that went back), so
 * a robot that disappears (landed, switched off, out of radio range) gives its slot
 * to the next robot heard; with NS2_PEERS_MAX live peers a new one is rejected.  A
 * peer's robot type is the one given with its latest accepted sample, so a peer
 * whose type changes (the ground rewrote the type table) carries the new type from
 * its next sample on.
 *
 * Wake memory (a model exported with model.history_ms, NS2_HISTORY_LAGS > 0): at
 * every history tick (ns2_peers_record, the app's 100 Hz position tick) the table
 * keeps each peer's [p; v] as the neighbour list uses it, and the robot's own, in
 * a ring of NS2_PEERS_HIST ticks (no dynamic memory).  The neighbour list then
 * holds, after x_ij of now, x_ij of each lag of ns2_history_ms (rounded half up to
 * NS2_PEERS_HIST_PERIOD_MS ticks, at least one): both states of that tick,
 * subtracted in float32 as the data builders do (ns2codegen.data.from_logs); a
 * peer recorded for fewer ticks than the lag uses its oldest recorded tick (and
 * the own state of that tick), the rule of the data sets (a flight piece's first
 * sample); ns2_peers_own_past gives the own [p; v] at each lag (the oldest where
 * younger).  A restarted track (NS2_PEERS_RESTARTED, or a new peer in a slot)
 * starts a new history; an own state that is not finite or beyond the limits
 * restarts every history (and records nothing); a peer not recorded yet uses its
 * present state for the past.  Without wake memory none of this is compiled in
 * (ns2_peers_record does nothing, the structures are those of before).
 *
 * Type table: the robot type of every radio id 0..255 in NS2_TYPE_TABLE_WORDS
 * 32-bit words, NS2_TYPE_BITS bits per id (id i: word i / 16, bits 2 (i % 16) and
 * 2 (i % 16) + 1), so up to 4 robot types; the app's PARAM ns2type.t0 .. t15, which
 * the ground side writes (host/cbuild.py type_table, through ns2ground/swarm.py).
 */
#ifndef NS2_PEERS_H
#define NS2_PEERS_H

#include <stdint.h>

#include "ns2_deepset.h"

#ifndef NS2_PEERS_MAX
#define NS2_PEERS_MAX 16u
#endif

#define NS2_PEERS_P_MAX_M 1.0e3f   /* |position| per axis */
#define NS2_PEERS_V_MAX_MS 50.0f    /* |implied velocity| per axis */
#define NS2_PEERS_GAP_MS 1000u      /* longer gaps restart the velocity estimate */
#define NS2_PEERS_REORDER_MS 1000u  /* older samples within this window are late: rejected */
#define NS2_PEERS_STALE_MS 1000u    /* a peer silent for longer gives its slot to a new one when full */

#define NS2_TYPE_BITS 2u            /* bits of the type table per radio id */
#define NS2_TYPE_TABLE_WORDS 16u    /* 256 radio ids x NS2_TYPE_BITS in uint32 words */
#define NS2_TYPE_TABLE_MAX_TYPES 4u /* robot types the table can name */

/* wake memory: ticks of the history ring (ns2_peers_record every NS2_PEERS_HIST_PERIOD_MS) */
#ifndef NS2_PEERS_HIST_PERIOD_MS
#define NS2_PEERS_HIST_PERIOD_MS 10u /* the app's 100 Hz position tick (NS2_PILOT_POS_HZ) */
#endif
/* the ticks of the longest lag, rounded half up, and the present */
#define NS2_PEERS_HIST ((NS2_HISTORY_MAX_MS + NS2_PEERS_HIST_PERIOD_MS / 2u) / NS2_PEERS_HIST_PERIOD_MS + 1u)

#define NS2_PEERS_OK 0
#define NS2_PEERS_REJECTED (-1)     /* table full or sample invalid / out of order */
#define NS2_PEERS_RESTARTED 1       /* accepted as the first sample of a new track */

typedef struct {
    uint8_t id;       /* radio id of the peer */
    uint8_t type;     /* robot type (NS2_TYPE_*) */
    uint8_t samples;  /* 0, 1 or 2 (saturating) */
    uint32_t t_ms;    /* time of the last sample */
    float p[3];       /* m, world frame */
    float v[3];       /* m/s, finite differences, filtered */
#if NS2_HISTORY_LAGS > 0
    uint8_t hist_count;                /* history ticks recorded since the track began (saturating) */
    float hist[NS2_PEERS_HIST][6];     /* [p; v] at each history tick, ring (head in ns2_peers_t) */
#endif
} ns2_peer_t;

typedef struct {
    ns2_peer_t peer[NS2_PEERS_MAX];
    uint8_t count;
    float alpha; /* velocity filter weight in (0, 1]; 1 = raw finite differences */
#if NS2_HISTORY_LAGS > 0
    uint8_t hist_head;                 /* ring slot of the latest history tick */
    uint8_t own_count;                 /* own history ticks recorded (saturating) */
    uint8_t lag_ticks[NS2_HISTORY_LAGS]; /* ns2_history_ms in history ticks */
    float own[NS2_PEERS_HIST][6];      /* own [p; v] at each history tick */
#endif
} ns2_peers_t;

void ns2_peers_init(ns2_peers_t *s, float alpha);

/* Record a position sample of robot `id` (of robot type `type`) taken at t_ms.
 * Returns NS2_PEERS_OK (0), NS2_PEERS_REJECTED (-1) when the table is full of live
 * peers or the sample is invalid or late, or NS2_PEERS_RESTARTED (1) after a jump.
 * The first sample of a new peer (in a free slot or a stale peer's) is NS2_PEERS_OK. */
int32_t ns2_peers_update(ns2_peers_t *s, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3]);

/* The robot type of radio id `id` in the type table (above); a type that is not
 * below n_types (not a robot type of the export) is type 0; a NULL table: 0. */
uint8_t ns2_type_table_get(const uint32_t table[NS2_TYPE_TABLE_WORDS], uint8_t id, uint8_t n_types);

/* Neighbour list (at most max entries) of the robot at p, v at time now_ms,
 * excluding peers older than max_age_ms (or stamped after now_ms) and the robot's
 * own id; nearest first.  At most NS2_PEERS_MAX entries are written. */
uint16_t ns2_peers_neighbors(const ns2_peers_t *s, uint8_t self_id, const float p[3], const float v[3],
                             uint32_t now_ms, uint32_t max_age_ms, ns2_neighbor_t *out, uint16_t max);

/* Wake memory: one history tick (every NS2_PEERS_HIST_PERIOD_MS, before the
 * neighbour list of that tick) with the robot's own state p, v; nothing without
 * NS2_HISTORY_LAGS. */
void ns2_peers_record(ns2_peers_t *s, const float p[3], const float v[3]);

/* Wake memory: the own [p; v] at each lag (6 NS2_HISTORY_LAGS floats, the
 * own_past of ns2_predict_*_hist); p, v (the present) where nothing is recorded.
 * Nothing is written without NS2_HISTORY_LAGS. */
void ns2_peers_own_past(const ns2_peers_t *s, const float p[3], const float v[3], float *own_past);

#endif /* NS2_PEERS_H */
