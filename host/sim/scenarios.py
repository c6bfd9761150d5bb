"""Data-collection and test scenarios (paper, "Data Collection" and "Experiments").

* ``swap``: robots on a vertical cylinder at different heights (0.2-0.3 m apart)
  fly straight to the opposite side and back; all pass the axis at the same
  instant, i.e. are vertically aligned once per swap.
* ``random_walk``: every robot is attracted by a goal drawn uniformly in a cube at
  a fixed rate and repelled by its neighbours (artificial potentials), speed
  limited; the cube reaches down to the ground (ground-effect data).
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


def rings(counts, heights, radius: float = 0.5, period: float = 8.0, seed: int = 0):
    """Robots on horizontal circles (one per height), neighbouring rings turning in
    opposite directions, so robots of different rings pass over each other
    (the paper's intertwined rings: 5 robots on 2 rings, 16 robots on 3 rings)."""
    rng = np.random.default_rng(seed)
    ring = np.concatenate([np.full(c, k) for k, c in enumerate(counts)])
    phase0 = np.concatenate([rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(c) / c for c in counts])
    direction = np.where(ring % 2 == 0, 1.0, -1.0)
    h = np.asarray(heights, float)[ring]
    w = 2 * np.pi / period
    n = len(ring)

    def sp(t, state=None):
        ang = phase0 + direction * w * t
        p = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), h])
        v = np.column_stack([-radius * w * direction * np.sin(ang), radius * w * direction * np.cos(ang),
                             np.zeros(n)])
        a = np.column_stack([-radius * w * w * np.cos(ang), -radius * w * w * np.sin(ang), np.zeros(n)])
        return Setpoints(p, v, a, np.zeros(n))

    return sp, sp(0.0).p
