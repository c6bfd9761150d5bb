"""The one neighbour selection (paper, "Heterogeneous Swarm Dynamics": the
interaction volume V(type_i, type_j)), in exactly the C's arithmetic
(firmware/src/ns2_select.c, ns2_prepare): every data-set builder and the Python
reference of the C call these functions, so training and flight agree on which
neighbours count, sample for sample.

* the relative state x_ij = [p_j - p_i; v_j - v_i] is formed in float32 from the
  float32 states (the drone holds float32 positions and subtracts them);
* robot j counts when its type is a robot type, its relative state is finite and
  p_j - p_i lies in the closed cuboid [lo, hi] of float32 bounds (lo <= x <= hi,
  false for NaN), in the order the neighbours are given, until ``max_neighbors``
  are accepted (the rest are truncated);
* every input is clamped to its declared box before phi (x < lo ? lo : x > hi ? hi : x);
  the environment's input is [-p_i; -v_i] in float32, clamped likewise;
* with ``model.history_ms`` every input also holds the states at each lag (6 values
  each, clamped to the same box; the environment's from the robot's own past); the
  selection is decided on the present state, and a non-finite past value makes a
  neighbour invalid (a non-finite own past fails the query, like its own state).
"""
from __future__ import annotations

import numpy as np


def volumes_f32(cfg) -> np.ndarray:
    """[K, K, 2, 3] float32: lo/hi of V(robot type, neighbour type), as in the C tables."""
    k = cfg.num_robot_types
    return np.array([[cfg.volume(r, t) for t in range(k)] for r in range(k)], np.float32)


def boxes_f32(cfg) -> np.ndarray:
    """[T, 6, 2] float32 input boxes of every neighbour type (environment last)."""
    return np.array([cfg.input_box(t) for t in range(len(cfg.neighbor_types))], np.float32)


def relative_state(p_i, v_i, p_j, v_j) -> np.ndarray:
    """x_ij [..., 6] float32, p_j - p_i and v_j - v_i subtracted in float32."""
    f = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return np.concatenate([f(p_j) - f(p_i), f(v_j) - f(v_i)], -1).astype(np.float32)


def env_state(p_i, v_i) -> np.ndarray:
    """The environment's input [-p_i; -v_i] [..., 6] float32 (unclamped)."""
    return -np.concatenate([np.asarray(p_i, np.float32), np.asarray(v_i, np.float32)], -1)


def env_input(p_i, v_i, past=None) -> np.ndarray:
    """The environment's phi input [-p_i; -v_i] [..., 6], then the robot's own past
    negated ([..., lags, 6] of [p; v] at each lag, ``model.history_ms``), unclamped."""
    now = env_state(p_i, v_i)
    if past is None or np.shape(past)[-2] == 0:
        return now
    past = np.asarray(past, np.float32)
    return np.concatenate([now, -past.reshape(*past.shape[:-2], -1)], -1)


def clamp(x: np.ndarray, box: np.ndarray) -> np.ndarray:
    """x < lo ? lo : (x > hi ? hi : x), elementwise with box [..., 6, 2] (float32); x of
    6 (1 + lags) values (``model.history_ms``): every 6-block to the same box, as the C."""
    lo, hi = box[..., 0], box[..., 1]
    reps = np.shape(x)[-1] // lo.shape[-1]
    if reps > 1:
        lo, hi = (np.tile(a, (1,) * (a.ndim - 1) + (reps,)) for a in (lo, hi))
    return np.where(x < lo, lo, np.where(x > hi, hi, x)).astype(np.float32)


def membership(volumes: np.ndarray, robot_type, nbr_type, rel: np.ndarray, given, num_robot_types: int,
               max_neighbors: int):
    """Which neighbour slots enter the sum, as ns2_select_neighbors decides.

    robot_type [Q] (valid indices), nbr_type [Q, S], rel [Q, S, 6] float32, given
    [Q, S] bool (slots that exist, in the order the C receives them).  Returns the
    boolean masks (valid, inside, accepted), each [Q, S]: valid = a robot type and
    finite; inside = valid and p_j - p_i in V; accepted = inside and among the
    first ``max_neighbors`` inside slots."""
    rel = np.asarray(rel, np.float32)
    nbr_type = np.asarray(nbr_type)
    with np.errstate(invalid="ignore"):
        valid = np.asarray(given, bool) & (nbr_type < num_robot_types) & np.isfinite(rel).all(-1)
        rt = np.minimum(np.asarray(robot_type), num_robot_types - 1).astype(np.int64)
        nt = np.minimum(nbr_type, num_robot_types - 1).astype(np.int64)
        vol = volumes[rt[:, None], nt]                       # [Q, S, 2, 3]
        pos = rel[..., :3]
        inside = valid & ((pos >= vol[..., 0, :]) & (pos <= vol[..., 1, :])).all(-1)
    accepted = inside & (np.cumsum(inside, axis=1) <= max_neighbors)
    return valid, inside, accepted
