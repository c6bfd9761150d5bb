"""Planning benchmark (JSON on stdout): planning time per trial and per robot of
Stage 1 (AO-RRT; the samples of the per-robot trees, and those of the
composite-state search when a case needs it) and Stage 2 (SCP), and where it goes
(PlanResult.profile: the composite search, SCP iterations, linearizations and convex
solves split into program build or parameter setting with the Jacobians, cvxpy
canonicalization and the solver's own time, learned-force evaluations and their
forward and backward seconds), for the 3-robot cases SSL and SLL, in 2-D (yz) and
3-D, with the learned model (the checkpoint NS2_PLAN_CHECKPOINT, default
build/plan/model.pt, else a small model trained here on the analytic downwash data)
and with f_a = 0.

Stage 2 runs twice on every trial's Stage 1 result, side by side: with the default
one parametrized program per run (SCPParams.program "parametrized") and with the
program rebuilt at every solve ("rebuilt"), in alternating order; ``scp_programs``
gives per case and over all trials Stage 2 and Stage 1 + 2 seconds per trial for
both, their ratios and how far the two plans are apart.  The other fields are those
of the default path.  Stage 1 stops on sample counts, so the plans (and the samples
drawn) are the same on every machine; only the times depend on it."""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from ns2codegen.checkpoint import save_checkpoint
from ns2codegen.config import Config
from ns2codegen.data.analytic import downwash_dataset
from ns2exp.planning import scenario_problem
from ns2plan.aorrt import AORRT, post_process
from ns2plan.forces import ForceModel, load_force_model, single_thread
from ns2plan.planner import PlanResult
from ns2plan.problem import PlanningError, RRTParams, SCPParams
from ns2plan.scp import scp
from ns2codegen.results import stamp
from ns2codegen.train import train

SEEDS = (0, 1)
PROGRAMS = ("parametrized", "rebuilt")      # the default first


def trial(pb, fm, seed: int, order) -> dict:
    """One trial: Stage 1 (as ns2plan.planner.plan), then Stage 2 with each program of
    ``order`` on its result.  Returns a PlanResult per program (the force counts of
    Stage 1 and that program's Stage 2)."""
    fm.reset_counts()
    with single_thread():
        s1 = AORRT(pb, fm, RRTParams(seed=seed)).run()
        initial = post_process(s1.trajs, pb.kappa())
    counts1 = dict(fm.counts)
    out = {}
    for program in order:
        fm.reset_counts()
        with single_thread():
            s2 = scp(pb, fm, initial, SCPParams(seed=seed, program=program))
        out[program] = PlanResult(s1, initial, s2, {k: counts1[k] + fm.counts[k] for k in counts1})
    return out


def _mean(xs, digits=3):
    return round(float(np.mean(xs)), digits) if xs else None


def _sig(x: float) -> float:
    return float(f"{x:.2g}")


def side_by_side(results: list) -> dict:
    """Stage 2 and Stage 1 + 2 seconds per trial of both programs, the ratios rebuilt /
    parametrized, the parametrized program's Stage 2 split, and the largest
    difference between the two plans (position m, action m/s^2, relative merit)."""
    if not results:
        return {}
    out = {}
    for program in PROGRAMS:
        s2 = [r[program].stage2 for r in results]
        out[program] = {"stage2_s_per_trial": _mean([s.time_s for s in s2]),
                        "stage1_plus_2_s_per_trial": _mean([r[program].stage1.time_s + r[program].stage2.time_s
                                                            for r in results]),
                        "convex_solves": _mean([s.profile.get("solves", 0) for s in s2], 1),
                        "linearizations": _mean([s.profile.get("linearizations", 0) for s in s2], 1),
                        **{f"cp_{k}": _mean([s.profile.get(k, 0.0) for s in s2])
                           for k in ("build_s", "canon_s", "solver_s")}}
    new, old = out["parametrized"], out["rebuilt"]
    out["stage2_speedup"] = round(old["stage2_s_per_trial"] / new["stage2_s_per_trial"], 2)
    out["stage1_plus_2_speedup"] = round(old["stage1_plus_2_s_per_trial"] / new["stage1_plus_2_s_per_trial"], 2)
    pairs = [(a, b) for r in results for a, b in zip(r["rebuilt"].trajs, r["parametrized"].trajs)]
    merits = [(r["rebuilt"].stage2.merit_history[-1], r["parametrized"].stage2.merit_history[-1]) for r in results]
    out["plans_max_dp_m"] = _sig(max(np.abs(a.p - b.p).max() for a, b in pairs))
    out["plans_max_du_mps2"] = _sig(max(np.abs(a.u - b.u).max() for a, b in pairs))
    out["merit_max_rel_diff"] = _sig(max(abs(a - b) / abs(a) for a, b in merits))
    out["same_iterations"] = all(r["rebuilt"].stage2.iterations == r["parametrized"].stage2.iterations
                                 for r in results)
    return out


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
        every = []
        k = 0
        for dims in (2, 3):
            for name in ("SSL", "SLL"):
                pb = scenario_problem(cfg, name, dims)
                for mode, fm in models.items():
                    results, failed = [], 0
                    for seed in SEEDS:
                        order = PROGRAMS if k % 2 == 0 else PROGRAMS[::-1]      # alternate who goes first
                        k += 1
                        try:
                            results.append(trial(pb, fm, seed, order))
                        except PlanningError:      # no plan within the limits (e.g. 2-D SLL with the model)
                            failed += 1
                    every += results
                    res = [r["parametrized"] for r in results]
                    prof = [{"trial_s": r.stage1.time_s + r.stage2.time_s, **r.profile()} for r in res]
                    result["cases"][f"{dims}D {name} {mode}"] = {
                        "stage1_s_per_robot": _mean([np.mean(r.stage1.time_per_robot_s) for r in res]),
                        "stage2_s_per_robot": _mean([np.mean(r.stage2.time_per_robot_s) for r in res]),
                        "stage1_samples_per_robot": int(np.mean([np.mean(r.stage1.samples_per_robot) for r in res]))
                        if res else None,
                        "stage1_joint_samples": int(np.mean([r.stage1.joint_samples for r in res])) if res else None,
                        "profile": {key: round(float(np.mean([p[key] for p in prof])), 3) for key in prof[0]}
                        if prof else None,
                        "scp_programs": side_by_side(results),
                        "no_plan_within_limits": failed}
        result["scp_programs"] = {"trials": len(every), **side_by_side(every)}
    print(json.dumps(stamp({"planning": result}), indent=2))


if __name__ == "__main__":
    main()
