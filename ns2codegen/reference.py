"""Deterministic Python references of the C inference (firmware/src/ns2_*.c).

* ``predict_f32``: torch float32, the same operations in the same order as the C
  (dot products from the bias, inputs in index order, latent sum environment
  first then neighbours in array order), hence bit-exact with the C float path.
* ``predict_q15``: an integer model (numpy int64) of the fixed-point C, also
  checking at every step that the int32 accumulators stay in range.

Both share the neighbour selection of ns2_select.c (``select``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .queries import Queries
from .selection import boxes_f32, clamp, env_input, membership, volumes_f32

ERR_ROBOT_TYPE, ERR_STATE = -1, -2
INT32_MAX = 2**31 - 1


@dataclass
class Selection:
    status: np.ndarray     # int32 [Q]
    accepted: np.ndarray   # bool [Q, S], slots that enter the sum
    n_invalid: np.ndarray
    n_outside: np.ndarray
    n_truncated: np.ndarray
    x_env: np.ndarray      # float32 [Q, 6 (1 + lags)], clamped environment input


def select(m, q: Queries) -> Selection:
    """Mirror of ns2_prepare / ns2_select_neighbors for a batch of queries (the one
    selection, ``ns2codegen.selection``)."""
    k = m.num_robot_types
    given = q.given()
    with np.errstate(invalid="ignore"):
        own_ok = np.isfinite(q.p).all(1) & np.isfinite(q.v).all(1) & np.isfinite(q.past).all((1, 2))
    status = np.where(q.robot_type >= k, ERR_ROBOT_TYPE, np.where(own_ok, 0, ERR_STATE)).astype(np.int32)
    ok = status == 0
    valid, inside, accepted = membership(m.volumes, q.robot_type, q.nbr_type, q.nbr_rel, given & ok[:, None], k,
                                         m.max_neighbors)
    x_env = clamp(env_input(q.p, q.v, q.past), m.boxes[m.env_index])
    cnt = lambda a: np.where(ok, a.sum(1), 0).astype(np.int64)  # noqa: E731
    return Selection(status, accepted, cnt(given & ok[:, None] & ~valid), cnt(valid & ~inside),
                     cnt(inside & ~accepted), x_env)


def phi_rows(cfg, q: Queries) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every clamped input the C feeds to phi for queries of valid robots (real flights),
    ordered as a data set's rows: by query, then neighbour type (environment last), then
    array order.  Returns (query index, neighbour type, input [rows, input_dim])."""
    boxes = boxes_f32(cfg)
    _, _, acc = membership(volumes_f32(cfg), q.robot_type, q.nbr_type, q.nbr_rel, q.given(), cfg.num_robot_types,
                           cfg.model["max_neighbors"])
    ts, ss = np.nonzero(acc)
    types = q.nbr_type[ts, ss].astype(np.int64)
    sample = np.concatenate([ts, np.arange(len(q))])
    ty = np.concatenate([types, np.full(len(q), cfg.env_index)])
    x = np.concatenate([clamp(q.nbr_rel[ts, ss], boxes[types]), clamp(env_input(q.p, q.v, q.past), boxes[cfg.env_index])])
    order = np.lexsort((ty, sample))  # stable: array order within a type
    return sample[order], ty[order], x[order]


# ---------------------------------------------------------------- float32 reference
def _dense_f32(w: torch.Tensor, b: torch.Tensor, x: torch.Tensor, relu: bool) -> torch.Tensor:
    acc = b.expand(x.shape[0], -1).clone()
    for i in range(w.shape[1]):
        acc = acc + w[:, i] * x[:, i:i + 1]  # two roundings: no fused multiply-add
    return torch.where(acc > 0, acc, torch.zeros_like(acc)) if relu else acc


def _net_f32(net, x: torch.Tensor) -> torch.Tensor:
    n = len(net)
    for l, (w, b) in enumerate(net):
        x = _dense_f32(torch.from_numpy(w), torch.from_numpy(b), x, l + 1 < n)
    return x


def predict_f32(m, q: Queries) -> tuple[np.ndarray, Selection]:
    sel = select(m, q)
    nq = len(q)
    h = torch.zeros((nq, m.hidden), dtype=torch.float32)
    ok = sel.status == 0
    if ok.any():
        h[ok] = _net_f32(m.phi[m.env_index], torch.from_numpy(sel.x_env[ok]))
    if sel.accepted.any():
        phi_out = torch.zeros((nq, q.slots, m.hidden), dtype=torch.float32)
        for t in range(m.num_robot_types):
            mask = sel.accepted & (q.nbr_type == t)
            if mask.any():
                x = clamp(q.nbr_rel[mask], m.boxes[t])
                phi_out[torch.from_numpy(mask)] = _net_f32(m.phi[t], torch.from_numpy(x))
        acc_mask = torch.from_numpy(sel.accepted)
        for s in range(q.slots):  # array order, like the C
            if acc_mask[:, s].any():
                h = torch.where(acc_mask[:, s, None], h + phi_out[:, s], h)
    out = torch.zeros(nq, dtype=torch.float32)
    for r in range(m.num_robot_types):
        rows = torch.from_numpy(ok & (q.robot_type == r))
        if rows.any():
            out[rows] = _net_f32(m.rho[r], h[rows])[:, 0]
    return out.numpy(), sel


# ---------------------------------------------------------------- integer reference
def floor_shift(a: np.ndarray, s: int) -> np.ndarray:
    return a >> s  # numpy's >> on int64 is an arithmetic (floor) shift


def round_shift_sat(a: np.ndarray, s: int) -> np.ndarray:
    """sat16(floor((a + 2^(s-1)) / 2^s)) of int64 values, the C's rounding shift (round
    half up); the quantizer's overflow proof uses it on its bounds too."""
    if s > 0:
        a = a + (1 << (s - 1))
        _check_int32(a, "rounding")
        a = floor_shift(a, s)
    return np.clip(a, -32768, 32767)


def _check_int32(a: np.ndarray, what: str) -> None:
    if a.size and (a.max() > INT32_MAX or a.min() < -INT32_MAX - 1):
        raise OverflowError(f"int32 overflow in {what}: the exporter's proof is wrong")


def quantize_input(x: np.ndarray, scale: float) -> np.ndarray:
    """sat16(floor(x * scale + 0.5)) with x * scale in float32 like the C (which
    gets the same floor by rounding to nearest, |x * scale| < 2^16)."""
    v = x.astype(np.float32) * np.float32(scale)
    fl = np.floor(v)
    qv = fl.astype(np.int64) + ((v - fl) >= np.float32(0.5))
    return np.clip(qv, -32768, 32767)


def dense_q15(layer, x: np.ndarray, relu: bool) -> np.ndarray:
    w = layer.w.astype(np.int64)
    xp = np.zeros((x.shape[0], w.shape[1]), np.int64)
    xp[:, :x.shape[1]] = x
    # the sequential C sum: every partial sum bounded by |b| + sum |w_i x_i|
    _check_int32(np.abs(layer.b.astype(np.int64))[None, :] + np.abs(xp) @ np.abs(w).T, "dense partial sums")
    acc = layer.b.astype(np.int64)[None, :] + xp @ w.T
    y = round_shift_sat(acc, layer.shift)
    return np.maximum(y, 0) if relu else y


def net_q15(net, x: np.ndarray) -> np.ndarray:
    n = len(net.layers)
    for l, layer in enumerate(net.layers):
        x = dense_q15(layer, x, l + 1 < n)
    return x


def predict_q15(m, q: Queries) -> tuple[np.ndarray, Selection]:
    """Raw int16 outputs (grams * 2^out_frac) of the fixed-point C."""
    qm = m.q15
    sel = select(m, q)
    nq = len(q)
    ok = sel.status == 0
    h = np.zeros((nq, m.hidden), np.int64)
    h[ok] = net_q15(qm.phi[m.env_index], quantize_input(sel.x_env[ok], qm.in_scale[m.env_index]))
    for t in range(m.num_robot_types):
        mask = sel.accepted & (q.nbr_type == t)
        if mask.any():
            x = quantize_input(clamp(q.nbr_rel[mask], m.boxes[t]), qm.in_scale[t])
            np.add.at(h, np.nonzero(mask)[0], net_q15(qm.phi[t], x))  # integer sums: any order
    _check_int32(h, "latent sum")
    hq = round_shift_sat(h, qm.sum_shift)
    out = np.zeros(nq, np.int64)
    for r in range(m.num_robot_types):
        rows = ok & (q.robot_type == r)
        if rows.any():
            out[rows] = net_q15(qm.rho[r], hq[rows])[:, 0]
    return out.astype(np.int16), sel
