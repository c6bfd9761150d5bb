"""Ablation of the paper's Table "ablation" on simulated flights (JSON on stdout):
validation MSE (g^2) for H in {10, 20, 40} at L = 4 and L in {3, 4, 5} at H = 20,
plus the intermediate widths W (phi 6-25-40-40-H / rho H-40-40-40-1 of the paper,
"40/25", against the one-tick on-board variant 6-16-24-24-H / H-24-24-24-1,
"24/16"; the paper: "the learning performance is not sensitive to ... the number
of weights in intermediate layers"), with --repeats seeds each, on the data sets
given (default: build/sim/round*.npz from `make sim`).

    python benchmarks/ablation.py [--data A.npz --data B.npz] [--epochs 20] [--repeats 1] [--axes H,L,W]
"""
from __future__ import annotations

import argparse
import glob
import json

import numpy as np

from ns2codegen.config import ONBOARD_WIDTHS, Config
from ns2codegen.data.dataset import Dataset
from ns2codegen.train import train

PAPER = {"hidden": 20, "layers": 4}
# (axis, value, model overrides); H = 20 at L = 4 is also L = 4 and W = 40/25
RUNS = [("H", h, {"hidden": h, "layers": 4}) for h in (10, 20, 40)] + \
       [("L", n, {"hidden": 20, "layers": n}) for n in (3, 5)] + \
       [("W", "24/16", dict(PAPER, **ONBOARD_WIDTHS))]
SAME_AS_PAPER = (("L", "4"), ("W", "40/25"))


def runs(axes: str) -> list:
    """The runs of the axes named (a comma list of H, L, W); the paper's network once."""
    wanted = set(axes.split(","))
    sel = [r for r in RUNS if r[0] in wanted]
    if wanted - {"H"} and not any(r[2] == PAPER for r in sel):
        sel.insert(0, ("H", 20, PAPER))
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", action="append", default=None)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--axes", default="H,L,W", help="comma list of H, L, W")
    args = ap.parse_args()
    paths = args.data or sorted(glob.glob("build/sim/round*.npz"))
    if not paths:
        raise SystemExit("no data: run `make sim` or pass --data")
    ds = Dataset.concat([Dataset.load(p) for p in paths])
    cfg = Config.load()
    results = {}
    for axis, value, over in runs(args.axes):
        mses = []
        for seed in range(args.repeats):
            _, rep = train(cfg.with_overrides(**over), ds, epochs=args.epochs, seed=seed)
            mses.append(rep["validation"]["mse"])
        results[(axis, value)] = {"mean": float(np.mean(mses)), "std": float(np.std(mses)), "runs": mses}
    out = {"data": paths, "samples": len(ds), "epochs": args.epochs, "repeats": args.repeats,
           **table(results, args.axes)}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
