"""One planning trial: plan a case (NN or BL), check the plan, fly it in the
simulator (ns2exp.tracking) and record it; the summary of a case's trials; the
workers that plan and fly trials (ns2codegen.executor), each holding the planning model."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ns2codegen.config import Config
from ns2codegen.data.from_logs import Flight
from ns2codegen.executor import Executor
from ns2codegen.results import file_hash
from ns2plan.forces import ForceModel, load_force_model
from ns2plan.planner import plan
from ns2plan.problem import GRAMS_TO_N, PlanningError, Problem, RRTParams, SCPParams
from ns2plan.verify import check_solution

from ..margin import FlownStates
from ..tracking import track
from .cases import SCENARIOS, scenario_problem


_WORKER_MODEL = None                    # the model of a planning worker (_worker_init)


def over_limit(trial: dict, fa_max) -> bool:
    """A flown trial (run_trial's record) over a robot's f_a,max somewhere in flight."""
    return any(f > lim for f, lim in zip(trial["track"]["worst_fa_g"], fa_max))


def trial_summary(trials: list, pb: Problem) -> dict:
    """A case's trials (run_trial's records) summed up per robot type."""
    ok = [t for t in trials if t.get("error") is None]
    types = [r.type for r in pb.robots]
    out = {"trials": len(trials), "planned": len(ok)}
    if not ok:
        return out
    err = np.array([max(t["track"]["worst_error_m"]) for t in ok])
    out.update(median_worst_error_m=float(np.median(err)), max_worst_error_m=float(err.max()))
    fa_max = pb.fa_max()
    for kind in sorted(set(types)):
        idx = [i for i, t in enumerate(types) if t == kind]
        worst = np.array([max(t["track"]["worst_fa_g"][i] for i in idx) for t in ok])
        planned = np.array([max(t["check"]["robots"][i]["worst_fa_g"] for i in idx) for t in ok])
        out[kind] = {"max_worst_fa_g": float(worst.max()), "median_worst_fa_g": float(np.median(worst)),
                     "limit_g": float(fa_max[idx[0]]), "trials_over_limit": int((worst > fa_max[idx[0]]).sum()),
                     "planned_max_fa_g": float(planned.max()),
                     "over_limit_states": int(sum(t["track"]["over_limit_states"][i] for t in ok for i in idx)),
                     "over_limit_in_bound_states": int(sum(t["track"]["over_limit_in_bound_states"][i]
                                                           for t in ok for i in idx))}
    out["trials_any_over_limit"] = int(sum(over_limit(t, fa_max) for t in ok))
    out["trials_hit_time_limit"] = int(sum(t["stage1_hit_time_limit"] for t in ok))
    out["stage1_s_per_robot"] = float(np.mean([np.mean(t["timings"]["stage1_per_robot_s"]) for t in ok]))
    out["stage2_s_per_robot"] = float(np.mean([np.mean(t["timings"]["stage2_per_robot_s"]) for t in ok]))
    return out


def run_trial(pb: Problem, fm: ForceModel, gen_dir, seed: int, rrt: RRTParams, scp_params: SCPParams):
    """One trial: plan ``pb`` with ``fm`` from ``seed``, check the plan, fly it; the
    record, the plan and the flight's log (both None without a plan)."""
    t0 = time.perf_counter()
    try:
        res = plan(pb, fm, replace(rrt, seed=seed), replace(scp_params, seed=seed))
    except PlanningError as e:
        return {"seed": seed, "error": str(e), "time_s": time.perf_counter() - t0}, None, None
    chk = check_solution(pb, fm, res.trajs)
    tr = track(pb, res.trajs, gen_dir)
    rec = {"seed": seed, "error": None, "types": [r.type for r in pb.robots], "timings": res.timings(),
           "stage1_costs": [float(c) for c in res.stage1.costs], "scp_merit": res.stage2.merit_history,
           "stage1_samples_per_robot": res.stage1.samples_per_robot, "stage1_hit_time_limit": res.stage1.hit_time_limit,
           "stage1_rounds": res.stage1.iterations,
           "stage1_relaxations": [{"round": r, "robot": i, "excess_g": g} for r, i, g in res.stage1.relaxations],
           "stage1_promotions": [{"round": r, "robot": i} for r, i in res.stage1.promotions],
           "stage1_joint_round": res.stage1.joint_round, "stage1_joint_samples": res.stage1.joint_samples,
           "scp_iterations": res.stage2.iterations, "scp_converged": res.stage2.converged,
           "profile": res.profile(),
           "check": {"robots": chk["robots"]},
           "track": {"worst_error_m": tr["worst_error_m"], "worst_fa_g": tr["worst_fa_g"],
                     **unforeseen(pb, fm, tr["log"])}}
    return rec, res, tr["log"]


def unforeseen(pb: Problem, fm: ForceModel, log: dict, t_pre: float = 1.0) -> dict:
    """Per robot, over a flown plan (from its start): the logged states over f_a,max
    (``over_limit_states``) and those of them where the model at the flown state was
    within the planning bound at the flown relative speed (``over_limit_in_bound_states``:
    the margin's promise broken in flight; the rest the tracking took over the bound)."""
    w = log["t"] >= t_pre
    P, V = log["truth_p"][w], log["truth_v"][w]
    types = pb.type_index()
    true = np.abs(log["truth_fa"][w, :, 2]) / GRAMS_TO_N
    over = true > pb.fa_max()
    in_bound = np.abs(fm.team_np(types, P, V)) <= pb.fa_bound(fm, P, V)
    return {"over_limit_states": over.sum(0).tolist(), "over_limit_in_bound_states": (over & in_bound).sum(0).tolist()}


def _worker_init(checkpoint, checkpoint_hash: str) -> None:
    """A worker's setup (ns2codegen.executor): the model of ``checkpoint`` (its content
    hash in the arguments: a checkpoint rewritten under the same name is loaded again)."""
    global _WORKER_MODEL
    from ns2codegen.checkpoint import load_checkpoint

    _WORKER_MODEL = load_force_model(load_checkpoint(checkpoint).cfg, checkpoint)


def _experiment_trial(mode: str, name: str, dims: int, seed: int, fa_margin_g, gen_dir, rrt: RRTParams,
                      scp_params: SCPParams):
    """run_trial of one experiment trial, planned with the worker's model (NN) or f_a = 0 (BL)."""
    fm = _WORKER_MODEL if mode == "NN" else ForceModel(_WORKER_MODEL.cfg, None)
    return run_trial(scenario_problem(fm.cfg, name, dims, fa_margin_g), fm, gen_dir, seed, rrt, scp_params)


def _flown_plan(name: str, dims: int, seed: int, fa_margin_g, gen_dir, rrt: RRTParams, scp_params: SCPParams,
                t_pre: float = 1.0):
    """One NN plan, flown (run_trial) with the worker's model: its record, the true
    states from the plan's start (FlownStates) and the drones' log of the whole
    flight (from_logs.Flight: estimates, as training data is logged), both None
    without a plan."""
    fm = _WORKER_MODEL
    pb = scenario_problem(fm.cfg, name, dims, fa_margin_g)
    rec, _, log = run_trial(pb, fm, gen_dir, seed, rrt, scp_params)
    if log is None:
        return rec, None, None
    w = log["t"] >= t_pre
    team = list(SCENARIOS[name])
    return (rec, FlownStates(team, log["truth_p"][w], log["truth_v"][w], log["truth_fa"][w, :, 2] / GRAMS_TO_N,
                             f"plan {dims}D"),
            Flight(team, *(log[k] for k in ("t", "p", "v", "q", "pwm", "battery_V")), p_d=log["p_d"],
                   name=f"plan {dims}D {name} seed {seed}"))


def fly_plans(checkpoint, gen_dir, tasks: list, fa_margin_g, rrt: RRTParams, scp_params: SCPParams,
              executor: Executor) -> list:
    """_flown_plan for every (scenario, dims, seed) of ``tasks`` on ``executor``
    (plan_executor's: its workers hold the model of ``checkpoint``)."""
    args = [(n, d, s, fa_margin_g, str(gen_dir), rrt, scp_params) for n, d, s in tasks]
    return executor.map(_flown_plan, args)


def plan_executor(checkpoint, gen_dir, workers: int, scheduler: str | None = None) -> Executor:
    """The executor of planning trials (ns2codegen.executor: ``workers`` forked processes,
    or the Dask cluster of ``scheduler`` / NS2_SCHEDULER, or this process), each worker
    holding the model of ``checkpoint`` (_worker_init); the C flight kernel is built here
    first (the workers on this machine load it)."""
    from ns2host.cfhost import load_fly

    load_fly(gen_dir)                                 # build once, before any worker loads it
    return Executor(workers, scheduler, setup=(_worker_init, (str(checkpoint), file_hash(checkpoint))))


def trial_rows(cfg: Config, tasks: list, done: list) -> list:
    """calibrated_margin's and plan_trained_checkpoint's record of each flown plan."""
    fa_max = {(n, d): scenario_problem(cfg, n, d).fa_max() for n, d, _ in tasks}
    return [{"case": f"{d}D {n}", "seed": s, "planned": fl is not None,
             **({"worst_fa_g": rec["track"]["worst_fa_g"], "over_limit": over_limit(rec, fa_max[n, d]),
                 "over_limit_in_bound_states": int(sum(rec["track"]["over_limit_in_bound_states"]))}
                if fl is not None else {"error": rec["error"]})}
            for (n, d, s), (rec, fl, _) in zip(tasks, done)]
