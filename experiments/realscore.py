"""Scores of f_a,z predictions on real flights where the force matters, and without a
mass convention deciding them (issue 52; docs/real-flights.md, "Blind scores").

Every score is an MSE (g^2) reported

* **overall**, **in the wake** (``WAKE``: another robot within 0.15 m horizontally and
  0.1-0.6 m higher, the swaps' passages; per receiving type too) and **per scenario**;
* **plain** and **mass-neutral**: the mass-neutral residual is the plain one minus the
  robot's own slow offset estimated causally, as a robot could on board: an exponential
  average with time constant ``OFFSET["tau_s"]`` of its past residuals (label minus
  prediction), updated only where its label is sane (|label| <= ``sane_abs_g``), and
  read ``delay_s`` late (only residuals at least that old count); it starts at 0 at
  each robot's first sample of a flight.  A constant label offset (a mass error) is
  removed by it within a few time constants; the wake's passages (a second or two)
  are not;
* under **both mass conventions**: the labels as built (each type's mass measured in
  hover) and relabelled exactly with the other convention's masses
  (label + (m_other - m) (v_dot_z + g) / g per sample, ``sample_info``'s load factor).

A model is scored on the samples given; ``common`` restricts every model of a table
to the samples where all of them predict (the on-board ``ctrlFa.Faz`` exists only
where the network flew).
"""
from __future__ import annotations

import numpy as np

from ns2codegen.data.from_logs import WAKE_DZ_M

WAKE = {"max_xy_m": 0.15, "dz_m": WAKE_DZ_M}
OFFSET = {"tau_s": 2.0, "delay_s": 0.02, "sane_abs_g": 25.0, "rate_hz": 100.0}


def causal_offset(residual: np.ndarray, robot: np.ndarray, t_s: np.ndarray, sane: np.ndarray,
                  tau_s: float = OFFSET["tau_s"], delay_s: float = OFFSET["delay_s"],
                  rate_hz: float = OFFSET["rate_hz"]) -> np.ndarray:
    """Per sample, its robot's exponential average (time constant ``tau_s``, one update
    per sane sample at ``rate_hz``) of the residuals of that robot's sane samples at
    least ``delay_s`` older; 0 before the first such sample."""
    from scipy.signal import lfilter

    out = np.zeros(len(residual))
    a = 1.0 - np.exp(-1.0 / (rate_hz * tau_s))
    for r in np.unique(robot):
        idx = np.flatnonzero(robot == r)
        idx = idx[np.argsort(t_s[idx], kind="stable")]
        ok = idx[sane[idx]]
        if not len(ok):
            continue
        ema = lfilter([a], [1.0, -(1.0 - a)], residual[ok])          # after each sane sample
        k = np.searchsorted(t_s[ok], t_s[idx] - delay_s + 1e-9, side="right")   # sane samples old enough
        out[idx] = np.where(k > 0, ema[np.maximum(k - 1, 0)], 0.0)
    return out


def _mse(e: np.ndarray, m: np.ndarray | None = None) -> float | None:
    e = e if m is None else e[m]
    return round(float(np.mean(e ** 2)), 4) if e.size else None


def score(label_g: np.ndarray, pred_g: np.ndarray, info: dict, robot_type: np.ndarray, type_names: list[str],
          scenario: np.ndarray, scenario_names: list[str]) -> dict:
    """Plain and mass-neutral MSE overall, in the wake (and per receiving type) and per
    scenario; ``info``: ``sample_info`` of the same samples."""
    e = label_g.astype(np.float64) - pred_g.astype(np.float64)
    sane = np.abs(label_g) <= OFFSET["sane_abs_g"]
    en = e - causal_offset(e, info["robot"], info["t_s"], sane)
    wake = info["above_xy_m"] <= WAKE["max_xy_m"]
    out = {"samples": int(len(e)), "plain": _mse(e), "neutral": _mse(en),
           "wake": {"samples": int(wake.sum()), "plain": _mse(e, wake), "neutral": _mse(en, wake)},
           "wake_by_type": {}, "scenario": {}}
    for k, ty in enumerate(type_names):
        m = wake & (robot_type == k)
        out["wake_by_type"][ty] = {"samples": int(m.sum()), "plain": _mse(e, m), "neutral": _mse(en, m)}
    for k, sc in enumerate(scenario_names):
        m = scenario == k
        if m.any():
            out["scenario"][sc] = {"samples": int(m.sum()), "plain": _mse(e, m), "neutral": _mse(en, m)}
    return out


def relabel(label_g: np.ndarray, info: dict, robot_type: np.ndarray, masses_from: dict, masses_to: dict,
            type_names: list[str]) -> np.ndarray:
    """The labels with each type's mass changed from ``masses_from`` to ``masses_to`` (g),
    exactly: f_a,z = m (v_dot_z + g) - (R f_u)_z is linear in m."""
    dm = np.array([masses_to[t] - masses_from[t] for t in type_names])[robot_type]
    return label_g.astype(np.float64) + dm * info["load_factor"]


def both_conventions(label_g, pred_g, info, robot_type, type_names, scenario, scenario_names,
                     masses: dict, other: dict) -> dict:
    """``score`` under the labels' own masses and relabelled with ``other``."""
    return {"labels": score(label_g, pred_g, info, robot_type, type_names, scenario, scenario_names),
            "other_masses": score(relabel(label_g, info, robot_type, masses, other, type_names), pred_g, info,
                                  robot_type, type_names, scenario, scenario_names),
            "masses_g": masses, "other_masses_g": other}


def gain(ours: dict, ref: dict) -> dict:
    """How much lower ours is than ref (1 - ours / ref) for the four headline numbers."""
    def g(a, b):
        return None if a is None or not b else round(1.0 - a / b, 4)
    return {"overall_plain": g(ours["plain"], ref["plain"]), "overall_neutral": g(ours["neutral"], ref["neutral"]),
            "wake_plain": g(ours["wake"]["plain"], ref["wake"]["plain"]),
            "wake_neutral": g(ours["wake"]["neutral"], ref["wake"]["neutral"])}
