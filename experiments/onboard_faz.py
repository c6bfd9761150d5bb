"""The on-board prediction ``ctrlFa.Faz`` of the authors' real flights, recomputed
from the logged states with a deep set (docs/real-flights.md, "The authors'
networks as a peer").

Per robot i of a flight and per log sample (its own clock ``tick``): its own logged
p_i, v_i (``stateEstimateZ``: mm, mm/s), and each other robot j of the flight at its
sample nearest in ``tick`` (the robots' clocks start together within about 15 ms);
robot neighbour input x_ij = [p_j - p_i; v_j - v_i], every other robot of the flight
counted; the environment (ground) input [-p_i; -v_i] when ``ground``.  The model's
f_a,z (grams) is compared with the logged ``ctrlFa.Faz`` where that is not exactly 0
(0 before the on-board network starts).  On board the neighbours' states came by
radio (motion-capture broadcast), not from their logs: an exact match is not expected.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from ns2codegen.logs.usdlog import read

from .real import RealDataError

NOT_LABELLED = ("100",)   # cf100: old IMU, its Faz is not used (a neighbour still)
SCENARIO = re.compile(r"^(swap|randomwalk|takeoff)_[sl]+$")


def robot_type(cf: str) -> int:
    """0 small (cf50-52), 1 large (cf100-102): the collection's readme."""
    return 0 if int(cf) < 100 else 1


def read_robot(path: str | Path) -> dict:
    ev = read(path).event("fixedFrequency")
    return {"t": ev["tick"] * 1e-6,
            "p": np.stack([ev[f"stateEstimateZ.{a}"] for a in "xyz"], 1) * 1e-3,
            "v": np.stack([ev[f"stateEstimateZ.v{a}"] for a in "xyz"], 1) * 1e-3,
            "faz": ev["ctrlFa.Faz"]}


def flights(folder: str | Path) -> dict[str, dict[str, Path]]:
    """{flight number: {robot id: file}} of one scenario folder (``cf<id>_<flight>``)."""
    out: dict[str, dict[str, Path]] = {}
    for f in sorted(Path(folder).iterdir()):
        m = re.fullmatch(r"cf(\d+)_(\d+)", f.name)
        if m:
            out.setdefault(m.group(2), {})[m.group(1)] = f
    return out


def _nearest(t_ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    k = np.clip(np.searchsorted(t, t_ref), 1, len(t) - 1)
    return np.where(np.abs(t[k - 1] - t_ref) <= np.abs(t[k] - t_ref), k - 1, k)


def predict_flight(model, files: dict[str, Path], ground: bool = True) -> dict[str, dict]:
    """{robot id: {"pred", "faz", "t"}} for every labelled robot of one flight."""
    robots = {cf: read_robot(path) for cf, path in files.items()}
    env = model.num_neighbor_types - 1
    out = {}
    for cf, r in robots.items():
        if cf in NOT_LABELLED:
            continue
        n = len(r["t"])
        rows_type, rows_state, sample_of = [np.zeros(0, int)], [np.zeros((0, 6))], [np.zeros(0, int)]
        for other, o in robots.items():
            if other == cf:
                continue
            k = _nearest(r["t"], o["t"])
            rows_state.append(np.concatenate([o["p"][k] - r["p"], o["v"][k] - r["v"]], 1))
            rows_type.append(np.full(n, robot_type(other)))
            sample_of.append(np.arange(n))
        if ground:
            rows_state.append(np.concatenate([-r["p"], -r["v"]], 1))
            rows_type.append(np.full(n, env))
            sample_of.append(np.arange(n))
        with torch.no_grad():
            pred = model(torch.full((n,), robot_type(cf), dtype=torch.int64),
                         torch.from_numpy(np.concatenate(sample_of)).long(),
                         torch.from_numpy(np.concatenate(rows_type)).long(),
                         torch.from_numpy(np.concatenate(rows_state).astype(np.float32))).numpy()
        used = r["faz"] != 0.0
        out[cf] = {"pred": pred[used], "faz": r["faz"][used], "t": r["t"][used]}
    return out


def reproduce(model, root: str | Path, scenarios=None, ground: bool = True) -> dict:
    """rms and max |prediction - Faz| (g) per scenario and robot type, and overall per type."""
    root = Path(root)
    if not root.is_dir():
        raise RealDataError(f"{root}: not a folder of the authors' flight logs")
    names = scenarios or sorted(d.name for d in root.iterdir() if d.is_dir() and SCENARIO.match(d.name))
    per, pooled = {}, {0: [], 1: []}
    for name in names:
        errs: dict[int, list] = {0: [], 1: []}
        fazs: dict[int, list] = {0: [], 1: []}
        for files in flights(root / name).values():
            for cf, r in predict_flight(model, files, ground).items():
                errs[robot_type(cf)].append(r["pred"] - r["faz"])
                fazs[robot_type(cf)].append(r["faz"])
        per[name] = {}
        for t, kind in ((0, "small"), (1, "large")):
            if errs[t]:
                e, f = np.concatenate(errs[t]), np.concatenate(fazs[t])
                per[name][kind] = _stats(e, f)
                pooled[t].append((e, f))
    overall = {kind: _stats(np.concatenate([e for e, _ in pooled[t]]), np.concatenate([f for _, f in pooled[t]]))
               for t, kind in ((0, "small"), (1, "large")) if pooled[t]}
    return {"ground": ground, "per_scenario": per, "overall": overall}


def _stats(e: np.ndarray, faz: np.ndarray) -> dict:
    """Error statistics, and the least-squares fit Faz ~ slope * prediction + offset."""
    pred = faz + e
    slope, offset = np.linalg.lstsq(np.stack([pred, np.ones_like(pred)], 1), faz, rcond=None)[0]
    return {"samples": int(e.size), "rms_g": float(np.sqrt(np.mean(e ** 2))), "max_abs_g": float(np.abs(e).max()),
            "median_abs_g": float(np.median(np.abs(e))), "mean_g": float(e.mean()),
            "faz_rms_g": float(np.sqrt(np.mean(faz ** 2))),
            "corr": float(np.corrcoef(pred, faz)[0, 1]) if pred.std() > 0 and faz.std() > 0 else float("nan"),
            "fit_slope": float(slope), "fit_offset_g": float(offset)}


def flight_queries(files: dict[str, Path]):
    """The C API's queries of one flight (ns2codegen.queries): per labelled robot and log
    sample, its own p, v and every other robot of the flight as a neighbour (the C then
    applies the interaction volume and the boxes); with the logged Faz of each query."""
    from ns2codegen.queries import Queries

    robots = {cf: read_robot(path) for cf, path in files.items()}
    parts, fazs = [], []
    for cf, r in robots.items():
        if cf in NOT_LABELLED:
            continue
        others = [o for o in robots if o != cf]
        n = len(r["t"])
        rel = np.zeros((n, max(len(others), 1), 6), np.float32)
        for s, other in enumerate(others):
            o = robots[other]
            k = _nearest(r["t"], o["t"])
            rel[:, s] = np.concatenate([o["p"][k] - r["p"], o["v"][k] - r["v"]], 1)
        types = np.array([[robot_type(o) for o in others] or [0]] * n, np.uint8)
        parts.append(Queries(np.full(n, robot_type(cf), np.uint8), r["p"].astype(np.float32),
                             r["v"].astype(np.float32), np.full(n, len(others), np.int64), types, rel))
        fazs.append(r["faz"])
    return Queries.concat(parts), np.concatenate(fazs)
