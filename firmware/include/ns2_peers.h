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
} ns2_peer_t;

typedef struct {
    ns2_peer_t peer[NS2_PEERS_MAX];
    uint8_t count;
    float alpha; /* velocity filter weight in (0, 1]; 1 = raw finite differences */
} ns2_peers_t;

void ns2_peers_init(ns2_peers_t *s, float alpha);

/* Record a position sample of robot `id` (of robot type `type`) taken at t_ms.
 * Returns NS2_PEERS_OK (0), NS2_PEERS_REJECTED (-1) when the table is full or the
 * sample is invalid or late, or NS2_PEERS_RESTARTED (1) after a jump. */
int32_t ns2_peers_update(ns2_peers_t *s, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3]);

/* Neighbour list (at most max entries) of the robot at p, v at time now_ms,
 * excluding peers older than max_age_ms (or stamped after now_ms) and the robot's
 * own id; nearest first.  At most NS2_PEERS_MAX entries are written. */
uint16_t ns2_peers_neighbors(const ns2_peers_t *s, uint8_t self_id, const float p[3], const float v[3],
                             uint32_t now_ms, uint32_t max_age_ms, ns2_neighbor_t *out, uint16_t max);

#endif /* NS2_PEERS_H */
