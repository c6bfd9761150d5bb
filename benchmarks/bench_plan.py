"""Planning benchmark (JSON on stdout): planning time per trial and per robot of
Stage 1 (AO-RRT; the samples of the per-robot trees, and those of the
composite-state search when a case needs it) and Stage 2 (SCP), and where it goes
(PlanResult.profile: the composite search, SCP iterations and convex solves split
into program build with the Jacobians, cvxpy canonicalization and the solver's own
time, learned-force evaluations and their forward and backward seconds), for the
3-robot cases SSL and SLL, in 2-D (yz) and 3-D,
with the learned model (the checkpoint NS2_PLAN_CHECKPOINT, default build/plan/model.pt, else a small
model trained here on the analytic downwash data) and with f_a = 0.  Stage 1 stops
on sample counts, so the plans (and the samples drawn) are the same on every
machine; only the times depend on it."""
from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ns2codegen.checkpoint import save_checkpoint
from ns2codegen.config import Config
from ns2codegen.data.analytic import downwash_dataset
from ns2exp.planning import scenario_problem
from ns2plan.forces import ForceModel, load_force_model
from ns2plan.planner import plan
from ns2plan.problem import PlanningError, RRTParams, SCPParams
from ns2codegen.train import train

SEEDS = (0,)


def main() -> None:
    cfg = Config.load()
    with tempfile.TemporaryDirectory() as tmp:
        ck = Path(os.environ.get("NS2_PLAN_CHECKPOINT", "build/plan/model.pt"))
        source = str(ck)
        if not ck.is_file():
            ds = downwash_dataset(cfg, 1000, seed=0)
            model, rep = train(cfg, ds, epochs=5)
            ck = Path(tmp) / "m.pt"
            save_checkpoint(ck, model, cfg, {"seed": 0, "data_hash": ds.content_hash(), "report": rep})
            source = "analytic downwash data, 5 epochs"
        models = {"NN": load_force_model(cfg, ck), "BL": ForceModel(cfg, None)}
        result = {"model": source, "seeds": list(SEEDS), "scp_solver": SCPParams().solver, "cases": {}}
        for dims in (2, 3):
            for name in ("SSL", "SLL"):
                pb = scenario_problem(cfg, name, dims)
                for mode, fm in models.items():
                    s1, s2, n1, nj, prof, failed = [], [], [], [], [], 0
                    for seed in SEEDS:
                        t0 = time.perf_counter()
                        try:
                            res = plan(pb, fm, RRTParams(seed=seed), SCPParams(seed=seed))
                        except PlanningError:      # no plan within the limits (e.g. 2-D SLL with the model)
                            failed += 1
                            continue
                        s1.append(np.mean(res.stage1.time_per_robot_s))
                        n1.append(np.mean(res.stage1.samples_per_robot))
                        nj.append(res.stage1.joint_samples)
                        s2.append(np.mean(res.stage2.time_per_robot_s))
                        prof.append({"trial_s": time.perf_counter() - t0, **res.profile()})
                    result["cases"][f"{dims}D {name} {mode}"] = {
                        "stage1_s_per_robot": round(float(np.mean(s1)), 3) if s1 else None,
                        "stage2_s_per_robot": round(float(np.mean(s2)), 3) if s2 else None,
                        "stage1_samples_per_robot": int(np.mean(n1)) if n1 else None,
                        "stage1_joint_samples": int(np.mean(nj)) if nj else None,
                        "profile": {k: round(float(np.mean([p[k] for p in prof])), 3) for k in prof[0]} if prof else None,
                        "no_plan_within_limits": failed}
    print(json.dumps({"planning": result}, indent=2))


if __name__ == "__main__":
    main()
