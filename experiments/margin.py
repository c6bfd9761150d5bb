"""The planner's model-error margin, measured (issue 24).

The planner keeps f_a,z-hat within f_a,max - m (``Limits.fa_margin_g``) so that a
model that reads low by up to m still keeps the flight within f_a,max.  m is chosen
per robot type from held-out simulated flights (seeds never trained on): at every
logged state the model is evaluated at the *true* state (P, V) and compared with the
simulator's true f_a,z (host/sim/aero.py), over the planning region:

* every robot inside the planning box (z in [0.3, 2.0] m), every velocity component
  within v_max, every pair at least r = (D_i + D_j) / 2 + clearance apart (the
  planner's collision distance).

The margin is the smallest m (on a 0.1 g grid) for which every held-out state in the
region with |f_model| <= f_a,max - m has |f_true| <= f_a,max: the guarantee the
margin is for, checked on every held-out state.  It is set by the states over the
limit: m > f_a,max - |f_model| at each of them (how far below the limit the model
read where the truth was over it).  The largest one-sided error |f_true| - |f_model|
over all the region's states with |f_model| <= f_a,max gives the same guarantee and is
reported beside it, but it is never smaller and is set by states far below the limit
(a 8 g error where the truth is 9 g and the model 1 g says nothing about the limit of
10 g), so it spends force budget on errors that cannot break the limit.  Beside them
the spectral-norm bound (eq. sn, ``ns2codegen.model.lipschitz_bound``): the model's
output moves by at most L ||dx|| between two logged states, which bounds the model's
part of the error between the samples; it is reported, and is not tighter for these
networks (see docs/planning.md)."""
from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ns2codegen.config import Config
from ns2codegen.fileio import atomic_write_bytes
from ns2plan.forces import ForceModel
from ns2plan.problem import GRAMS_TO_N, Limits, speed_bin

# held-out flights per pair of types (kind, seconds); seed HELD_OUT_SEED, never a training seed
HELD_OUT = (("who", 120.0), ("near", 120.0))
HELD_OUT_SEED = 7
# and per team of three (a pair, the third robot hovering nearby: collect.bystander_teams)
HELD_OUT_BYSTANDER = (("who", 120.0),)
# m/s: the bins of the relative speed the margin is conditioned on (ForceModel.rel_speed_np;
# the last bin is every speed above the last edge); chosen before any run, in quarter steps
# up to the planner's v_max and one bin to 1.5 m/s, where the held-out passes thin out
SPEED_EDGES_MPS = (0.25, 0.5, 0.75, 1.0, 1.5)


@dataclass
class FlownStates:
    """Truth along one flight: types [N], P, V [T, N, 3] (m, m/s), F [T, N] (g, f_a,z),
    the flight's kind (collect.flight_log)."""
    types: list
    P: np.ndarray
    V: np.ndarray
    F: np.ndarray
    kind: str


def held_out_flights(cfg: Config, gen_dir, flights=HELD_OUT, seed: int = HELD_OUT_SEED, gap_max: float = 1.5,
                     pairs=None, progress=None, cache=None, trios=None, trio_flights=HELD_OUT_BYSTANDER,
                     workers: int = 1) -> list[FlownStates]:
    """Fly every pair of types (or ``pairs``) in each (kind, seconds) of ``flights``, and
    every team of three of collect.bystander_teams (or ``trios``) in each of
    ``trio_flights``; ``workers`` flights at once (the same flights); with ``cache`` (an
    .npz path) the flights are kept there and read back when it holds these flights."""
    from ns2host.sim.collect import bystander_teams, flight_log, fly_many, teams

    pairs = pairs or [t for t in teams(cfg, 2) if len(t) == 2]
    trios = bystander_teams(cfg) if trios is None else trios
    key = json.dumps([cfg.to_json(), list(map(list, flights)), seed, gap_max, [list(t) for t in pairs],
                      [list(t) for t in trios], list(map(list, trio_flights))])
    if cache is not None and Path(cache).is_file():
        found, stored = load_flights(cache)
        if stored == key:
            return found
    jobs = [(team, kind, seconds, seed * 1000 + 10 * k + j)
            for k, (team, fl) in enumerate([(t, flights) for t in pairs] + [(t, trio_flights) for t in trios])
            for j, (kind, seconds) in enumerate(fl)]
    logs = fly_many(flight_log, [(cfg, team, gen_dir, kind, seconds, s, None, gap_max) for team, kind, seconds, s
                                 in jobs], gen_dir, workers, progress)
    out = [FlownStates(list(team), log["truth_p"], log["truth_v"], log["truth_fa"][..., 2] / GRAMS_TO_N, kind)
           for (team, kind, _, _), log in zip(jobs, logs)]
    if cache is not None:
        save_flights(cache, out, key)
    return out


def save_flights(path, flights: list, key: str = "") -> None:
    """Flights as load_flights reads them (.npz), written atomically."""
    buf = io.BytesIO()
    arrays = {f"{k}{i}": getattr(fl, k) for i, fl in enumerate(flights) for k in ("P", "V", "F")}
    np.savez_compressed(buf, key=np.array(key), meta=np.array(json.dumps([{"types": fl.types, "kind": fl.kind}
                                                                          for fl in flights])), **arrays)
    atomic_write_bytes(Path(path), buf.getvalue())


def load_flights(path) -> tuple[list[FlownStates], str]:
    """The flights of a held_out_flights cache and the key they were flown with."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        return ([FlownStates(m["types"], z[f"P{i}"], z[f"V{i}"], z[f"F{i}"], m["kind"]) for i, m in enumerate(meta)],
                str(z["key"]))


def in_region(cfg: Config, fl: FlownStates, limits: Limits) -> np.ndarray:
    """[T, N] bool: the state is one the planner may fly (box, speed, separation)."""
    lo, hi = np.array(limits.pos_lo, float), np.array(limits.pos_hi, float)
    z_ok = (fl.P[..., 2] >= lo[2]) & (fl.P[..., 2] <= hi[2])
    v_ok = (np.abs(fl.V) <= limits.v_max).all(2)
    rad = np.array([float(cfg.vehicle(t).get("diameter_m", 0.12)) / 2 for t in fl.types])
    r = rad[:, None] + rad[None, :] + limits.clearance_m
    d = np.linalg.norm(fl.P[:, :, None] - fl.P[:, None], axis=3) + np.eye(len(fl.types)) * 1e9
    sep = (d >= r).all(2)
    row = (z_ok & v_ok & sep).all(1)
    return np.repeat(row[:, None], len(fl.types), 1)


def errors(cfg: Config, fm: ForceModel, flights: list, limits: Limits) -> dict:
    """Per robot type: the true and predicted f_a,z (g) and the robot's relative speed
    to the neighbours the model sees (m/s, ForceModel.rel_speed_np) at the held-out
    states in the planning region."""
    out = {t: {"true": [], "pred": [], "speed": []} for t in cfg.robot_types}
    for fl in flights:
        types = [cfg.robot_types.index(t) for t in fl.types]
        pred = fm.team_np(types, fl.P, fl.V)
        speed = fm.rel_speed_np(types, fl.P, fl.V)
        mask = in_region(cfg, fl, limits)
        for i, t in enumerate(fl.types):
            out[t]["true"].append(fl.F[mask[:, i], i])
            out[t]["pred"].append(pred[mask[:, i], i])
            out[t]["speed"].append(speed[mask[:, i], i])
    return {t: {k: np.concatenate(v) if v else np.zeros(0) for k, v in d.items()} for t, d in out.items()}


def error_stats(true: np.ndarray, pred: np.ndarray, fa_max: float | None = None) -> dict:
    """RMSE, the largest |error| and the largest one-sided error |true| - |pred| (the
    model reading low), optionally only where |pred| <= fa_max."""
    keep = np.ones(len(true), bool) if fa_max is None else np.abs(pred) <= fa_max
    t, p = true[keep], pred[keep]
    if not len(t):
        return {"states": 0}
    e = t - p
    return {"states": int(len(t)), "rmse_g": float(np.sqrt(np.mean(e * e))), "max_abs_g": float(np.abs(e).max()),
            "max_low_g": float((np.abs(t) - np.abs(p)).max()), "p99_low_g": float(np.percentile(np.abs(t) - np.abs(p), 99))}


def _smallest_margin(true: np.ndarray, pred: np.ndarray, lim: float, step: float) -> float:
    """The smallest multiple of ``step`` m with |true| <= lim wherever |pred| <= lim - m."""
    need = lim - np.abs(pred)[np.abs(true) > lim]   # m must exceed this at every state over the limit
    return 0.0 if not len(need) or need.max() < 0 else (math.floor(need.max() / step + 1e-9) + 1) * step


def margin_from_errors(err: dict, fa_max_g: dict, step: float = 0.1, speed_edges=None) -> dict:
    """Per robot type the margin m: the smallest multiple of ``step`` such that every
    held-out state with |f_model| <= f_a,max - m has |f_true| <= f_a,max (0 when no
    state is over the limit where the model reads under it).  With ``speed_edges``
    (m/s) a speed table (Limits.fa_margin_g): that margin over the states of each bin
    of the relative speed, and never less than a slower bin's (a bin's margin is the
    largest up to it: a sparse fast bin does not undercut the slow ones' evidence)."""
    out = {}
    for t, lim in fa_max_g.items():
        true, pred = err[t]["true"], err[t]["pred"]
        if not len(true):
            raise ValueError(f"no held-out states of robot type {t!r} in the planning region: cannot measure its margin")
        if speed_edges is None:
            out[t] = _smallest_margin(true, pred, lim, step)
            continue
        per_bin = [b["own_margin_g"] for b in speed_bins(err, {t: lim}, speed_edges, step)[t]]
        out[t] = {"speeds_mps": [float(e) for e in speed_edges],
                  "margins_g": [round(float(m), 10) for m in np.maximum.accumulate(per_bin)]}
    return out


def speed_bins(err: dict, fa_max_g: dict, speed_edges=SPEED_EDGES_MPS, step: float = 0.1) -> dict:
    """Per robot type and bin of the relative speed (ns2plan.problem.speed_bin): the
    held-out states, those over the limit and the bin's own margin (before the running
    maximum of margin_from_errors)."""
    out = {}
    for t, lim in fa_max_g.items():
        k = speed_bin(speed_edges, err[t]["speed"])
        true, pred = err[t]["true"], err[t]["pred"]
        out[t] = [{"states": int((k == b).sum()), "over_limit": int((np.abs(true[k == b]) > lim).sum()),
                   "own_margin_g": _smallest_margin(true[k == b], pred[k == b], lim, step)}
                  for b in range(len(speed_edges) + 1)]
    return out


def over_limit(err: dict, fa_max_g: dict) -> dict:
    """Per robot type: the region's held-out states, those over the limit (|f_true| >
    f_a,max: the evidence of the margin) and the largest one-sided error at states with
    |f_model| <= f_a,max rounded up to 0.1 g (the stricter rule, for comparison)."""
    out = {}
    for t, lim in fa_max_g.items():
        s = error_stats(err[t]["true"], err[t]["pred"], lim)
        out[t] = {"states": int(len(err[t]["true"])), "over_limit": int((np.abs(err[t]["true"]) > lim).sum()),
                  "largest_low_rule_g": max(0.0, math.ceil(s.get("max_low_g", 0.0) / 0.1 - 1e-9) * 0.1)}
    return out


def lipschitz(fm: ForceModel) -> dict:
    """Spectral-norm bound of the model's output per (robot type, neighbour type) on one
    neighbour's input x_ij = [p_j - p_i; v_j - v_i]: L(rho_i) L(phi_j) (g per unit of
    ||x_ij||_2; the input clamp is 1-Lipschitz)."""
    from ns2codegen.model import lipschitz_bound

    net, cfg = fm.net, fm.cfg
    out = {}
    for r, rt in enumerate(cfg.robot_types):
        for j, nt in enumerate(cfg.robot_types):
            w_rho = [m.weight.detach() for m in net.rho[r].layers]
            w_phi = [m.weight.detach() for m in net.phi[j].layers]
            out[f"{rt}|{nt}"] = lipschitz_bound(w_rho) * lipschitz_bound(w_phi)
    return out


def sample_spacing(flights: list) -> float:
    """The largest change of a neighbour input ||x_ij|| between two consecutive logged
    states of the held-out flights (m and m/s together, as the model sees them)."""
    worst = 0.0
    for fl in flights:
        rel = np.concatenate([fl.P[:, 1] - fl.P[:, 0], fl.V[:, 1] - fl.V[:, 0]], 1) if len(fl.types) == 2 else None
        if rel is not None and len(rel) > 1:
            worst = max(worst, float(np.linalg.norm(np.diff(rel, axis=0), axis=1).max()))
    return worst


def closest_gap(cfg: Config, fm: ForceModel, lower: str, upper: str, bound_g: float, z: float = 1.0,
                gaps=np.arange(0.1, 2.0, 0.005)) -> float:
    """The smallest vertical gap (m, on the grid ``gaps``) from which on ``lower`` may
    hover under a hovering ``upper`` with the model's |f_a,z-hat| within ``bound_g``
    at every larger gap of the grid (inf: nowhere)."""
    types = [cfg.robot_types.index(lower), cfg.robot_types.index(upper)]
    P = np.zeros((len(gaps), 2, 3))
    P[:, 0, 2], P[:, 1, 2] = z, z + gaps
    over = np.abs(fm.team_np(types, P, np.zeros_like(P))[:, 0]) > bound_g
    if over[-1]:
        return float("inf")
    return float(gaps[np.flatnonzero(over)[-1] + 1]) if over.any() else float(gaps[0])


def _margin(cfg: Config, fm: ForceModel, flights: list, limits: Limits) -> tuple[dict, dict, dict]:
    """(the planner's margin, the errors over all flights, per team size its margin and
    speed bins): measure's and planning_margin's common part."""
    err = errors(cfg, fm, flights, limits)
    m = margin_from_errors(err, limits.fa_max_g, speed_edges=SPEED_EDGES_MPS)
    sizes = sorted({len(fl.types) for fl in flights})
    by_size = {}
    if len(sizes) > 1:          # a team of n robots can only reach states of at most n robots: their evidence
        for n in sizes:
            e = errors(cfg, fm, [fl for fl in flights if len(fl.types) <= n], limits)
            by_size[str(n)] = {"margin_g": margin_from_errors(e, limits.fa_max_g, speed_edges=SPEED_EDGES_MPS),
                               "speed_bins": speed_bins(e, limits.fa_max_g)}
        m = {"by_team_size": {n: v["margin_g"] for n, v in by_size.items()}}
    return m, err, by_size


def planning_margin(cfg: Config, fm: ForceModel, flights: list, limits: Limits) -> dict:
    """The margin the planner takes (measure's ``margin_g``) alone, without the
    evidence tables and gaps measure adds."""
    return _margin(cfg, fm, flights, limits)[0]


def measure(cfg: Config, fm: ForceModel, flights: list, limits: Limits) -> dict:
    """The margin per robot type and its evidence (plan.json's ``margin``): error
    statistics per type and flight kind (and team size beyond a pair), the spectral-norm
    bound and what it gives over the logs' sample spacing, and the closest hovering
    gaps per type pair with this
    margin and with the largest one-sided error as margin.  The
    margin the planner takes (``margin_g``) is conditioned on the relative speed
    (SPEED_EDGES_MPS, a speed table); ``margin_constant_g`` is the one over all speeds."""
    m, err, by_size = _margin(cfg, fm, flights, limits)
    m_const = margin_from_errors(err, limits.fa_max_g)
    pair = for_team(m, 2)
    evidence = over_limit(err, limits.fa_max_g)
    stats = {}
    for kind in sorted({_group(fl) for fl in flights}):
        e = errors(cfg, fm, [fl for fl in flights if _group(fl) == kind], limits)
        stats[kind] = {t: error_stats(e[t]["true"], e[t]["pred"], limits.fa_max_g[t]) for t in cfg.robot_types}
    lip = lipschitz(fm) if fm.net is not None else {}
    h = sample_spacing(flights)
    gaps = []
    for lower in cfg.robot_types:
        for upper in cfg.robot_types:
            row = {"lower": lower, "upper": upper,
                   "gap_m": closest_gap(cfg, fm, lower, upper, limits.fa_max_g[lower] - pair[lower]["margins_g"][0]),
                   "gap_constant_m": closest_gap(cfg, fm, lower, upper, limits.fa_max_g[lower] - m_const[lower])}
            row["gap_largest_low_m"] = closest_gap(cfg, fm, lower, upper, limits.fa_max_g[lower]
                                                   - evidence[lower]["largest_low_rule_g"])
            gaps.append(row)
    return {"margin_g": m, "margin_constant_g": m_const, "speed_bins": speed_bins(err, limits.fa_max_g),
            "speed_bins_by_team_size": {n: v["speed_bins"] for n, v in by_size.items()},
            "source": "per bin of the relative speed to the neighbours the model sees, the smallest m (0.1 g grid) "
            "with |f_true| <= f_a,max at every held-out state of the bin in the planning region with |f_model| <= "
            "f_a,max - m, and at least the slower bins' m"
            + ("; per team size n, on the flights of at most n robots" if by_size else ""), "evidence": evidence,
            "errors": {t: error_stats(err[t]["true"], err[t]["pred"], limits.fa_max_g[t]) for t in cfg.robot_types},
            "errors_by_kind": stats, "lipschitz_g_per_unit": lip, "sample_spacing": h,
            "lipschitz_between_samples_g": {k: v * h / 2 for k, v in lip.items()}, "closest_gaps": gaps}


def for_team(m, n: int):
    """The margin a team of ``n`` robots plans with: ``m`` itself, or of a margin by team
    size ({"by_team_size": {"2": per type, "3": per type}}, ``measure``) the entry of the
    largest size up to n (the smallest size when there is none)."""
    if not (isinstance(m, dict) and "by_team_size" in m):
        return m
    sizes = sorted(int(k) for k in m["by_team_size"])
    fit = [k for k in sizes if k <= n]
    return m["by_team_size"][str(fit[-1] if fit else sizes[0])]


def _group(fl: FlownStates) -> str:
    """The flight's row in the error tables: its kind, and its team size beyond a pair."""
    return fl.kind if len(fl.types) <= 2 else f"{fl.kind}, {len(fl.types)} robots"


def margin_table(rep: dict) -> str:
    """Markdown: per robot type the margin and the error statistics behind it (RMSE and
    errors over the region's states with |f_model| <= f_a,max), and the closest
    hovering gaps it allows."""
    lines = ["| robot type | states | over the limit | RMSE (g) | max \\|error\\| (g) | max one-sided (model low, g) | "
             "margin over all speeds (g) |", "|---|---|---|---|---|---|---|"]
    for t, s in rep["errors"].items():
        ev = rep.get("evidence", {}).get(t, {})
        lines.append(f"| {t} | {ev.get('states', s['states'])} | {ev.get('over_limit', '-')} | {s['rmse_g']:.2f} | "
                     f"{s['max_abs_g']:.2f} | {s['max_low_g']:.2f} | {rep['margin_constant_g'][t]:.1f} |")
    edges = next(iter(for_team(rep["margin_g"], 2).values()))["speeds_mps"]
    names = [f"<= {edges[0]:g}"] + [f"{a:g}-{b:g}" for a, b in zip(edges, edges[1:])] + [f"> {edges[-1]:g}"]
    by_size = rep.get("speed_bins_by_team_size") or {}
    lines += ["", f"| {'team size, ' if by_size else ''}robot type: states / over the limit / margin (g) at relative "
              "speed (m/s) | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for n, per_type in (by_size.items() if by_size else [(None, rep["speed_bins"])]):
        m = rep["margin_g"] if n is None else rep["margin_g"]["by_team_size"][n]
        for t, bins in per_type.items():
            cells = [f"{b['states']} / {b['over_limit']} / **{x:.1f}**" for b, x in zip(bins, m[t]["margins_g"])]
            lines.append(f"| {'' if n is None else f'{n} robots (flights of at most {n}), '}{t} | "
                         + " | ".join(cells) + " |")
    lines += ["", "| lower under upper (hovering) | closest gap, margin at rest | closest gap, margin over all speeds | "
              "closest gap, margin = largest one-sided error |", "|---|---|---|---|"]
    for g in rep["closest_gaps"]:
        rest, const, big = ("-" if g.get(k) is None else "none" if math.isinf(g[k]) else f"{g[k]:.2f} m"
                            for k in ("gap_m", "gap_constant_m", "gap_largest_low_m"))
        lines.append(f"| {g['lower']} under {g['upper']} | {rest} | {const} | {big} |")
    if rep.get("rounds"):
        per_case = rep.get("calibration_plans_per_case")
        lines += ["", f"Calibration on the NN's own flown plans (seeds {rep['calibration_seeds']}"
                  + (f" in order, until {per_case} planned per case" if per_case else "") + "; "
                  f"{'converged' if rep['converged'] else 'NOT converged'}): margins in g per speed bin, "
                  + ", ".join(for_team(rep["margin_g"], 2)) + ":", "",
                  "| round | margin planned with | planned | trials over a limit in flight | flown states over the limit "
                  "within the bound | margin after |", "|---|---|---|---|---|---|"]
        for r in rep["rounds"]:
            ok = [t for t in r["trials"] if t["planned"]]
            lines.append(f"| {r['round']} | {_margins(r['margin_g'])} | {len(ok)}/{len(r['trials'])} | "
                         f"{sum(t['over_limit'] for t in ok)} | {sum(t['over_limit_in_bound_states'] for t in ok)} | "
                         f"{_margins(r['margin_after_g'])} |")
    return "\n".join(lines)


def _margins(m: dict, named: bool = False) -> str:
    """Per robot type its margin table as 'm_0/m_1/...' (g), types separated by '; '
    (``named``: 'type m_0/...', separated by ', '; by team size: 'n robots: ...' per size,
    separated by ' | ')."""
    if "by_team_size" in m:
        return " \\| ".join(f"{n} robots: {_margins(v, named)}" for n, v in m["by_team_size"].items())
    cells = [(f"{t} " if named else "") + "/".join(f"{x:.1f}" for x in tab["margins_g"]) for t, tab in m.items()]
    return (", " if named else "; ").join(cells)


def compare_table(reports: dict) -> str:
    """Markdown: the error per flight kind and robot type (RMSE / largest one-sided
    error where |f_model| <= f_a,max) for several models (name -> ``measure`` report)."""
    names = list(reports)
    first = reports[names[0]]
    lines = ["| held-out flights | robot type | states | " + " | ".join(f"{n}: RMSE / max low (g)" for n in names) + " |",
             "|---|---|---|" + "---|" * len(names)]
    for kind, per_type in first["errors_by_kind"].items():
        for t, s in per_type.items():
            cells = [f"{reports[n]['errors_by_kind'][kind][t].get('rmse_g', float('nan')):.2f} / "
                     f"{reports[n]['errors_by_kind'][kind][t].get('max_low_g', float('nan')):.2f}" for n in names]
            lines.append(f"| {kind} | {t} | {s['states']} | " + " | ".join(cells) + " |")
    lines.append("| margin over all speeds (g) | | | " + " | ".join(
        ", ".join(f"{t} {m:.1f}" for t, m in reports[n]["margin_constant_g"].items()) for n in names) + " |")
    lines.append("| margin by relative speed (g) | | | " + " | ".join(
        _margins(reports[n]["margin_g"], named=True) for n in names) + " |")
    return "\n".join(lines)
