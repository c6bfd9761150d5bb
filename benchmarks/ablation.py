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
        [--test-data C.npz] [--workers 1] [--scheduler ADDRESS] [--runs DIR]

Each training is kept in --runs (default build/runs/ablation; make ablation: the
committed docs/results/runs/ablation) as it finishes: the same command again trains
only those missing (ns2exp.ablation, ns2codegen.results).  --workers trainings at once
in forked processes, or on the Dask cluster of --scheduler / NS2_SCHEDULER (docs/experiments.md).
"""
from __future__ import annotations

import argparse
import glob
import json
import time
from pathlib import Path

import numpy as np

from ns2codegen.results import stamp
from ns2exp.ablation import TRAIN_OPTIONS, runs, table, train_all


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
    ap.add_argument("--scheduler", default=None,
                    help="a Dask scheduler's address (or local-cluster) to train on its workers "
                         "[default: NS2_SCHEDULER, else this machine's processes]")
    ap.add_argument("--runs", default="build/runs/ablation",
                    help="keep every finished training here and reuse those kept ('' : keep none)")
    args = ap.parse_args()
    if args.workers > 1 and args.device != "cpu":
        raise SystemExit(f"--workers {args.workers}: trainings side by side only on the CPU (--device {args.device})")
    paths = args.data or sorted(glob.glob("build/sim/round*.npz"))
    if not paths:
        raise SystemExit("no data: run `make paper-data` or pass --data")
    if args.save_dir:
        Path(args.save_dir).mkdir(parents=True, exist_ok=True)
    results, t_all = {}, time.perf_counter()
    selected = runs(args.axes)
    if args.no_reference:
        selected = [r for r in selected if r[:2] != ("H", 20)]
    spec = {"data": paths, "test_data": args.test_data, "config": args.config, "save_dir": args.save_dir,
            "test_label": args.test_label, "train": {k: getattr(args, k) for k in TRAIN_OPTIONS}}
    done, sizes = train_all(spec, selected, args.seeds, args.workers, args.scheduler, args.runs or None)
    for k, run in enumerate(selected):
        axis, value = run[:2]
        mine = done[k * args.seeds:(k + 1) * args.seeds]
        mses, epochs, wall, tests = ([j[key] for j in mine] for key in ("mse", "epochs", "wall_s", "test_mse"))
        results[(axis, value)] = {"mean": float(np.mean(mses)), "std": float(np.std(mses)), "runs": mses,
                                  "epochs": epochs, "wall_s": [round(w, 1) for w in wall]}
        if args.test_data:
            results[(axis, value)][args.test_label] = {"mean": float(np.mean(tests)), "std": float(np.std(tests)),
                                                      "runs": tests}
    out = {"data": paths, "samples": sizes["samples"], "device": args.device, "seeds": args.seeds, "workers": args.workers,
           "stopping_rule": {"max_epochs": args.max_epochs, "patience": args.patience, "min_delta": args.min_delta,
                             "lr_drops": args.lr_drops},
           "label_variance_g2": sizes["label_var"],
           "test_data": args.test_data, "test_samples": sizes["test_samples"],
           "wall_s": round(time.perf_counter() - t_all, 1),
           **table(results, args.axes)}
    print(json.dumps(stamp(out), indent=2))


if __name__ == "__main__":
    main()
