"""Inference queries as the C API sees them, batched: used by the references,
the format calibration, the C-vs-reference tests and the benchmark.

A query is one call of ns2_predict_*: robot type, own position p and velocity v
(world frame), and a list of neighbours (robot type + x_ij) of length n[q].
Slots beyond n[q] are padding and never read.  With ``model.history_ms`` (L lags)
x_ij has 6 (1 + L) values (now, then each lag) and ``past`` holds the robot's own
[p; v] at each lag (ns2_predict_*_hist's own_past); without, ``past`` is [Q, 0, 6].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import Config


@dataclass
class Queries:
    robot_type: np.ndarray  # uint8 [Q]
    p: np.ndarray           # float32 [Q, 3]
    v: np.ndarray           # float32 [Q, 3]
    n: np.ndarray           # int64 [Q], neighbours given
    nbr_type: np.ndarray    # uint8 [Q, S]
    nbr_rel: np.ndarray     # float32 [Q, S, 6 (1 + L)]
    past: np.ndarray | None = None  # float32 [Q, L, 6]: own [p; v] at each history lag

    def __post_init__(self):
        if self.past is None:
            self.past = np.zeros((len(self.robot_type), 0, 6), np.float32)

    @property
    def lags(self) -> int:
        return int(self.past.shape[1])

    def __len__(self) -> int:
        return int(self.robot_type.shape[0])

    @property
    def slots(self) -> int:
        return int(self.nbr_type.shape[1])

    def given(self) -> np.ndarray:
        """[Q, S] mask of slots that are part of the query."""
        return np.arange(self.slots)[None, :] < self.n[:, None]

    def take(self, idx) -> "Queries":
        return Queries(self.robot_type[idx], self.p[idx], self.v[idx], self.n[idx],
                       self.nbr_type[idx], self.nbr_rel[idx], self.past[idx])

    @staticmethod
    def concat(parts: list["Queries"]) -> "Queries":
        s = max(q.slots for q in parts)

        def pad(a, fill):
            width = [(0, 0), (0, s - a.shape[1])] + [(0, 0)] * (a.ndim - 2)
            return np.pad(a, width, constant_values=fill)

        return Queries(np.concatenate([q.robot_type for q in parts]),
                       np.concatenate([q.p for q in parts]), np.concatenate([q.v for q in parts]),
                       np.concatenate([q.n for q in parts]),
                       np.concatenate([pad(q.nbr_type, 0) for q in parts]),
                       np.concatenate([pad(q.nbr_rel, 0.0) for q in parts]),
                       np.concatenate([q.past for q in parts]))


def _box_arrays(cfg: Config):
    nt = len(cfg.neighbor_types)
    box = np.array([cfg.input_box(t) for t in range(nt)], dtype=np.float64)  # [T, 6, 2]
    vol = np.array([[cfg.volume(r, t) for t in range(cfg.num_robot_types)]
                    for r in range(cfg.num_robot_types)], dtype=np.float64)  # [K, K, 2, 3]
    return box, vol


def random_queries(cfg: Config, n: int, seed: int, max_given: int | None = None,
                   inside: float = 0.8, edge: float = 0.05, wild: float = 0.0) -> Queries:
    """Random queries.  Neighbour counts uniform in 0..max_given (default: the C
    maximum + 4, to exercise truncation), all type mixes; a fraction ``inside`` of
    neighbours placed inside their interaction volume, the rest anywhere in the
    box; ``edge`` of all coordinates snapped to a box/volume edge; ``wild`` of all
    coordinates replaced by out-of-box values, NaN or Inf (and invalid types).
    With ``model.history_ms`` every neighbour's past states and the robot's own are
    drawn anywhere in their boxes (edges and wild values alike); these draws come
    after all others, so a config without history gets the same queries as before."""
    rng = np.random.default_rng(seed)
    k = cfg.num_robot_types
    max_given = cfg.model["max_neighbors"] + 4 if max_given is None else max_given
    box, vol = _box_arrays(cfg)
    env_box = box[cfg.env_index]
    robot_type = rng.integers(0, k, n)
    own = rng.uniform(env_box[:, 0], env_box[:, 1], (n, 6))  # x_env = [-p; -v]
    snap = rng.uniform(size=(n, 6)) < edge
    own = np.where(snap, np.where(rng.uniform(size=(n, 6)) < 0.5, env_box[:, 0], env_box[:, 1]), own)
    p, v = -own[:, :3], -own[:, 3:]
    counts = rng.integers(0, max_given + 1, n)
    s = max(max_given, 1)
    nbr_type = rng.integers(0, k, (n, s))
    nb_box = box[0]
    rel = rng.uniform(nb_box[:, 0], nb_box[:, 1], (n, s, 6))
    v_lo = vol[robot_type[:, None], nbr_type, 0]  # [n, s, 3]
    v_hi = vol[robot_type[:, None], nbr_type, 1]
    in_vol = rng.uniform(v_lo, v_hi)
    put_inside = rng.uniform(size=(n, s)) < inside
    rel[..., :3] = np.where(put_inside[..., None], in_vol, rel[..., :3])
    snap = rng.uniform(size=(n, s, 6)) < edge
    edge_val = np.concatenate([np.where(rng.uniform(size=(n, s, 3)) < 0.5, v_lo, v_hi),
                               np.where(rng.uniform(size=(n, s, 3)) < 0.5,
                                        nb_box[3:, 0], nb_box[3:, 1])], axis=-1)
    rel = np.where(snap, edge_val, rel)
    p = p.astype(np.float32)
    v = v.astype(np.float32)
    rel = rel.astype(np.float32)
    lags = len(cfg.history_ms)
    past = np.zeros((n, 0, 6), np.float32)
    if lags:
        nb_past = rng.uniform(np.tile(nb_box[:, 0], lags), np.tile(nb_box[:, 1], lags), (n, s, 6 * lags))
        snap = rng.uniform(size=nb_past.shape) < edge
        nb_past = np.where(snap, np.where(rng.uniform(size=nb_past.shape) < 0.5, np.tile(nb_box[:, 0], lags),
                                          np.tile(nb_box[:, 1], lags)), nb_past)
        rel = np.concatenate([rel, nb_past.astype(np.float32)], -1)
        past = -rng.uniform(env_box[:, 0], env_box[:, 1], (n, lags, 6)).astype(np.float32)  # own [p; v]
    if wild > 0:
        specials = np.array([np.nan, np.inf, -np.inf, 1e30, -1e30, 50.0, -50.0, 1e-40], np.float32)
        m = rng.uniform(size=rel.shape) < wild
        rel[m] = np.where(rng.uniform(size=m.sum()) < 0.5, specials[rng.integers(0, specials.size, m.sum())],
                          rel[m] * rng.uniform(2, 20, m.sum()).astype(np.float32))
        m = rng.uniform(size=(n, s)) < wild
        nbr_type[m] = rng.integers(k, 256, m.sum())
        own_f = np.concatenate([p, v], 1)
        m = rng.uniform(size=own_f.shape) < wild * 0.1
        own_f[m] = np.where(rng.uniform(size=m.sum()) < 0.5, specials[rng.integers(0, 3, m.sum())],
                            own_f[m] * rng.uniform(2, 20, m.sum()).astype(np.float32))
        p, v = own_f[:, :3].copy(), own_f[:, 3:].copy()
        m = rng.uniform(size=n) < wild * 0.05
        robot_type[m] = rng.integers(k, 256, m.sum())
        if lags:
            m = rng.uniform(size=past.shape) < wild * 0.1
            past[m] = specials[rng.integers(0, specials.size, m.sum())]
    return Queries(robot_type.astype(np.uint8), p, v, counts.astype(np.int64),
                   nbr_type.astype(np.uint8), rel, past)
