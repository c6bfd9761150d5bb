"""Core benchmarks (JSON on stdout): training throughput on a paper-sized data set
(1.4 million samples over the 12 scenarios, generated), time for 20 epochs, and the
host C inference time per call with 1, 4 and 16 neighbours, float and fixed point.

    python benchmarks/bench_core.py [--epochs 20] [--samples 1400000] [--skip-training]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from ns2codegen.checkpoint import save_checkpoint
from ns2codegen.config import Config
from ns2codegen.data.analytic import downwash_dataset, scenario_mixes
from ns2codegen.export import export
from ns2codegen.results import stamp
from ns2codegen.train import train


def bench_training(cfg: Config, samples: int, epochs: int) -> tuple[dict, object]:
    per = samples // len(scenario_mixes(cfg))
    t0 = time.perf_counter()
    ds = downwash_dataset(cfg, per, seed=0)
    gen_s = time.perf_counter() - t0
    done = [0]
    t_start = time.perf_counter()

    def progress(n):
        done[0] += n
        if done[0] % 1_000_000 < n:
            print(f"  trained {done[0]:,} samples, {time.perf_counter() - t_start:.0f} s", file=sys.stderr)

    model, rep = train(cfg, ds, epochs=epochs, seed=0, progress=progress)
    return {"samples": len(ds), "train_samples": rep["train_samples"], "epochs": epochs,
            "batch_size": rep["batch_size"], "data_generation_s": round(gen_s, 3),
            "train_time_s": round(rep["train_seconds"], 1),
            "samples_per_second": round(rep["samples_per_second"]),
            "validation_mse_g2": round(rep["validation"]["mse"], 4),
            "label_variance_g2": round(rep["validation"]["label_var"], 4),
            "torch_threads": torch.get_num_threads()}, (model, ds, rep)


def bench_inference(gen_dir: Path, cfg: Config, reps: int = 20000) -> dict:
    from ns2host.cbuild import CModel

    c = CModel(gen_dir)
    rng = np.random.default_rng(0)
    out = {}
    for n in (1, 4, 16):
        types = rng.integers(0, cfg.num_robot_types, n)
        rels = np.column_stack([rng.uniform(-0.2, 0.2, (n, 2)), rng.uniform(0.1, 1.0, n),
                                rng.normal(0, 0.3, (n, 3))]).astype(np.float32)
        p, v = np.float32([0.1, -0.2, 0.8]), np.float32([0.2, 0.0, -0.1])
        for fixed in (False, True):
            best = min(c.ns_per_call(fixed, reps, 0, p, v, types, rels) for _ in range(5))
            out[f"{'fixed' if fixed else 'float'}_{n}_neighbors_us"] = round(best / 1000.0, 3)
    out["note"] = "best of 5 runs of the mean over %d calls; environment neighbour always included" % reps
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=1_400_000)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--skip-training", action="store_true", help="train a small model for the C timing only")
    args = ap.parse_args()
    cfg = Config.load()
    result = {"machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                          "python": platform.python_version(), "torch": torch.__version__}}
    with tempfile.TemporaryDirectory() as tmp:
        if args.skip_training:
            _, (model, ds, rep) = bench_training(cfg, 12_000, 2)
        else:
            result["training"], (model, ds, rep) = bench_training(cfg, args.samples, args.epochs)
        ck = Path(tmp) / "model.pt"
        save_checkpoint(ck, model, cfg, {"seed": 0, "data_hash": ds.content_hash(), "report": rep})
        t0 = time.perf_counter()
        export(ck, Path(tmp) / "gen")
        result["export_s"] = round(time.perf_counter() - t0, 2)
        result["host_c_inference"] = bench_inference(Path(tmp) / "gen", cfg)
    print(json.dumps(stamp(result), indent=2))


if __name__ == "__main__":
    main()
