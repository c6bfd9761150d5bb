"""The paper's ablations on simulated flights (JSON on stdout), each trained with
--seeds seeds (the paper: 3) to convergence by one stopping rule: at most
--max-epochs epochs, stop when the validation MSE has not improved by --min-delta
(relative) for --patience epochs, keep the best epoch (ns2codegen.train); with
--lr-drops k the first k such plateaus halve the learning rate instead.
Validation MSE (g^2), mean +- std over the seeds, with the epochs and wall time:

  H   H in {10, 20, 40} at L = 4 (Table ablation, top)
  L   L in {3, 4, 5} at H = 20 (Table ablation, bottom)
  W   intermediate widths 40/25 (paper) against the on-board 24/16
  V   without relative velocity: x_ij = [p_j - p_i; 0] (paper: 6.42 -> 7.60, +18 %)
  P   a sum of pairwise models, sum_j rho(phi(x_ij)), instead of the deep set
  T   a deep set that ignores robot types (one phi for all robots, one rho)

on the data sets given (make ablation: the paper-sized set of make paper-data).
With --test-data every trained model is also scored on flights of larger teams
than any in training (make ablation: teams of 4 and 5 robots, 3-4 neighbours plus
the ground): the generalization the paper's deep set is for (Fig. vis (g)).

    python benchmarks/ablation.py --data A.npz [--data B.npz] [--axes H,L,V,P,T] [--seeds 3]
        [--max-epochs 60] [--patience 3] [--min-delta 0.01] [--lr-drops 0] [--device cpu]
        [--test-data C.npz] [--workers 1]
"""
from __future__ import annotations

import argparse
import glob
import json
import sys
import time
from pathlib import Path

import numpy as np

from ns2codegen.checkpoint import save_checkpoint
from ns2codegen.config import ONBOARD_WIDTHS, Config
from ns2codegen.data.dataset import Dataset
from ns2codegen.parallel import forked_map
from ns2codegen.train import evaluate, train

PAPER = {"hidden": 20, "layers": 4}
# (axis, value, model overrides, variant, drop relative velocity); H = 20 at L = 4 is
# also L = 4, W = 40/25 and the full model of V, P, T
RUNS = [("H", h, {"hidden": h, "layers": 4}, "hetero", False) for h in (10, 20, 40)] + \
       [("L", n, {"hidden": 20, "layers": n}, "hetero", False) for n in (3, 5)] + \
       [("W", "24/16", dict(PAPER, **ONBOARD_WIDTHS), "hetero", False),
        ("V", "without", PAPER, "hetero", True),
        ("P", "pairwise sum", PAPER, "pairwise", False),
        ("T", "type-agnostic", PAPER, "agnostic", False)]
SAME_AS_PAPER = (("L", "4"), ("W", "40/25"), ("V", "with"), ("P", "deep set"), ("T", "heterogeneous"))


def runs(axes: str) -> list:
    """The runs of the axes named (a comma list of H, L, W, V, P, T; "paper": the paper's network alone);
    the paper's network once, first."""
    order = axes.split(",")
    sel = sorted((r for r in RUNS if r[0] in order), key=lambda r: order.index(r[0]))
    paper = ("H", 20, PAPER, "hetero", False)     # the reference runs first
    if set(order) - {"H"} or paper in sel:
        sel = [paper] + [r for r in sel if r != paper]
    return sel


def table(results: dict, axes: str) -> dict:
    """results[(axis, value)] -> {axis: {value: result}} with the paper's network under each axis."""
    out = {a: {} for a in axes.split(",")}
    for (axis, value), r in results.items():
        out.setdefault(axis, {})[str(value)] = r
    for axis, value in SAME_AS_PAPER:
        if axis in out and "20" in out.get("H", {}):
            out[axis][value] = out["H"]["20"]
    return out


# the data (by whether the relative velocity is dropped) and options of this run, set before
# the workers fork (they inherit it, nothing is pickled)
_DATA: dict = {}


def train_one(run: tuple, seed: int) -> tuple:
    """One training of the ablation: (validation MSE, epochs, wall s, test MSE or None)."""
    cfg, args = _DATA["cfg"], _DATA["args"]
    axis, value, over, variant, drop_v = run
    data, test_run = _DATA["data"][drop_v], _DATA["test"][drop_v]
    t0 = time.perf_counter()
    model, rep = train(cfg.with_overrides(**over), data, epochs=args.max_epochs, seed=seed,
                       batch_size=args.batch_size, lr=args.lr,
                       device=args.device, variant=variant, patience=args.patience,
                       min_delta=args.min_delta, lr_drops=args.lr_drops)
    wall = time.perf_counter() - t0
    tested = evaluate(model, test_run)["mse"] if test_run is not None else None  # the model is on the CPU
    if args.save_dir and variant == "hetero":
        save_checkpoint(Path(args.save_dir) / f"{axis}-{value}-seed{seed}.pt".replace("/", "_"), model,
                        cfg.with_overrides(**over), {"seed": seed, "data_hash": data.content_hash(),
                                                     "report": rep, "relative_velocity": not drop_v})
    print(f"  {axis}={value} seed {seed}: {rep['validation']['mse']:.3f} g^2 after {rep['epochs']} epochs "
          f"({wall:.0f} s)" + (f", {args.test_label} {tested:.3f} g^2" if tested is not None else ""),
          file=sys.stderr, flush=True)
    return rep["validation"]["mse"], rep["epochs"], wall, tested


def without_velocity(ds: Dataset) -> Dataset:
    """The data set with the relative velocities (and the environment's -v_i) zeroed."""
    state = ds.nbr_state.copy()
    state[:, 3:] = 0.0
    return Dataset(**{**ds.__dict__, "nbr_state": state})


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", action="append", default=None)
    ap.add_argument("--axes", default="H,L,V,P,T", help="comma list of H, L, W, V, P, T")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--max-epochs", type=int, default=60)
    ap.add_argument("--patience", type=int, default=3)
    ap.add_argument("--min-delta", type=float, default=0.01)
    ap.add_argument("--lr-drops", type=int, default=0,
                    help="halve the learning rate this many times at a plateau before stopping")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--test-data", action="append", default=[],
                    help="also score every model on this set (larger teams than in training)")
    ap.add_argument("--test-label", default="larger_teams", help="the key of the --test-data scores in the JSON")
    ap.add_argument("--config", default=None, help="config of the models (default: the package's default.toml)")
    ap.add_argument("--save-dir", default=None, help="save every trained model there (<axis>-<value>-seed<k>.pt)")
    ap.add_argument("--no-reference", action="store_true",
                    help="skip the paper's network (H = 20, L = 4: trained and reported by another run)")
    ap.add_argument("--batch-size", type=int, default=None, help="[default: the config's train.batch_size]")
    ap.add_argument("--lr", type=float, default=None, help="[default: the config's train.lr]")
    ap.add_argument("--workers", type=int, default=1,
                    help="trainings at once, in forked processes (the same results; one torch thread each "
                         "with OMP_NUM_THREADS=1)")
    args = ap.parse_args()
    if args.workers > 1 and args.device != "cpu":
        raise SystemExit(f"--workers {args.workers}: trainings side by side only on the CPU (--device {args.device})")
    paths = args.data or sorted(glob.glob("build/sim/round*.npz"))
    if not paths:
        raise SystemExit("no data: run `make paper-data` or pass --data")
    ds = Dataset.concat([Dataset.load(p) for p in paths])
    test = Dataset.concat([Dataset.load(p) for p in args.test_data]) if args.test_data else None
    cfg = Config.load(args.config)
    if args.save_dir:
        Path(args.save_dir).mkdir(parents=True, exist_ok=True)
    results, t_all = {}, time.perf_counter()
    selected = runs(args.axes)
    if args.no_reference:
        selected = [r for r in selected if r[:2] != ("H", 20)]
    jobs = [(run, seed) for run in selected for seed in range(args.seeds)]
    drops = {run[4] for run in selected}    # the sets with the relative velocities zeroed, once
    _DATA.update(cfg=cfg, args=args, data={d: without_velocity(ds) if d else ds for d in drops},
                 test={d: without_velocity(test) if d and test is not None else test for d in drops})
    done = forked_map(train_one, jobs, args.workers)   # each training seeded: the same results
    for k, run in enumerate(selected):
        axis, value = run[:2]
        mine = done[k * args.seeds:(k + 1) * args.seeds]
        mses, epochs, wall, tests = ([j[i] for j in mine] for i in range(4))
        results[(axis, value)] = {"mean": float(np.mean(mses)), "std": float(np.std(mses)), "runs": mses,
                                  "epochs": epochs, "wall_s": [round(w, 1) for w in wall]}
        if test is not None:
            results[(axis, value)][args.test_label] = {"mean": float(np.mean(tests)), "std": float(np.std(tests)),
                                                      "runs": tests}
    out = {"data": paths, "samples": len(ds), "device": args.device, "seeds": args.seeds, "workers": args.workers,
           "stopping_rule": {"max_epochs": args.max_epochs, "patience": args.patience, "min_delta": args.min_delta,
                             "lr_drops": args.lr_drops},
           "label_variance_g2": float(np.var(ds.label_g)),
           "test_data": args.test_data, "test_samples": len(test) if test is not None else 0,
           "wall_s": round(time.perf_counter() - t_all, 1),
           **table(results, args.axes)}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
