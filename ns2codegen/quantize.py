"""Export model: float32 tables plus fixed-point formats with an overflow proof.

Fixed-point scheme (implemented by firmware/src/ns2_q15.c, modelled by
reference.predict_q15): int16 weights w = round(W 2^f_w), int16 activations with
f fractional bits, int32 bias b = round(B 2^(f_in + f_w)) and accumulator,
output y = sat16(round_half_up(acc / 2^shift)), f_out = f_in + f_w - shift.

Format choice, per layer:
  * f_in of each phi net from the declared input box (exact fit in int16; with
    ``model.history_ms`` the past states have the same box, so phi's first layer
    has 6 (1 + lags) inputs in the proof, each bounded by its component's box);
  * f_out from the float activations of calibration queries spread over the
    whole input box with 0..max neighbours, with a headroom factor (larger
    values saturate, which the C handles);
  * f_w as large as possible such that the proof below holds.
Overflow proof (integer interval arithmetic, exact): each layer's int16 input
is known to lie in [lo_i, hi_i] (from the box for the first layer, from the
previous layer's interval otherwise, never wider than int16), so every partial
sum of the C's sequential dot product is bounded by
  |b_o| + sum_i |w_oi| max(|lo_i|, |hi_i|)  (+ 2^(shift-1) for the rounding),
and the exporter requires that bound <= 2^31 - 1 for every output o.  The latent
sum of up to 1 + NS2_MAX_NEIGHBORS phi outputs is bounded the same way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from .checkpoint import Checkpoint
from .config import Config
from .model import lipschitz_bound
from .queries import Queries, random_queries
from .reference import round_shift_sat
from .errors import Ns2Error

INT32_MAX = 2**31 - 1
HEADROOM = 2.0
CALIBRATION_QUERIES = 20000


class QuantizationError(Ns2Error, ValueError):
    """No fixed-point format satisfies the overflow proof."""


@dataclass
class QLayer:
    w: np.ndarray          # int16 [out, in_pad], inputs zero-padded to a multiple of four
    b: np.ndarray          # int32 [out]
    n_in: int
    shift: int
    f_in: int
    f_w: int
    f_out: int
    out_lo: np.ndarray     # int interval of the layer's int16 output (after ReLU)
    out_hi: np.ndarray
    proof: dict


@dataclass
class QNet:
    layers: list[QLayer]


@dataclass
class Q15Model:
    phi: list[QNet]
    rho: list[QNet]
    in_frac: list[int]
    phi_out_frac: int
    sum_shift: int
    rho_in_frac: int
    out_frac: int
    proof: list[dict] = field(default_factory=list)

    @property
    def in_scale(self) -> list[float]:
        return [2.0 ** f for f in self.in_frac]


@dataclass
class ExportModel:
    cfg: Config
    phi: list[list[tuple[np.ndarray, np.ndarray]]]  # float32 (W, b) per layer, per neighbour type
    rho: list[list[tuple[np.ndarray, np.ndarray]]]
    volumes: np.ndarray   # float32 [K, K, 2, 3]
    boxes: np.ndarray     # float32 [T, 6, 2]
    model_hash: str
    meta: dict
    q15: Q15Model | None = None

    @property
    def num_robot_types(self) -> int:
        return self.cfg.num_robot_types

    @property
    def env_index(self) -> int:
        return self.cfg.env_index

    @property
    def hidden(self) -> int:
        return self.cfg.model["hidden"]

    @property
    def max_neighbors(self) -> int:
        return self.cfg.model["max_neighbors"]

    def phi_box(self, t: int) -> np.ndarray:
        """[input_dim, 2] box of phi[t]'s input: the type's 6-box for now and again for
        each ``model.history_ms`` lag (the C clamps past states to the same box)."""
        return np.tile(self.boxes[t], (self.cfg.input_dim // 6, 1))

    def lipschitz(self) -> dict:
        phi = [lipschitz_bound([w for w, _ in net]) for net in self.phi]
        rho = [lipschitz_bound([w for w, _ in net]) for net in self.rho]
        return {"gamma": float(self.cfg.model["gamma"]), "phi": phi, "rho": rho,
                "per_neighbor_input": max(rho) * max(phi),
                "note": "|f(x) - f(x')| <= max(rho) * max(phi) * sum_j ||x_j - x'_j||_2 over the "
                        "environment and each neighbour input; product of exact spectral norms "
                        "of the exported float32 weights, rounded up"}


FLOAT_LIMIT = 1e30  # far below FLT_MAX: sums of up to 1 + max_neighbors phi outputs stay finite


def float_activation_bound(m: ExportModel) -> float:
    """Bound on |every float activation| for inputs in the box (interval arithmetic in
    float64, all neighbours at once): the float path can never produce Inf or NaN."""
    def run(net, lo, hi):
        worst = 0.0
        for l, (w, b) in enumerate(net):
            w64, b64 = w.astype(np.float64), b.astype(np.float64)
            new_lo = b64 + np.minimum(w64 * lo, w64 * hi).sum(1)
            new_hi = b64 + np.maximum(w64 * lo, w64 * hi).sum(1)
            worst = max(worst, float(np.abs(new_lo).max()), float(np.abs(new_hi).max()))
            lo, hi = new_lo, new_hi
            if l + 1 < len(net):
                lo, hi = np.maximum(lo, 0.0), np.maximum(hi, 0.0)
        return worst, lo, hi

    worst, h_lo, h_hi = 0.0, 0.0, 0.0
    for t, net in enumerate(m.phi):
        box = m.phi_box(t).astype(np.float64)
        wt, lo, hi = run(net, box[:, 0], box[:, 1])
        count = 1 if t == m.env_index else m.max_neighbors
        worst = max(worst, wt)
        h_lo, h_hi = h_lo + count * np.minimum(lo, 0.0), h_hi + count * np.maximum(hi, 0.0)
    worst = max(worst, float(np.abs(h_lo).max()), float(np.abs(h_hi).max()))
    for net in m.rho:
        worst = max(worst, run(net, h_lo, h_hi)[0])
    return worst


def from_checkpoint(ck: Checkpoint) -> ExportModel:
    cfg = ck.cfg

    def net(kind, i):
        return [(w.numpy().astype(np.float32), b.numpy().astype(np.float32))
                for w, b in ck.net_weights(kind, i)]

    k = cfg.num_robot_types
    volumes = np.array([[cfg.volume(r, t) for t in range(k)] for r in range(k)], np.float32)
    boxes = np.array([cfg.input_box(t) for t in range(len(cfg.neighbor_types))], np.float32)
    m = ExportModel(cfg, [net("phi", t) for t in range(len(cfg.neighbor_types))],
                    [net("rho", r) for r in range(k)], volumes, boxes, ck.model_hash(), ck.meta)
    bound = float_activation_bound(m)
    if not bound < FLOAT_LIMIT:
        raise QuantizationError(f"float activations can reach {bound:.3g} for inputs in the box "
                                f"(limit {FLOAT_LIMIT:g}): the weights are not exportable")
    m.meta = dict(m.meta, float_activation_bound=bound)
    m.q15 = quantize(m)
    return m


# ------------------------------------------------------------------ calibration
def _forward_maxima(net, x: np.ndarray) -> tuple[list[float], np.ndarray]:
    """Max |output| of every layer (pre-ReLU positive part for hidden layers)."""
    maxima = []
    h = torch.from_numpy(x.astype(np.float64))
    for l, (w, b) in enumerate(net):
        h = h @ torch.from_numpy(w.astype(np.float64)).T + torch.from_numpy(b.astype(np.float64))
        last = l + 1 == len(net)
        maxima.append(float(h.abs().max() if last else h.clamp(min=0).max()) if h.numel() else 0.0)
        if not last:
            h = torch.relu(h)
    return maxima, h.numpy()


def calibrate(m: ExportModel, q: Queries) -> dict:
    from .reference import clamp, select  # late import: reference imports nothing from here

    sel = select(m, q)
    ok = sel.status == 0
    phi_max, h = [], np.zeros((len(q), m.hidden))
    env_max, h[ok] = _forward_maxima(m.phi[m.env_index], sel.x_env[ok])
    for t in range(m.num_robot_types):
        mask = sel.accepted & (q.nbr_type == t)
        x = clamp(q.nbr_rel[mask], m.boxes[t])
        mx, out = _forward_maxima(m.phi[t], x)
        np.add.at(h, np.nonzero(mask)[0], out)
        phi_max.append(mx)
    phi_max.append(env_max)
    rho_max = [_forward_maxima(m.rho[r], h[ok & (q.robot_type == r)])[0] for r in range(m.num_robot_types)]
    return {"phi": phi_max, "rho": rho_max, "h": float(np.abs(h).max())}


def _frac_for(max_abs: float, headroom: float = HEADROOM) -> int:
    if max_abs <= 0:
        return 15
    return int(min(30, max(-30, math.floor(math.log2(32767.0 / (max_abs * headroom))))))


# ------------------------------------------------------------------ quantization
def pad4(n: int) -> int:
    """n rounded up to a multiple of four: the C kernels work on blocks of four rows
    and quads of inputs (zero-padded)."""
    return (n + 3) // 4 * 4


def quantize_layer(w: np.ndarray, b: np.ndarray, f_in: int, f_out_wanted: int,
                   in_lo: np.ndarray, in_hi: np.ndarray, relu: bool, name: str) -> QLayer:
    n_out, n_in = w.shape
    in_pad = pad4(n_in)
    amax = np.maximum(np.abs(in_lo), np.abs(in_hi)).astype(object)  # exact Python ints
    w64, b64 = w.astype(np.float64), b.astype(np.float64)
    wmax = float(np.abs(w64).max())
    f_w = min(30, math.floor(math.log2(32767.0 / wmax))) if wmax > 0 else 15
    while True:
        if f_w < -40:
            raise QuantizationError(f"{name}: no weight format satisfies the overflow proof")
        shift = max(0, min(30, f_in + f_w - f_out_wanted))
        f_out = f_in + f_w - shift
        wq = np.round(w64 * 2.0 ** f_w).astype(np.int64)
        bq = np.round(b64 * 2.0 ** (f_in + f_w))
        half = (1 << (shift - 1)) if shift else 0
        if np.abs(wq).max() <= 32767 and np.abs(bq).max() <= INT32_MAX:
            bq = bq.astype(np.int64)
            wo = wq.astype(object)
            bound = [abs(int(bq[o])) + int(np.abs(wo[o]) @ amax) + half for o in range(n_out)]
            if max(bound) <= INT32_MAX:
                break
        f_w -= 1
    lo_terms = np.minimum(wq * in_lo[None, :], wq * in_hi[None, :]).sum(1) + bq
    hi_terms = np.maximum(wq * in_lo[None, :], wq * in_hi[None, :]).sum(1) + bq
    out_lo = round_shift_sat(np.asarray(lo_terms, np.int64), shift)
    out_hi = round_shift_sat(np.asarray(hi_terms, np.int64), shift)
    if relu:
        out_lo, out_hi = np.maximum(out_lo, 0), np.maximum(out_hi, 0)
    wpad = np.zeros((n_out, in_pad), np.int16)
    wpad[:, :n_in] = wq
    acc = max(bound)
    proof = {"layer": name, "f_in": f_in, "f_w": f_w, "f_out": f_out, "shift": shift,
             "max_abs_input": int(max(amax)), "max_abs_inputs": [int(a) for a in amax], "max_abs_weight": int(np.abs(wq).max()),
             "max_abs_bias": int(np.abs(bq).max()), "accumulator_bound": int(acc),
             "int32_max": INT32_MAX, "margin_bits": round(math.log2(INT32_MAX / max(acc, 1)), 3)}
    return QLayer(wpad, bq.astype(np.int32), n_in, shift, f_in, f_w, f_out, out_lo, out_hi, proof)


def quantize_net(net, f_in: int, f_out_last: int, lo: np.ndarray, hi: np.ndarray,
                 maxima: list[float], name: str) -> QNet:
    layers = []
    for l, (w, b) in enumerate(net):
        last = l + 1 == len(net)
        want = f_out_last if last else _frac_for(maxima[l])
        layer = quantize_layer(w, b, f_in, want, lo, hi, not last, f"{name}.layer{l}")
        layers.append(layer)
        f_in, lo, hi = layer.f_out, layer.out_lo, layer.out_hi
    return QNet(layers)


def _input_interval(box: np.ndarray, f: int) -> tuple[np.ndarray, np.ndarray]:
    from .reference import quantize_input

    lo = quantize_input(box[:, 0], 2.0 ** f).astype(np.int64)
    hi = quantize_input(box[:, 1], 2.0 ** f).astype(np.int64)
    return lo, hi


def quantize(m: ExportModel, calibration: Queries | None = None) -> Q15Model:
    cfg = m.cfg
    if calibration is None:
        calibration = random_queries(cfg, CALIBRATION_QUERIES, seed=20211, max_given=m.max_neighbors,
                                     inside=1.0, edge=0.02)
    cal = calibrate(m, calibration)
    n_types = len(cfg.neighbor_types)
    in_frac = [min(15, math.floor(math.log2(32767.0 / float(np.abs(m.boxes[t]).max()))))
               for t in range(n_types)]
    f_phi = min(_frac_for(cal["phi"][t][-1]) for t in range(n_types))
    f_out = min(_frac_for(cal["rho"][r][-1]) if cal["rho"][r] else 15 for r in range(m.num_robot_types))
    for _ in range(8):  # the shared output formats may have to shrink; a few passes settle
        phi = [quantize_net(m.phi[t], in_frac[t], f_phi, *_input_interval(m.phi_box(t), in_frac[t]),
                            cal["phi"][t], f"phi[{cfg.neighbor_types[t]}]") for t in range(n_types)]
        got = min(net.layers[-1].f_out for net in phi)
        if got < f_phi:
            f_phi = got
            continue
        # latent sum: environment + up to max_neighbors robot neighbours
        env, rob = phi[m.env_index].layers[-1], phi[:m.env_index]
        r_lo = np.minimum.reduce([n.layers[-1].out_lo for n in rob])
        r_hi = np.maximum.reduce([n.layers[-1].out_hi for n in rob])
        h_lo = env.out_lo + m.max_neighbors * np.minimum(r_lo, 0)
        h_hi = env.out_hi + m.max_neighbors * np.maximum(r_hi, 0)
        f_rin = min(f_phi, _frac_for(cal["h"]))
        sum_shift = f_phi - f_rin
        half = (1 << (sum_shift - 1)) if sum_shift else 0
        h_bound = int(max(np.abs(h_lo).max(), np.abs(h_hi).max())) + half
        if h_bound > INT32_MAX:
            raise QuantizationError("latent sum can overflow int32")
        rin_lo = round_shift_sat(np.asarray(h_lo, np.int64), sum_shift)
        rin_hi = round_shift_sat(np.asarray(h_hi, np.int64), sum_shift)
        rho = [quantize_net(m.rho[r], f_rin, f_out, rin_lo, rin_hi, cal["rho"][r],
                            f"rho[{cfg.robot_types[r]}]") for r in range(m.num_robot_types)]
        got = min(net.layers[-1].f_out for net in rho)
        if got < f_out:
            f_out = got
            continue
        proof = [l.proof for net in phi + rho for l in net.layers]
        proof.append({"layer": "latent sum", "terms": 1 + m.max_neighbors, "shift": sum_shift,
                      "accumulator_bound": h_bound, "int32_max": INT32_MAX,
                      "margin_bits": round(math.log2(INT32_MAX / max(h_bound, 1)), 3)})
        return Q15Model(phi, rho, in_frac, f_phi, sum_shift, f_rin, f_out, proof)
    raise QuantizationError("fixed-point output formats did not settle")
