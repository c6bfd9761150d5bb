"""Float32 references of the on-board label and adaptation (issue 53): the very
operations of firmware/src/ns2_label.c and ns2_adapt.c in the same order, in
numpy float32 scalars, so that the C equals them bit for bit (tests/test_adapt.py).

``label_f32`` is the causal form of ``ns2codegen.data.labels.residual_force``'s
z component: at sample k it gives the label of sample k - 2 (the five-point
stencil two samples late).  ``adapt_f32`` is the recursive least squares with
forgetting of ns2_adapt.h on psi = [1, NN], with the composite law's tracking term
when ``track_gain`` > 0.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from .vehicle import G

F = np.float32
LABEL_DELAY, STENCIL = 2, 5
# status bits (ns2_label.h, ns2_adapt.h)
LABEL_OK, LABEL_BAD_INPUT, LABEL_WARMUP, LABEL_GROUND, LABEL_TILTED, LABEL_SATURATED, LABEL_BAD_CONFIG = \
    0, 1, 2, 4, 8, 16, 32
(ADAPT_UPDATED, ADAPT_OFF, ADAPT_BAD_PARAM, ADAPT_BAD_INPUT, ADAPT_LABEL, ADAPT_LABEL_BOUND, ADAPT_WAKE,
 ADAPT_RESET, ADAPT_CLAMPED, ADAPT_BAD_TRACK) = (1 << i for i in range(10))
FORGET_MIN, P_MIN, LIMIT_MAX, MEM_MAX = F(0.5), F(1e-6), F(1e3), F(1e30)
TRACK_GAIN_MAX, TRACK_SH_MAX = F(1e6), F(1.0)       # NS2_ADAPT_TRACK_GAIN_MAX, NS2_ADAPT_TRACK_SH_MAX
V_MAX, P_MAX, BAT_MAX = F(1e2), F(1e3), F(10.0)     # NS2_CTRL_V_MAX_MS, _P_MAX_M, _BAT_MAX_V


@dataclass
class LabelCfg:
    mass_kg: float
    lam: float            # motor delay constant, 1/s (C: lambda)
    psi1: tuple           # 5 coefficients, grams from (PWM, V / 4.2)
    h_s: float = 0.01
    min_z_m: float = 0.1
    min_r33: float = 0.866  # cos 30 deg

    @classmethod
    def of_vehicle(cls, veh: dict, **kw) -> "LabelCfg":
        """From a config's vehicle dict (``Config.vehicle``: mass_g, lambda, psi1)."""
        return cls(veh["mass_g"] / 1000.0, veh["lambda"], tuple(veh["psi1"]), **kw)


@dataclass
class AdaptCfg:
    enable: int = 1
    gate_neighbours: int = 0    # 1: the caller's wake flag also stops updates (ns2_adapt.h)
    forget: float = 0.995
    p0: float = 1.0
    p_max: float = 10.0
    bias_max_g: float = 10.0
    scale_max: float = 0.0
    fa_max_g: float = 10.0
    label_max_g: float = 40.0
    wake_g: float = 15.0
    track_gain: float = 0.0     # the composite law's tracking gain, g/(m/s)/s at P = 1; 0: RLS alone (ns2_adapt.h)

    def as_dict(self) -> dict:
        return asdict(self)


ADAPT_FIELDS = [f.name for f in fields(AdaptCfg)]
ADAPT_U8_FIELDS = ("enable", "gate_neighbours")    # uint8_t in ns2_adapt_cfg_t, the others float


def u8(x) -> int:
    """A value stored into a uint8_t field (C keeps the low byte of the integer)."""
    return int(x) & 0xFF


def _in(x, lo, hi) -> bool:
    return bool(lo <= x <= hi)      # False for NaN


def exp_neg_f32(x) -> np.float32:
    """ns2_label_exp_neg: exp(-x) by halving into (0.25, 0.5], Taylor to degree 8, squaring."""
    x = F(x)
    if not x > 0:
        return F(1.0)
    if not x <= F(1e4):
        return F(0.0)
    s = 0
    while x > F(0.5):
        x = x * F(0.5)
        s += 1
    y = F(1.0) - x / F(8.0)
    for d in (7.0, 6.0, 5.0, 4.0, 3.0, 2.0):
        y = F(1.0) - x / F(d) * y
    y = F(1.0) - x * y
    for _ in range(s):
        y = y * y
    return y


def label_cfg_ok(c: LabelCfg) -> bool:
    return (_in(F(c.mass_kg), F(1e-6), F(100.0)) and _in(F(c.lam), 0, F(1e4)) and _in(F(c.h_s), F(1e-4), F(1.0))
            and _in(F(c.min_z_m), F(-1e3), F(1e3)) and _in(F(c.min_r33), F(-2.0), F(2.0))
            and all(_in(F(k), F(-1e6), F(1e6)) for k in c.psi1))


def _motor_force_N(k, p, v):
    if not p > 0:
        return F(0.0)
    f = k[0] + k[1] * p + k[2] * v + k[3] * p * p + k[4] * p * v
    f = f if f > 0 else F(0.0)
    return f * F(G) / F(1000.0)


def _input_ok(vz, z, q, pwm, bat) -> bool:
    n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
    return (_in(vz, -V_MAX, V_MAX) and _in(z, -P_MAX, P_MAX) and _in(n2, F(0.25), F(4.0)) and _in(bat, 0, BAT_MAX)
            and all(_in(p, 0, F(1.0)) for p in pwm))


def label_f32(cfg: LabelCfg, vz, z, q, pwm, battery_V) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ns2_label_step over a sequence: (label_N [T], label_g [T], status [T]); entry k
    is the label of sample k - 2 (0 with a nonzero status bit BAD_INPUT/WARMUP/BAD_CONFIG
    where there is none)."""
    vz, z, bat = (np.asarray(a, F) for a in (vz, z, battery_V))
    q, pwm = np.asarray(q, F), np.asarray(pwm, F)
    n = len(vz)
    out_N, out_g, status = np.zeros(n, F), np.zeros(n, F), np.zeros(n, np.uint32)
    if not label_cfg_ok(cfg):
        status[:] = LABEL_BAD_CONFIG
        return out_N, out_g, status
    k = [F(x) for x in cfg.psi1]
    m, h, a = F(cfg.mass_kg), F(cfg.h_s), exp_neg_f32(F(cfg.lam) * F(cfg.h_s))
    g = F(G)
    hist, u, uc_prev, sat, good = [], [F(0)] * 4, [F(0)] * 4, 0, 0
    for t in range(n):
        if not _input_ok(vz[t], z[t], q[t], pwm[t], bat[t]):
            hist, sat, good = [], 0, 0
            status[t] = LABEL_BAD_INPUT
            continue
        v = bat[t] / F(4.2)
        uc = [_motor_force_N(k, pwm[t, i], v) for i in range(4)]
        s = int(any(p <= 0 or p >= 1 for p in pwm[t]))
        u = [a * u[i] + (F(1.0) - a) * uc_prev[i] if good else uc[i] for i in range(4)]
        uc_prev = uc
        T = u[0] + u[1] + u[2] + u[3]
        r33 = F(1.0) - F(2.0) * (q[t, 1] * q[t, 1] + q[t, 2] * q[t, 2])
        hist = (hist + [(vz[t], r33 * T, z[t], r33)])[-STENCIL:]
        sat = ((sat << 1) | s) & 0x1F
        good = min(good + 1, STENCIL)
        if good < STENCIL:
            status[t] = LABEL_WARMUP
            continue
        x = [e[0] for e in hist]
        vdot = (-x[4] + F(8.0) * x[3] - F(8.0) * x[1] + x[0]) / (F(12.0) * h)
        _, ft, zl, rl = hist[STENCIL - 1 - LABEL_DELAY]
        out_N[t] = m * vdot + m * g - ft
        out_g[t] = out_N[t] * F(1000.0) / g
        status[t] = ((LABEL_GROUND if zl < F(cfg.min_z_m) else 0) | (LABEL_TILTED if rl < F(cfg.min_r33) else 0)
                     | (LABEL_SATURATED if sat else 0))
    return out_N, out_g, status


def adapt_cfg_ok(c: AdaptCfg) -> bool:
    pm = F(c.p_max)
    return (u8(c.gate_neighbours) <= 1 and _in(F(c.forget), FORGET_MIN, F(1.0)) and _in(pm, P_MIN, LIMIT_MAX) and _in(F(c.p0), P_MIN, pm)
            and all(_in(F(getattr(c, k)), 0, LIMIT_MAX) for k in ("bias_max_g", "scale_max", "fa_max_g",
                                                                   "label_max_g", "wake_g"))
            and _in(F(c.track_gain), 0, TRACK_GAIN_MAX))


class AdaptF32:
    """ns2_adapt_t and its calls, in float32 scalars."""

    def __init__(self, cfg: AdaptCfg):
        self.reset(cfg)

    def reset(self, cfg: AdaptCfg) -> None:
        p0 = F(cfg.p0) if adapt_cfg_ok(cfg) else F(1.0)
        self.theta = [F(0.0), F(0.0)]
        self.P = [p0, F(0.0), p0]
        self.nn = [F(0.0)] * (LABEL_DELAY + 1)
        self.wake = [False] * (LABEL_DELAY + 1)
        self.n_nn, self.term, self.out, self.status, self.updates = 0, F(0.0), F(0.0), 0, 0

    @staticmethod
    def _clamp(x, lim, st):
        if x > lim:
            return lim, st | ADAPT_CLAMPED
        if x < -lim:
            return -lim, st | ADAPT_CLAMPED
        return x, st

    def _memory_ok(self) -> bool:
        return all(_in(x, -MEM_MAX, MEM_MAX) for x in self.theta + self.P)

    def _rls(self, c: AdaptCfg, n, y, s_h, st):
        P, th, lam = self.P, self.theta, F(c.forget)
        x = n if F(c.scale_max) > 0 else F(0.0)         # psi_1: the bias alone when scale_max = 0
        Pp0 = P[0] + P[1] * x
        Pp1 = P[1] + P[2] * x
        den = lam + (Pp0 + x * Pp1)
        k0, k1 = Pp0 / den, Pp1 / den
        e = y - n - (th[0] + th[1] * n)
        if F(c.track_gain) > 0 and _in(s_h, -TRACK_SH_MAX, TRACK_SH_MAX):    # the composite law's tracking term
            gs = F(c.track_gain) * s_h
            th[0], st = self._clamp(th[0] + k0 * e + gs * Pp0, F(c.bias_max_g), st)
            th[1], st = self._clamp(th[1] + k1 * e + gs * Pp1, F(c.scale_max), st)
        else:
            st |= ADAPT_BAD_TRACK if F(c.track_gain) > 0 else 0
            th[0], st = self._clamp(th[0] + k0 * e, F(c.bias_max_g), st)
            th[1], st = self._clamp(th[1] + k1 * e, F(c.scale_max), st)
        P[0] = (P[0] - k0 * Pp0) / lam
        P[1] = (P[1] - k0 * Pp1) / lam
        P[2] = (P[2] - k1 * Pp1) / lam
        P[0] = P[0] if P[0] < F(c.p_max) else F(c.p_max)
        P[2] = P[2] if P[2] < F(c.p_max) else F(c.p_max)
        P[0] = P[0] if P[0] > P_MIN else P_MIN
        P[2] = P[2] if P[2] > P_MIN else P_MIN
        if P[1] * P[1] > P[0] * P[2]:
            P[1] = F(0.0)
        self.updates += 1
        return st | ADAPT_UPDATED

    def step(self, c: AdaptCfg, nn_g, wake: bool, label_g, label_status: int, s_h=0.0) -> np.float32:
        nn_g, label_g, s_h = F(nn_g), F(label_g), F(s_h)
        if not _in(nn_g, -MEM_MAX, MEM_MAX):
            self.n_nn, self.term, self.out, self.status = 0, F(0.0), F(0.0), ADAPT_BAD_INPUT
            return self.out
        self.nn = self.nn[1:] + [nn_g]
        self.wake = self.wake[1:] + [bool(wake)]
        self.n_nn = min(self.n_nn + 1, LABEL_DELAY + 1)
        ok = adapt_cfg_ok(c)
        if not ok or not c.enable:
            self.term, self.out, self.status = F(0.0), nn_g, (ADAPT_OFF if ok else ADAPT_BAD_PARAM)
            return nn_g
        st = 0
        if not self._memory_ok():
            self.reset(c)
            self.nn[-1], self.wake[-1], self.n_nn, st = nn_g, bool(wake), 1, ADAPT_RESET
        n = self.nn[0]
        if label_status != 0 or self.n_nn <= LABEL_DELAY:
            st |= ADAPT_LABEL
        elif not _in(label_g, -F(c.label_max_g), F(c.label_max_g)):
            st |= ADAPT_LABEL_BOUND
        elif (u8(c.gate_neighbours) and self.wake[0]) or not _in(n, -F(c.wake_g), F(c.wake_g)):
            st |= ADAPT_WAKE
        else:
            st = self._rls(c, n, label_g, s_h, st)
        self.term, st = self._clamp(self.theta[0] + self.theta[1] * nn_g, F(c.fa_max_g), st)
        self.out = nn_g + self.term
        self.status = st
        return self.out


def adapt_f32(cfgs, nn_g, wake, label_g, label_status, reset=None, s_h=None) -> dict:
    """AdaptF32 over a sequence, ``cfgs`` one AdaptCfg or one per step, ``wake`` the
    caller's wake flag per step, reset before the steps where ``reset`` is true, ``s_h``
    the composite tracking error times the period per step (m; None: 0); returns arrays
    out_g, term_g, theta [T, 2], P [T, 3], status, updates after every step."""
    n = len(nn_g)
    cfgs = [cfgs] * n if isinstance(cfgs, AdaptCfg) else list(cfgs)
    a = AdaptF32(cfgs[0])
    res = {"out_g": np.zeros(n, F), "term_g": np.zeros(n, F), "theta": np.zeros((n, 2), F), "P": np.zeros((n, 3), F),
           "status": np.zeros(n, np.uint32), "updates": np.zeros(n, np.uint32)}
    for t in range(n):
        if reset is not None and reset[t]:
            a.reset(cfgs[t])
        res["out_g"][t] = a.step(cfgs[t], nn_g[t], wake[t], label_g[t], int(label_status[t]),
                                 0.0 if s_h is None else s_h[t])
        res["term_g"][t], res["status"][t], res["updates"][t] = a.term, a.status, a.updates
        res["theta"][t], res["P"][t] = a.theta, a.P
    return res
