"""Simulator benchmarks (JSON on stdout): data-generation rate (labelled samples per
second of wall time, simulated flights of every team) and the C-in-the-loop speed
as a real-time factor for 1 and 16 robots (host/ns2_fly.c at 1 kHz: sensing, the
firmware's EKF, ns2_pilot with the learned fixed-point term on; RK4 dynamics;
ground-truth interactions on)."""
from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from ns2codegen.checkpoint import save_checkpoint
from ns2codegen.config import Config
from ns2codegen.data.analytic import downwash_dataset
from ns2codegen.export import export
from ns2codegen.results import stamp
from ns2codegen.train import train
from ns2host.sim.cloop import CLoopSwarm, NS2Controller, hover_setpoints, robots_of
from ns2host.sim.collect import collect, teams


def main() -> None:
    cfg = Config.load()
    with tempfile.TemporaryDirectory() as tmp:
        ds0 = downwash_dataset(cfg, 300, seed=0)
        model, rep = train(cfg, ds0, epochs=1)
        save_checkpoint(Path(tmp) / "m.pt", model, cfg, {"seed": 0, "data_hash": ds0.content_hash(), "report": rep})
        export(Path(tmp) / "m.pt", Path(tmp) / "gen")
        gen = Path(tmp) / "gen"
        seconds = 20.0
        t0 = time.perf_counter()
        ds = collect(cfg, gen, seconds, seed=0)
        wall = time.perf_counter() - t0
        result = {"data_generation": {"teams": len(teams(cfg)), "flight_seconds_per_team": seconds,
                                      "samples": len(ds), "wall_s": round(wall, 2),
                                      "samples_per_second": round(len(ds) / wall),
                                      "paper_size_1.4M_estimate_s": round(1.4e6 / (len(ds) / wall))}}
        rtf = {}
        for n, duration in ((1, 10.0), (16, 5.0)):
            pos = [[0.35 * (i % 4), 0.35 * (i // 4), 0.6 + 0.3 * (i % 2)] for i in range(n)]
            sw = CLoopSwarm(cfg, robots_of(["small"] * n, pos, NS2Controller("fixed")), gen, aero=True)
            t0 = time.perf_counter()
            sw.run(duration, hover_setpoints(np.array(pos)), settle_s=0.0)
            rtf[f"{n}_robots"] = round(duration / (time.perf_counter() - t0), 2)
        result["c_in_the_loop_real_time_factor"] = rtf
        result["c_in_the_loop_60s_16_robots_wall_s_estimate"] = round(60.0 / rtf["16_robots"], 1)
    print(json.dumps(stamp(result), indent=2))


if __name__ == "__main__":
    main()
