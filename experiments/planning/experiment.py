"""The paper's planning experiments: every case in every dimension, planned with the
learned model (NN) and with f_a = 0 (BL) by the same algorithm and parameters, then
flown in the simulator with the C controller and the ground-truth interactions.
Reported per robot type: worst tracking error and worst true interaction force
against the limits (5 g small, 10 g large), planning times; figures like the paper's."""
from __future__ import annotations

import json
from contextlib import nullcontext
from pathlib import Path

from ns2codegen.config import Config
from ns2codegen.fileio import atomic_write_files
from ns2codegen.results import stamp
from ns2plan.forces import load_force_model
from ns2plan.output import write_plan
from ns2plan.problem import RRTParams, SCPParams

from ..margin import margin_table
from . import runs
from .calibrated import measured_margin
from .cases import SCENARIOS, scenario_problem
from .reports import downwash_check, downwash_table, example_figure, profile_table, summary_figure, table
from .store import RESUME_DIR, TrialStore, runs_folder


def planning_experiments(cfg: Config, checkpoint, gen_dir, out_dir, scenarios=None, dims=(2, 3), trials: int = 5,
                         rrt: RRTParams = RRTParams(), scp_params: SCPParams = SCPParams(), log=print,
                         progress=None, fa_margin_g=None, modes=("NN", "BL"), calibrate: bool = False,
                         workers: int = 2, runs_dir=None) -> dict:
    """Every scenario in every dimension, ``trials`` seeds with NN and with BL (or
    ``modes``; ``progress(1)`` after every trial), ``workers`` trials at once (forked
    processes, or the Dask cluster of NS2_SCHEDULER: runs.plan_executor; a trial's
    outcome does not depend on it); writes plan.json, plan.md and
    the figures.  ``fa_margin_g`` None: the margin measured on held-out flights
    (measured_margin; with ``calibrate`` also on the NN's flown plans of calibration
    seeds, calibrated_margin), else this one (g, one value or per type).  The margin
    and every finished trial are kept in ``runs_dir`` (default ``out_dir``/RESUME_DIR;
    TrialStore; each case's example plan in ``out_dir``/RESUME_DIR) as they finish: the
    same call again, after a run was cut short, reuses them and plans only the rest."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    models = [m for m in ("NN", "BL") if m in modes]
    nn = load_force_model(cfg, checkpoint)
    names = list(scenarios or SCENARIOS)
    store = TrialStore(runs_folder(out, runs_dir), checkpoint, names, list(dims), rrt,
                       scp_params, examples=out / RESUME_DIR)
    rep = None
    if fa_margin_g is None:
        rep = store.get("margin", calibrate)
        if rep is None:
            cal = (dict(checkpoint=checkpoint, scenarios=names, dims=dims, rrt=rrt,
                        scp_params=scp_params, workers=workers, cache=out / "calibration_flights.npz")
                   if calibrate else None)
            rep = measured_margin(cfg, nn, gen_dir, cache=out / "held_out_flights.npz", log=log, calibration=cal,
                                  workers=workers)
            rep = json.loads(json.dumps(rep, default=float))     # as a resumed run reads it back
            store.put("margin", rep, calibrate)
        else:
            log(f"the margin of an earlier run of these inputs ({store.folder})")
        fa_margin_g = rep["margin_g"]
        log(f"planning margin (g): {fa_margin_g}")
    tasks = [(mode, name, d, trial) for d in dims for name in names for mode in models for trial in range(trials)]
    tkey = lambda mode, name, d, trial: (mode, name, d, trial, fa_margin_g)  # noqa: E731
    kept = {t: store.get("trial", *tkey(*t)) for t in tasks}
    todo = [t for t in tasks if kept[t] is None]
    store.report("trials", len(tasks), len(todo), log)
    for group in {t[:3] for t in tasks}:    # a case's example (the first plan) kept elsewhere: fly it again
        first = next((t for t in tasks if t[:3] == group and (kept[t] is None or kept[t]["error"] is None)), None)
        if first is not None and kept[first] is not None and not store.has_example(*tkey(*first)):
            kept[first] = None
            todo.append(first)
    ex = runs.plan_executor(checkpoint, gen_dir, workers) if todo else nullcontext()
    with ex:
        args = {t: (*t[:4], fa_margin_g, str(gen_dir), rrt, scp_params) for t in todo}

        futures = {t: ex.submit(runs._experiment_trial, *a) for t, a in args.items()}
        for t, f in futures.items():            # a trial kept as soon as it finishes, in any order
            ex.when_done(f, lambda out, t=t: store.put("trial", out[0], *tkey(*t)))
        results, figures = {}, {}
        for d in dims:
            for name in names:
                pb = scenario_problem(cfg, name, d, fa_margin_g)
                key = f"{d}D {name}"
                results[key] = {}
                examples = {}
                for mode in models:
                    recs = []
                    for trial in range(trials):
                        t = (mode, name, d, trial)
                        if kept[t] is not None:
                            rec, res, flight = kept[t], None, None
                            if rec["error"] is None and mode not in examples:
                                res, flight = store.get_example(*tkey(*t)) or (None, None)
                        else:
                            rec, res, flight = futures[t].result()
                            if res is not None and mode not in examples:
                                store.put_example((res, flight), *tkey(*t))
                        recs.append(rec)
                        if progress is not None:
                            progress(1)
                        if res is not None and mode not in examples:
                            examples[mode] = (res, flight)
                            write_plan(out / "trajectories" / f"{d}d_{name}_{mode}", res.trajs,
                                       [r.type for r in pb.robots], pb.kappa())
                        log(f"{key} {mode} trial {trial}: " + (rec["error"] if rec["error"] else
                            f"worst error {100 * max(rec['track']['worst_error_m']):.1f} cm, worst |f_a| "
                            + ", ".join(f"{r.type} {f:.1f} g" for r, f in zip(pb.robots, rec["track"]["worst_fa_g"]))))
                    results[key][mode] = {"summary": runs.trial_summary(recs, pb), "trials": recs}
                if d == 2 and len(examples) == 2:
                    figures[f"plan_{d}d_{name}.png"] = (pb, examples)
    check = downwash_check(cfg, nn)
    md = ("Model vs simulator, f_a,z (g) of a robot hovering 1 m up directly under another, predicted / true:\n\n"
          + downwash_table(check) + "\n\n"
          + (f"Planning margin from held-out flights ({rep['source']}):\n\n{margin_table(rep)}\n\n" if rep else
             f"Planning margin (given): {fa_margin_g} g\n\n")
          + table(results) + "\n\nWhere the planning time goes (means per trial, PlanResult.profile):\n\n"
          + profile_table(results) + "\n")
    atomic_write_files(out, {"plan.json": json.dumps(stamp({"model_check": check, "margin": rep or {"margin_g": fa_margin_g},
                                                            "cases": results}), indent=1, default=float) + "\n",
                             "plan.md": md})
    for fname, (pb, examples) in figures.items():      # after the results: a figure cannot lose them
        example_figure(pb, examples, out / fname)
    summary_figure(results, out / "plan_summary.png")
    return results
