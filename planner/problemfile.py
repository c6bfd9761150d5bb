"""Problem files (``ns2 plan --problem``): one JSON file -> a validated Problem, and
that problem planned into the Crazyflie files and plan.json (docs/inputs.md: every
bad field is one PlanningError naming the file and the field)."""
from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

from ns2codegen.config import Config
from ns2codegen.fileio import atomic_write_files

from .forces import load_force_model
from .output import write_plan
from .planner import PlanResult, plan
from .problem import Limits, PlanningError, Problem, Robot, RRTParams, SCPParams, check_margin
from .verify import check_solution, is_valid


# limits a problem file may set: kind and upper bound; the bounds keep every value
# physical (a v_max of 1e308 m/s overflows the propagation)
PROBLEM_LIMITS = {"v_max": ("positive", 100.0), "u_max": ("positive", 1000.0), "b_fa_g": ("positive", 1000.0),
                  "clearance_m": ("nonneg", 10.0), "fa_margin_g": ("nonneg_or_per_type", 1000.0), "fa_substeps": ("int", 64),
                  "pos_lo": ("point", 1000.0), "pos_hi": ("point", 1000.0), "fa_max_g": ("per_type", 1e4)}


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _point(v, where: str, lim: float = 1000.0) -> tuple:
    if not (isinstance(v, list) and len(v) == 3 and all(_is_number(x) and abs(x) <= lim for x in v)):
        raise ValueError(f"{where}: must be [x, y, z], 3 finite numbers within +-{lim:g} m, got {v!r}")
    return tuple(float(x) for x in v)


def _speed_table(v: dict, where: str, hi: float) -> dict:
    """A margin conditioned on the relative speed: {"speeds_mps": [...], "margins_g": [...]}
    as Limits.margin reads it, every value within physical bounds."""
    try:
        check_margin(where, v)
    except PlanningError as e:
        raise ValueError(str(e).removeprefix("limit parameter ")) from None
    if max(v["margins_g"]) > hi or max(v["speeds_mps"], default=0.0) > 100.0:
        raise ValueError(f"{where}: margins must be at most {hi:g} g and speeds at most 100 m/s, got {v!r}")
    return {"speeds_mps": [float(x) for x in v["speeds_mps"]], "margins_g": [float(x) for x in v["margins_g"]]}


def _limit(cfg: Config, key: str, v, where: str):
    kind, hi = PROBLEM_LIMITS[key]
    if kind == "point":
        return _point(v, where, hi)
    if kind == "int":
        if not (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= hi):
            raise ValueError(f"{where}: must be an integer in [1, {hi:g}], got {v!r}")
        return v
    if kind == "per_type" or (kind == "nonneg_or_per_type" and isinstance(v, dict)):
        positive = kind == "per_type"
        if not (isinstance(v, dict) and v):
            raise ValueError(f"{where}: must be a table {{robot type: grams}}, got {v!r}")
        out = {}
        for t, g in v.items():
            if t not in cfg.robot_types:
                raise ValueError(f"{where}.{t}: unknown robot type (the config has {cfg.robot_types})")
            if not positive and isinstance(g, dict):     # a margin's speed table (Limits.margin)
                out[t] = _speed_table(g, f"{where}.{t}", hi)
                continue
            if not (_is_number(g) and (g > 0 if positive else g >= 0) and g <= hi):
                raise ValueError(f"{where}.{t}: must be a number in {'(' if positive else '['}0, {hi:g}]"
                                 f"{'' if positive else ' or a speed table'}, got {g!r}")
            out[t] = float(g)
        return out
    ok = _is_number(v) and (v > 0 if kind == "positive" else v >= 0) and v <= hi
    if not ok:
        extra = " or a table {robot type: grams}" if kind == "nonneg_or_per_type" else ""
        raise ValueError(f"{where}: must be a number in {'(' if kind == 'positive' else '['}0, {hi:g}]{extra}, "
                         f"got {v!r}")
    return float(v)


def load_problem(cfg: Config, path) -> Problem:
    """A problem file (JSON): {"robots": [{"type", "start", "goal"}], "axes": "yz" or
    "xyz", "limits": {fields of Limits}}.  Anything else is refused with a
    PlanningError naming the file and the field."""
    try:
        raw = json.loads(Path(path).read_text(), parse_constant=lambda c: float(c))
    except FileNotFoundError as e:
        raise PlanningError(f"problem file not found: {path}") from e
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise PlanningError(f"problem file {path} is not readable JSON: {e}") from e
    try:
        if not isinstance(raw, dict):
            raise ValueError("top level: must be an object {robots, axes, limits}")
        unknown = sorted(set(raw) - {"robots", "axes", "limits"})
        if unknown:
            raise ValueError(f"{unknown[0]}: unknown field (known: robots, axes, limits)")
        if not (isinstance(raw.get("robots"), list) and raw["robots"]):
            raise ValueError("robots: must be a non-empty list of {type, start, goal}")
        robots = []
        for i, r in enumerate(raw["robots"]):
            if not (isinstance(r, dict) and set(r) == {"type", "start", "goal"}):
                raise ValueError(f"robots[{i}]: must be {{type, start, goal}}, got {r!r}")
            if not (isinstance(r["type"], str) and r["type"] in cfg.robot_types):
                raise ValueError(f"robots[{i}].type: must be one of {cfg.robot_types}, got {r['type']!r}")
            robots.append(Robot(r["type"], _point(r["start"], f"robots[{i}].start"),
                                _point(r["goal"], f"robots[{i}].goal")))
        axes = raw.get("axes", "yz")
        if axes not in ("yz", "xyz"):
            raise ValueError(f"axes: must be \"yz\" or \"xyz\", got {axes!r}")
        lim = raw.get("limits", {})
        if not isinstance(lim, dict):
            raise ValueError(f"limits: must be an object, got {lim!r}")
        for k in lim:
            if k not in PROBLEM_LIMITS:
                raise ValueError(f"limits.{k}: unknown limit (known: {sorted(PROBLEM_LIMITS)})")
        limits = replace(Limits(), **{k: _limit(cfg, k, v, f"limits.{k}") for k, v in lim.items()})
    except ValueError as e:
        raise PlanningError(f"problem file {path}: {e}") from None
    pb = Problem(cfg, robots, limits, {"yz": (1, 2), "xyz": (0, 1, 2)}[axes])
    try:
        pb.validate()
    except PlanningError as e:
        raise PlanningError(f"problem file {path}: {e}") from None
    return pb


def plan_problem_file(cfg: Config, path, checkpoint, out_dir, rrt: RRTParams, scp_params: SCPParams) -> dict:
    """Plan one problem file; write the Crazyflie files and plan.json (check + timings)."""
    pb = load_problem(cfg, path)
    fm = load_force_model(cfg, checkpoint)
    res: PlanResult = plan(pb, fm, rrt, scp_params)
    chk = check_solution(pb, fm, res.trajs)
    files = write_plan(out_dir, res.trajs, [r.type for r in pb.robots], pb.kappa())
    report = {"valid": is_valid(chk, tol=1e-3), "timings": res.timings(), "robots": chk["robots"], "files": files,
              "scp_merit": res.stage2.merit_history, "model": "BL (f_a = 0)" if checkpoint is None else str(checkpoint)}
    atomic_write_files(Path(out_dir), {"plan.json": json.dumps(report, indent=1) + "\n"})
    return report
