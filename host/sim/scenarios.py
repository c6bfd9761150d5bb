"""Data-collection and test scenarios (paper, "Data Collection" and "Experiments").

* ``swap``: robots on a vertical cylinder at different heights (0.2-0.3 m apart)
  fly straight to the opposite side and back; all pass the axis at the same
  instant, i.e. are vertically aligned once per swap.
* ``random_walk``: every robot is attracted by a goal drawn uniformly in a cube at
  a fixed rate and repelled by its neighbours (artificial potentials), speed
  limited; the cube reaches down to the ground (ground-effect data).
* ``intertwined_rings``: the paper's 5- and 16-robot ring experiments (vertical
  rings of S* robots linked with a horizontal ring).
* ``near_field``: a pair at close range, one under the other (both move).
* ``who_moves``: a pair in which one robot moves under and over the other,
  hovering one (the truth depends on each robot's own velocity);
  ``who_moves_bystander``: the same with a third robot hovering nearby.
Setpoint functions take (t, state) and return cloop.Setpoints.
"""
from __future__ import annotations

import numpy as np

from .cloop import Setpoints


def swap(n: int, heights, radius: float = 0.5, duration: float = 3.0, rest: float = 1.0,
         seed: int = 0, center=(0.0, 0.0)):
    """n robots at the given heights; robot k crosses along azimuth phi_k (spread
    over 180 degrees) from -radius to +radius and back; cosine velocity profile."""
    rng = np.random.default_rng(seed)
    phi = rng.uniform(0, np.pi) + np.arange(n) * np.pi / max(n, 1)
    d = np.column_stack([np.cos(phi), np.sin(phi)])
    h = np.asarray(heights, float)
    c = np.asarray(center, float)
    period = duration + rest

    def sp(t, state=None):
        k, tau = divmod(t, period)
        sign = 1.0 if int(k) % 2 == 0 else -1.0
        s = min(tau / duration, 1.0)
        pos = -np.cos(np.pi * s)                       # -1 .. 1
        vel = np.pi / duration * np.sin(np.pi * s) if tau < duration else 0.0
        acc = (np.pi / duration) ** 2 * np.cos(np.pi * s) if tau < duration else 0.0
        p = np.column_stack([c + sign * radius * pos * d, h])
        v = np.column_stack([sign * radius * vel * d, np.zeros(n)])
        a = np.column_stack([sign * radius * acc * d, np.zeros(n)])
        return Setpoints(p, v, a, np.zeros(n))

    start = np.column_stack([c - radius * d, h])
    return sp, start


def random_walk(n: int, cube=((-1.0, 1.0), (-1.0, 1.0), (0.05, 1.2)), goal_period: float = 3.0,
                v_max: float = 1.0, k_att: float = 1.0, k_rep: float = 0.02, d_rep: float = 0.35,
                seed: int = 0):
    """Goals every ``goal_period`` s; v_d = k_att (goal - p) + repulsion, |v_d| <= v_max;
    the position setpoint is integrated from v_d (what the on-board planner would do)."""
    rng = np.random.default_rng(seed)
    lo = np.array([c[0] for c in cube])
    hi = np.array([c[1] for c in cube])
    goals = rng.uniform(lo, hi, (n, 3))
    state = {"p_d": None, "t": 0.0, "next_goal": goal_period}
    start = rng.uniform(lo + [0, 0, 0.2], hi, (n, 3))

    def sp(t, st):
        if state["p_d"] is None:
            state["p_d"] = st.p.copy()
        if t >= state["next_goal"]:
            goals[:] = rng.uniform(lo, hi, (n, 3))
            state["next_goal"] += goal_period
        p = st.p
        diff = p[:, None, :] - p[None, :, :]
        dist = np.linalg.norm(diff, axis=2) + np.eye(n) * 1e9
        rep = (k_rep * diff / dist[..., None] ** 3 * (dist < d_rep)[..., None]).sum(1)
        v = k_att * (goals - state["p_d"]) + rep
        speed = np.linalg.norm(v, axis=1, keepdims=True)
        v = v * np.minimum(1.0, v_max / np.maximum(speed, 1e-9))
        dt = t - state["t"]
        state["p_d"] = np.clip(state["p_d"] + v * dt, lo, hi)
        state["t"] = t
        return Setpoints(state["p_d"].copy(), v, np.zeros((n, 3)), np.zeros(n))

    return sp, start


# The rings as the authors flew them: their 16-robot trajectory files
# (aerorobotics/neural-swarm, hardware/neural-swarm-ros-pkg/scripts/three_rings.py and
# three_rings16_pps/, read for these facts, evaluated in a one-off): a horizontal ellipse
# and two vertical circles in the xz plane centred on its two x vertices, all at 0.7 m;
# one lap per 5 s on every ring (angular speed 1.13-1.45 rad/s along the polynomials),
# every robot counter-clockwise from the first in-plane axis to the second, evenly spaced
# in phase from 11.6 deg; one flight of 10 s from rest to rest covering 696 deg.
RING_Z = 0.7                 # m, height of the horizontal ring and of the vertical rings' centres
RING_AXES_H = (0.5, 0.3)     # m, semi-axes of the horizontal ellipse (x, y)
RING_RADIUS_V = 0.3          # m, vertical circles
RING_CENTER_X = 0.5          # m, the vertical circles' centres at x = -0.5 and +0.5
RING_PERIOD = 5.0            # s per lap
RING_PHASE0 = np.radians(11.6)
RING_SECONDS = 10.0          # s of ring motion, from rest to rest
RING_RAMP = 0.33             # s, cosine ramp of the angular speed at each end: 2 pi / 5 s x
                             # (10 - 0.33) s = 696 deg, the authors' flight's


def _ring(center, e1, e2, a, b, n, phase0=RING_PHASE0):
    """(center, in-plane axes, semi-axes, n robots evenly spaced in phase)."""
    return (np.asarray(center, float), np.asarray(e1, float), np.asarray(e2, float), a, b,
            phase0 + 2 * np.pi * np.arange(n) / n)


def ring_angle(t: float):
    """Angle travelled on every ring by time t, its rate and its acceleration: one lap
    per RING_PERIOD, ramped up from rest over RING_RAMP at the start and down to rest
    at RING_SECONDS (cosine profile of the rate)."""
    w0, tr, T = 2 * np.pi / RING_PERIOD, RING_RAMP, RING_SECONDS
    k = np.pi / tr

    def up(s):          # angle, rate, acceleration s after a start from rest
        return (w0 * (s / 2 - np.sin(k * s) / (2 * k)), w0 * (1 - np.cos(k * s)) / 2,
                w0 * k * np.sin(k * s) / 2)

    total = w0 * (T - tr)
    if t <= 0.0:
        return 0.0, 0.0, 0.0
    if t < tr:
        return up(t)
    if t <= T - tr:
        return w0 * (t - tr / 2), w0, 0.0
    if t < T:
        ang, rate, acc = up(T - t)
        return total - ang, rate, -acc
    return total, 0.0, 0.0


def intertwined_rings(robots: int):
    """The paper's ring experiments ("Control Performance in Flight Tests", Fig. plot5
    and fig1): robots move on a horizontal ring and on vertical rings that pass
    through it like chain links, each vertical ring centred on the horizontal one,
    so the horizontal ring's robots fly through the vertical rings and pass under and
    over their robots.  The vertical rings carry the small robots with stronger motors
    ("S*", the robots whose z error the paper reports).

    * 16 robots: the authors' flight (the constants above): two large and four small
      on the horizontal ellipse (in phase order S, S, L, S, S, L: cf5, cf7, cf102,
      cf51, cf10, cf101), five on each vertical circle (x = -0.5: cf9, cf52, cf11,
      cf17, cf21; x = +0.5: cf1, cf4, cf8, cf200, cf6). cf51 and cf52 are the
      collection's 34 g small robots; the others of the paper's S* robots are not
      named, so every other small robot of a vertical ring is S* and the horizontal
      ring's are small.
    * 5 robots: no trajectory files are published; the same rings with one vertical
      circle (x = +0.5, three S*) and a horizontal circle of radius 0.5 m (the paper:
      a circle) carrying the two large robots opposite each other, timed so that the
      large robots pass right over an S* at the bottom of the vertical circle (once in
      the flight) and right under it at its top (twice).

    Returns (robot types, setpoints, start positions, vertical-ring robot indices)."""
    ex, ey, ez = np.eye(3)
    r, z, xc = RING_RADIUS_V, RING_Z, RING_CENTER_X
    if robots == 5:
        rings = [(("large", "large"), _ring([0, 0, z], ex, ey, xc, xc, 2)),
                 (("small*",) * 3, _ring([xc, 0, z], ex, ez, r, r, 3, RING_PHASE0 - np.pi / 2))]
    elif robots == 16:
        rings = [(("small", "small", "large", "small", "small", "large"), _ring([0, 0, z], ex, ey, *RING_AXES_H, 6)),
                 (("small*", "small", "small*", "small*", "small*"), _ring([-xc, 0, z], ex, ez, r, r, 5)),
                 (("small*",) * 5, _ring([xc, 0, z], ex, ez, r, r, 5))]
    else:
        raise ValueError(f"intertwined_rings: the paper flies 5 or 16 robots, not {robots}")
    types = [t for ts, _ in rings for t in ts]
    c = np.concatenate([np.repeat(g[0][None], len(g[5]), 0) for _, g in rings])
    e1 = np.concatenate([np.repeat(g[1][None], len(g[5]), 0) for _, g in rings])
    e2 = np.concatenate([np.repeat(g[2][None], len(g[5]), 0) for _, g in rings])
    a = np.concatenate([np.full(len(g[5]), g[3]) for _, g in rings])[:, None]
    b = np.concatenate([np.full(len(g[5]), g[4]) for _, g in rings])[:, None]
    phase = np.concatenate([g[5] for _, g in rings])[:, None]
    vertical = [k for k, (ts, g) in enumerate((ts, g) for ts, g in rings for _ in ts) if g[2][2] == 1.0]
    n = len(types)

    def sp(t, state=None):
        ang0, rate, acc0 = ring_angle(t)
        ang = phase + ang0
        cs, sn = np.cos(ang), np.sin(ang)
        tangent = -a * sn * e1 + b * cs * e2
        p = c + a * cs * e1 + b * sn * e2
        v = rate * tangent
        acc = -rate * rate * (a * cs * e1 + b * sn * e2) + acc0 * tangent
        return Setpoints(p, v, acc, np.zeros(n))

    return types, sp, sp(0.0).p, vertical


def _cosine_setpoints(W, T):
    """Setpoints along waypoints W [w, n, 3] at times T [w], joined by cosine
    profiles (rest at every waypoint)."""
    n = W.shape[1]

    def sp(t, state=None):
        k = int(np.clip(np.searchsorted(T, t, side="right") - 1, 0, len(T) - 2))
        d = T[k + 1] - T[k]
        s = min(max((t - T[k]) / d, 0.0), 1.0)
        delta = W[k + 1] - W[k]
        p = W[k] + delta * (1.0 - np.cos(np.pi * s)) / 2.0
        inside = 0.0 < s < 1.0
        v = delta * (np.pi / (2.0 * d)) * np.sin(np.pi * s) if inside else np.zeros((n, 3))
        a = delta * (np.pi ** 2 / (2.0 * d * d)) * np.cos(np.pi * s) if inside else np.zeros((n, 3))
        return Setpoints(p, v, a, np.zeros(n))

    return sp


def _pair_gap(diameters, gap_max: float, duration: float, who: str) -> float:
    """The tight collision distance r = (D_0 + D_1) / 2 of a pair; a clear error for an
    empty gap range r..gap_max or a non-positive duration."""
    g_min = (float(diameters[0]) + float(diameters[1])) / 2.0
    if not 0.0 < g_min < gap_max:
        raise ValueError(f"{who}: gap range {g_min:.3f}..{gap_max:.3f} m is empty")
    if duration <= 0:
        raise ValueError(f"{who}: duration must be positive")
    return g_min


def near_field(types, diameters, duration: float, z_low=(0.5, 1.0), gap_max: float = 1.2, reach: float = 0.35,
               offset: float = 0.06, center: float = 0.2, t_cross=(2.0, 4.0), t_sweep=(2.0, 4.0),
               t_pass=(1.25, 5.0), pass_reach: float = 0.8, pass_gap=(0.03, 0.6), passes: int = 3,
               t_move: float = 2.0,
               t_move_pass: float = 2.0, seed: int = 0):
    """Close-range flights of a pair (near-field downwash data), in blocks; in
    every block one robot is above the other (the roles alternate from block to
    block).  A block starts with a sweep: the lower robot comes in slowly along a
    horizontal direction d from ``reach`` m to one side (relative position robot
    1 - robot 0, whatever the roles) at a vertical gap g_a, stays nearly under the
    upper robot (within 3 cm along d, a small constant offset |y| <= ``offset``
    across d) while the gap changes slowly to g_b, and leaves to ``reach`` m on
    the other side.  Then ``passes`` passes straight through under the upper robot
    at one gap each, from ``pass_reach`` m on one side to ``pass_reach`` m on the
    other in a time drawn log-uniformly from ``t_pass`` (relative speeds up to
    2 m/s under the upper robot, as in the planner's crossings, where the wake hits
    the lower robot for only a tenth of a second, with accelerations of at most
    2.5 m/s^2 per robot, the planner's action box).  Gaps are drawn
    log-uniformly (stratified per role) from the tight collision distance
    r = (D_0 + D_1) / 2 to ``gap_max`` for the sweeps and in ``pass_gap`` for the
    passes (where a fast crossing's short, sharp wake is hardest to learn); a
    pass below r is offset sideways just enough to keep the distance >= r (the
    planner's tight sphere allows that).  Each segment's
    direction is within 60 degrees of where the last one ended, so the moves
    between segments (heights, roles and centre change there) keep the robots at
    least ``reach`` cos 30 deg apart sideways, never through each other.  Both
    robots carry half of the relative motion about a slowly moving centre.
    Waypoints are joined by cosine profiles (rest at every waypoint).  Returns
    (setpoints, start positions, waypoint times)."""
    rng = np.random.default_rng(seed)
    g_min = _pair_gap(diameters, gap_max, duration, "near_field")
    mean_block = t_move + (t_cross[0] + t_cross[1] + t_sweep[0] + t_sweep[1]) / 2 + \
        passes * (t_move_pass + np.sqrt(t_pass[0] * t_pass[1]))
    blocks = max(2, int(np.ceil(duration / mean_block)) + 1)
    kinds = np.tile(["sweep"] + ["pass"] * passes, blocks)
    roles = np.repeat(np.arange(blocks) % 2, passes + 1)        # index of the upper robot
    gaps = np.zeros((len(kinds), 2))
    for r in (0, 1):
        for kind, lo, hi in (("sweep", g_min, gap_max), ("pass", min(pass_gap[0], g_min), pass_gap[1])):
            idx = np.flatnonzero((roles == r) & (kinds == kind))
            for e in (0, 1):
                u = (rng.permutation(len(idx)) + rng.uniform(0, 1, len(idx))) / len(idx)
                gaps[idx, e] = lo * (hi / lo) ** u

    def pose(upper, gap, zl, c, rel):
        p = np.zeros((2, 3))
        p[0, :2], p[1, :2] = c - rel / 2, c + rel / 2
        p[upper, 2], p[1 - upper, 2] = zl + gap, zl
        return p

    pts, times = [], []
    phi = rng.uniform(0, 2 * np.pi)
    for k, kind in enumerate(kinds):
        zl = rng.uniform(*z_low)
        c = rng.uniform(-center, center, 2)
        (ga, gb), up = gaps[k], roles[k]
        d, n = np.array([np.cos(phi), np.sin(phi)]), np.array([-np.sin(phi), np.cos(phi)])
        across = rng.uniform(-offset, offset)
        if kind == "pass" and ga < g_min:             # beside the sphere of radius r around the upper robot
            across = np.sign(across) * (np.sqrt(g_min ** 2 - ga ** 2) + abs(across))
        across = across * n
        if kind == "pass":
            t0 = times[-1] + t_move_pass if times else 0.0
            pts += [pose(up, ga, zl, c, pass_reach * d + across), pose(up, ga, zl, c, -pass_reach * d + across)]
            times += [t0, t0 + np.exp(rng.uniform(np.log(t_pass[0]), np.log(t_pass[1])))]
        else:                                         # in, sweep the gap nearly under the upper robot, out
            t0 = times[-1] + t_move if times else 0.0
            tc = rng.uniform(*t_cross)
            pts += [pose(up, ga, zl, c, reach * d + across),
                    pose(up, ga, zl, c, rng.uniform(-0.03, 0.03) * d + across),
                    pose(up, gb, zl, c, rng.uniform(-0.03, 0.03) * d + across),
                    pose(up, gb, zl, c, -reach * d + across)]
            times += [t0, t0 + tc / 2, t0 + tc / 2 + rng.uniform(*t_sweep)]
            times.append(times[-1] + tc / 2)
        phi += np.pi + rng.uniform(-np.pi / 3, np.pi / 3)      # start near where this segment ended
    W = np.stack(pts)                                 # [w, 2, 3]
    T = np.array(times)
    return _cosine_setpoints(W, T), W[0].copy(), T


WHO_MOVES_ROLES = ((0, "below"), (0, "above"), (1, "below"), (1, "above"))   # (moving robot, where it moves)


def who_moves(diameters, duration: float, gap_max: float = 1.5, reach: float = 0.7, offset: float = 0.06,
              z_range=(0.3, 2.0), v_peak=(0.3, 1.4), a_max: float = 2.5, passes: int = 4, seed: int = 0):
    """A pair in which only one robot moves at a time (data that separates who
    moves: the truth depends on each robot's own velocity, host/sim/aero.py, the
    model sees the relative one).  In blocks, one per role of WHO_MOVES_ROLES in
    turn (each robot moves, under and over the other): the still robot comes to
    the centre and hovers there; the moving robot flies ``passes`` times from
    ``reach`` m on one side to ``reach`` m on the other and back (both
    directions), under (or over) the hovering one at a vertical gap drawn
    log-uniformly from the tight collision distance r = (D_0 + D_1) / 2 to
    ``gap_max`` (and the room within ``z_range``) at each end of the pass (so it climbs or descends as it crosses),
    ``offset`` m at most sideways; every other pass stops under the hovering robot
    and changes the gap there (a pure climb or descent under it).  Peak speeds
    drawn in ``v_peak`` (m/s, at most ``a_max`` m/s^2), heights within
    ``z_range``.  Between blocks both robots rest on opposite
    sides, ``reach`` m from the centre, and turn the pair's direction by up to 90
    degrees (never closer than sqrt(2) ``reach``).  Returns (setpoints, start
    positions, waypoint times, the moving robot per segment (-1: both or none))."""
    W, T, movers = _who_moves_waypoints(diameters, duration, gap_max, reach, offset, z_range, v_peak, a_max,
                                        passes, np.random.default_rng(seed))
    return _cosine_setpoints(W, T), W[0].copy(), T, movers


def who_moves_bystander(diameters, duration: float, gap_max: float = 1.5, reach: float = 0.7,
                        offset: float = 0.06, z_range=(0.3, 2.0), v_peak=(0.3, 1.4), a_max: float = 2.5,
                        passes: int = 4, radius=(0.3, 0.9), clearance: float = 0.05, tries: int = 200,
                        seed: int = 0):
    """``who_moves`` of robots 0 and 1 with robot 2 hovering nearby (issue 24: the
    planner's three-robot overs were a robot moving under a hovering one with a third
    robot about a metre away, which the pair flights never show the model).  Before
    each block of ``who_moves`` robot 2 flies alone (the others still) to a spot drawn
    at a horizontal distance in ``radius`` (m) from the block's centre, in any
    direction, at any height of ``z_range``, and hovers there through the block; a spot
    is drawn again (at most ``tries`` times) until robot 2 stays at least the tight
    collision distance (D_2 + D_k) / 2 + ``clearance`` from both others through its move
    and the block (checked exactly on the straight segments).  Returns (setpoints [3
    robots], start positions, waypoint times, the moving robot per segment (2: the
    bystander, -1: both of the pair))."""
    if len(diameters) != 3:
        raise ValueError(f"who_moves_bystander: three robots, got {len(diameters)} diameters")
    rng = np.random.default_rng(seed)
    W2, T2, mv2 = _who_moves_waypoints(diameters[:2], duration, gap_max, reach, offset, z_range, v_peak, a_max,
                                       passes, rng)
    r_min = np.array([(float(diameters[k]) + float(diameters[2])) / 2 + clearance for k in (0, 1)])
    starts = [j for j in range(len(mv2)) if mv2[j] == -1] + [len(mv2)]

    def clear(q_from, q, j0, j1):
        """Robot 2 moving q_from -> q with the pair at W2[j0], then still at q through segments j0 .. j1 - 1."""
        a = np.concatenate([W2[j0] - q_from] + [W2[j] - q for j in range(j0, j1)])
        b = np.concatenate([np.tile(q_from - q, (2, 1))] + [W2[j + 1] - W2[j] for j in range(j0, j1)])
        bb = np.maximum((b * b).sum(1), 1e-12)
        s = np.clip(-(a * b).sum(1) / bb, 0.0, 1.0)
        d = np.linalg.norm(a + s[:, None] * b, axis=1)     # the closest approach on each straight segment
        return bool((d >= np.tile(r_min, len(d) // 2)).all())

    pts, times, movers = [], [0.0], []
    q = None
    for k in range(len(starts) - 1):
        j0, j1 = starts[k], starts[k + 1]
        for _ in range(tries):
            ang, rho = rng.uniform(0, 2 * np.pi), rng.uniform(*radius)
            cand = np.array([rho * np.cos(ang), rho * np.sin(ang), rng.uniform(*z_range)])
            if clear(cand if q is None else q, cand, j0, j1):
                break
        else:
            raise ValueError(f"who_moves_bystander: no spot for robot 2 in block {k} after {tries} draws "
                             f"(seed {seed}); widen radius or z_range")
        if q is None:
            pts.append(np.vstack([W2[0], cand]))
        else:
            pts.append(np.vstack([W2[j0], cand]))
            times.append(times[-1] + _segment_time(float(np.abs(cand - q).max()), rng, v_peak, a_max))
            movers.append(2)
        q = cand
        for j in range(j0, j1):
            pts.append(np.vstack([W2[j + 1], q]))
            times.append(times[-1] + float(T2[j + 1] - T2[j]))
            movers.append(int(mv2[j]))
    W = np.stack(pts)
    T = np.array(times)
    return _cosine_setpoints(W, T), W[0].copy(), T, np.array(movers)


def _segment_time(dist: float, rng, v_peak, a_max: float) -> float:
    """s: a cosine segment of ``dist`` m at a peak speed drawn in ``v_peak`` (m/s), at most
    ``a_max`` m/s^2, at least 0.2 s."""
    vp = rng.uniform(*v_peak)
    return max(np.pi / 2 * dist / vp, np.pi * np.sqrt(dist / (2 * a_max)), 0.2)


def _who_moves_waypoints(diameters, duration, gap_max, reach, offset, z_range, v_peak, a_max, passes, rng):
    """who_moves' waypoints W [w, 2, 3], times T [w] and the moving robot per segment."""
    g_min = _pair_gap(diameters, gap_max, duration, "who_moves")
    if z_range[1] - z_range[0] < 0.5 + g_min:
        raise ValueError(f"who_moves: height range {z_range} leaves no room for the gaps")
    phi = rng.uniform(0, 2 * np.pi)
    pts, times, movers = [], [], []

    def add(p, mover, dist=None):
        """Append waypoint p [2, 3]; the segment's time from its length and a drawn peak speed."""
        dist = float(np.abs(p - pts[-1]).max()) if dist is None else dist
        t = _segment_time(dist, rng, v_peak, a_max)
        pts.append(p)
        times.append(times[-1] + t)
        movers.append(mover)

    def log_gap(hi):
        return g_min * (hi / g_min) ** rng.uniform()

    e = np.array([np.cos(phi), np.sin(phi), 0.0])
    z0 = np.mean(z_range)
    pts.append(np.array([-reach * e + [0, 0, z0], reach * e + [0, 0, z0]]))   # robot 0 on -e, robot 1 on +e
    times.append(0.0)
    k = 0
    while times[-1] < duration:
        mover, where = WHO_MOVES_ROLES[k % len(WHO_MOVES_ROLES)]
        still = 1 - mover
        k += 1
        # the still robot's height, at least 0.5 m from the side of z_range the mover flies in
        zs = rng.uniform(z_range[0] + 0.5, z_range[1]) if where == "below" else \
            rng.uniform(z_range[0], z_range[1] - 0.5)
        sign = -1.0 if where == "below" else 1.0
        room = min(gap_max, zs - z_range[0] if where == "below" else z_range[1] - zs)
        # turn the pair (both robots, opposite sides) and set the heights: robot 0 at -e, robot 1 at +e
        phi += rng.uniform(-np.pi / 2, np.pi / 2)
        e = np.array([np.cos(phi), np.sin(phi), 0.0])
        n = np.array([-e[1], e[0], 0.0])
        side = np.array([-1.0, 1.0])
        p = np.array([side[0] * reach * e, side[1] * reach * e])
        p[still, 2] = zs
        p[mover, 2] = zs + sign * log_gap(room)
        add(p, -1)
        p = p.copy()
        p[still, :2] = 0.0                              # the still robot to the centre (the other waits aside)
        add(p, still)
        s = side[mover]
        for j in range(passes):
            across = rng.uniform(-offset, offset) * n
            g2 = log_gap(room)
            q = p.copy()
            if j % 2:                                   # in under it, change the gap there, out
                q[mover] = across + [0, 0, p[mover, 2]]
                add(q.copy(), mover)
                q[mover, 2] = zs + sign * g2
                add(q.copy(), mover)
            s = -s
            q[mover] = s * reach * e + across + [0, 0, zs + sign * g2]
            add(q, mover)
            p = q
        p = p.copy()
        p[still] = -s * reach * e + [0, 0, zs]          # the still robot back to the far side
        add(p, still)
        if s != side[mover]:                            # the robots ended on swapped sides: keep robot 0 on -e
            phi += np.pi
    return np.stack(pts), np.array(times), np.array(movers)
