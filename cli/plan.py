"""`ns2 plan`: interaction-aware motion planning (AO-RRT + SCP) of one problem file (the
product: ns2plan.problemfile, the planning model of ns2host.sim.planmodel); without
--problem the paper's experiments, which cli/planexp.py runs."""
from __future__ import annotations

from pathlib import Path

import click

from ns2codegen.config import Config

from .common import (
    _config, _config_option, _emit, _json_option, _progress,
    _quiet_option, _scheduler_option, main,
)


@main.command("plan")
@click.option("--checkpoint", type=click.Path(dir_okay=False), default=None,
              help="deep set for the NN planner (its config is used); without it one is trained on simulated "
                   "flights into --model-dir first (several minutes, announced)")
@click.option("--model-dir", type=click.Path(file_okay=False), default=None,
              help="where the planning model is trained without --checkpoint (reused while its config matches) "
                   "[default: OUT/model]")
@_config_option
@click.option("--problem", "problem_path", type=click.Path(dir_okay=False), default=None,
              help="plan one problem (JSON: robots, axes, limits) instead of the paper's experiments")
@click.option("--baseline", is_flag=True, help="with --problem: plan with f_a = 0 (BL)")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True,
              help="results folder (plans, plan.json, plan.md, figures)")
@click.option("--scenarios", default="SL,SS,LL,SSL,SLL", show_default=True,
              help="comma-separated experiment scenarios")
@click.option("--dims", type=click.Choice(["2", "3", "both"]), default="both", show_default=True,
              help="plan in the yz plane (2), in 3-D (3) or both")
@click.option("--trials", type=click.IntRange(min=1), default=5, show_default=True,
              help="seeds per scenario and planner")
@click.option("--max-samples", type=click.IntRange(min=1), default=None,
              help="samples per RRT run, Stage 1's stopping rule [default: SearchParams.max_samples]")
@click.option("--time-limit", type=click.FloatRange(min=1.0), default=300.0, show_default=True,
              help="wall-clock safety net in seconds for Stage 1 and again for Stage 2, per plan (the sample and "
                   "iteration counts stop them first, so a seed gives the same plan on any machine)")
@click.option("--fa-margin", default="calibrated", show_default=True,
              help="experiments: g of every force limit kept free for model error, a number, 'measured' (per "
                   "robot type and bin of the relative speed from the model's error on held-out simulated flights, "
                   "ns2exp.margin) or 'calibrated' (measured on those and on the NN's own flown plans of "
                   "calibration seeds, raised round by round until they keep it: ns2exp.planning.calibrated_margin)")
@click.option("--plan-data-rounds", type=click.IntRange(min=0), default=None,
              help="experiments: first train the model on its own flown plans too, this many rounds (plan the "
                   "training seeds, fly, add the logs, retrain: ns2exp.planning.plan_trained_checkpoint; the checkpoint "
                   "needs its data_files beside it, as the default planning model has) [default: 2 for the planning "
                   "model trained without --checkpoint, 0 with --checkpoint]")
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True,
              help="experiments (and --fa-margin calibrated, --plan-data-rounds): trials planned and flown at once, "
                   "in forked processes (the outcomes do not depend on it)")
@_scheduler_option
@click.option("--runs", "runs_dir", type=click.Path(file_okay=False), default=None,
              help="experiments: keep the margin and every finished trial here (small JSON files; a rerun plans "
                   "only what is missing; docs/results/runs/planning for the runs behind docs/) [default: OUT/resume]")
@_quiet_option
@_json_option
def plan_cmd(checkpoint, model_dir, config_path, problem_path, baseline, out_dir, scenarios, dims, trials,
             max_samples, time_limit, fa_margin, plan_data_rounds, workers, runs_dir, quiet, as_json):
    """Interaction-aware motion planning (AO-RRT + SCP): the paper's experiments, or one problem.
    The config is the checkpoint's; --config only without a checkpoint."""
    from dataclasses import replace

    from ns2plan.problem import PlanningError, RRTParams, SCPParams, SearchParams
    from ns2plan.problemfile import load_problem, plan_problem_file

    rrt = RRTParams(SearchParams(time_s=min(SearchParams.time_s, time_limit)), total_time_s=time_limit)
    if max_samples is not None:
        rrt = replace(rrt, search=replace(rrt.search, max_samples=max_samples))
    scp_params = SCPParams(time_limit_s=time_limit)
    names = [s.strip() for s in scenarios.split(",") if s.strip()]
    if not problem_path:
        from .planexp import check_scenarios        # the paper's experiments (ns2exp), never a problem file's

        check_scenarios(names)
    try:
        margin = None if fa_margin in ("measured", "calibrated") else float(fa_margin)
    except ValueError:
        raise click.UsageError(f"--fa-margin: a number of grams, 'measured' or 'calibrated', got {fa_margin!r}") from None
    if margin is not None and not (0.0 <= margin < 1000.0):
        raise click.UsageError(f"--fa-margin: must be in [0, 1000) g, got {fa_margin!r}")
    if checkpoint is not None and config_path is not None:
        raise click.UsageError("give --checkpoint or --config: a checkpoint carries its config")
    if problem_path and not Path(problem_path).is_file():
        raise PlanningError(f"problem file not found: {problem_path}")
    cfg = _plan_config(checkpoint, config_path)
    if problem_path:
        load_problem(cfg, problem_path)              # refuse a bad file before any training
    trained = checkpoint is None and not (problem_path and baseline)
    if trained:
        checkpoint = planning_model(cfg, model_dir, out_dir)
        cfg = _plan_config(checkpoint, None)
    if not problem_path:
        from .planexp import plan_experiments

        plan_experiments(cfg, checkpoint, trained, out_dir, names, dims, trials, rrt, scp_params, margin,
                         fa_margin == "calibrated", plan_data_rounds, workers, quiet, as_json, runs_dir)
        return
    with _progress(quiet, None, "stage", "plan"):
        report = plan_problem_file(cfg, problem_path, None if baseline else checkpoint, out_dir, rrt, scp_params)
    summary = {k: report[k] for k in ("valid", "timings", "robots")}
    _emit(as_json, summary, f"wrote {out_dir}: plan " + ("valid" if report["valid"] else "INVALID")
          + f", Stage 1 {report['timings']['stage1_s']:.1f} s, Stage 2 {report['timings']['stage2_s']:.1f} s")
    if not report["valid"]:
        raise click.ClickException(f"the plan violates a limit (see {out_dir}/plan.json)")


def planning_model(cfg: Config, model_dir, out_dir) -> Path:
    """The planning model trained on simulated flights into --model-dir (default OUT/model),
    reused while its config matches (ns2host.sim.planmodel)."""
    from ns2host.sim.planmodel import default_checkpoint

    folder = Path(model_dir) if model_dir else Path(out_dir) / "model"
    return default_checkpoint(cfg, folder, log=lambda msg: click.echo(msg, err=True))


def _plan_config(checkpoint, config_path) -> Config:
    """The checkpoint's config when one is given, else --config or the default."""
    if checkpoint is None:
        return _config(config_path)
    from ns2codegen.checkpoint import load_checkpoint

    return load_checkpoint(checkpoint).cfg
