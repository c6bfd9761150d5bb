"""Ablation of the paper's Table "ablation" on simulated flights (JSON on stdout):
validation MSE (g^2) for H in {10, 20, 40} at L = 4 and L in {3, 4, 5} at H = 20,
with --repeats seeds each, on the data sets given (default: build/sim/round*.npz
from `make sim`).

    python benchmarks/ablation.py [--data A.npz --data B.npz] [--epochs 20] [--repeats 1]
"""
from __future__ import annotations

import argparse
import glob
import json

import numpy as np

from ns2codegen.config import Config
from ns2codegen.data.dataset import Dataset
from ns2codegen.train import train


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", action="append", default=None)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    paths = args.data or sorted(glob.glob("build/sim/round*.npz"))
    if not paths:
        raise SystemExit("no data: run `make sim` or pass --data")
    ds = Dataset.concat([Dataset.load(p) for p in paths])
    cfg = Config.load()
    runs = [("H", h, {"hidden": h, "layers": 4}) for h in (10, 20, 40)] + \
           [("L", l, {"hidden": 20, "layers": l}) for l in (3, 5)]
    out = {"data": paths, "samples": len(ds), "epochs": args.epochs, "repeats": args.repeats, "H": {}, "L": {}}
    for axis, value, over in runs:
        mses = []
        for seed in range(args.repeats):
            _, rep = train(cfg.with_overrides(**over), ds, epochs=args.epochs, seed=seed)
            mses.append(rep["validation"]["mse"])
        entry = {"mean": float(np.mean(mses)), "std": float(np.std(mses)), "runs": mses}
        out[axis][str(value)] = entry
        if axis == "H" and value == 20:
            out["L"]["4"] = entry
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
