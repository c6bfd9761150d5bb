"""`ns2 plan` without --problem: the paper's planning experiments (ns2exp.planning).

The one CLI module of `ns2 plan` that reaches the experiments; the product path
(cli/plan.py: options, problem files, the planning model) never imports it when
given --problem (tests/test_layers.py)."""
from __future__ import annotations

from pathlib import Path

import click

from ns2codegen.config import Config

from .common import _emit, _progress


def check_scenarios(names: list) -> None:
    """--scenarios: every name one of the paper's cases."""
    from ns2exp.planning import SCENARIOS

    unknown = [s for s in names if s not in SCENARIOS]
    if unknown:
        raise click.UsageError(f"unknown scenarios {unknown}; choose from {list(SCENARIOS)}")


def plan_experiments(cfg: Config, checkpoint, trained: bool, out_dir, names: list, dims: str, trials: int, rrt,
                     scp_params, margin, calibrate: bool, plan_data_rounds, workers: int, quiet: bool,
                     as_json: bool, runs_dir=None) -> None:
    """Every case of ``names`` in ``dims``, NN and BL (ns2exp.planning.planning_experiments),
    with ``checkpoint`` (``trained``: the planning model `ns2 plan` trained, not one given)
    after, with ``plan_data_rounds``, its retraining on its own flown plans; the finished
    trials kept in ``runs_dir`` (default ``out_dir``/resume)."""
    from ns2codegen.export import export as run_export
    from ns2exp import planning as ex
    from ns2exp.margin import held_out_flights
    from ns2host.sim.planmodel import NEAR_GAP_MAX

    if plan_data_rounds is None:
        plan_data_rounds = ex.PLAN_DATA_ROUNDS if trained else 0
    if plan_data_rounds:
        ex.training_data_files(checkpoint)            # refuse a checkpoint without its data before any flight
    gen = Path(out_dir) / "gen"
    run_export(checkpoint, gen)
    dim_list = (2, 3) if dims == "both" else (int(dims),)
    log = (lambda msg: None) if quiet else (lambda msg: click.echo(msg, err=True))
    if plan_data_rounds:
        held = held_out_flights(cfg, gen, gap_max=NEAR_GAP_MAX, cache=Path(out_dir) / "held_out_flights.npz",
                                workers=workers)
        keep = ex.runs_folder(out_dir, runs_dir) / "models"
        checkpoint = ex.plan_trained_checkpoint(cfg, checkpoint, gen, held, names, dim_list, rounds=plan_data_rounds,
                                                rrt=rrt, scp_params=scp_params, workers=workers, log=log, keep=keep)
        run_export(checkpoint, gen)
    with _progress(quiet, len(dim_list) * len(names) * 2 * trials, "trial", "plan") as update:
        res = ex.planning_experiments(cfg, checkpoint, gen, out_dir, names, dim_list, trials, rrt, scp_params,
                                      log=log, progress=update, fa_margin_g=margin, calibrate=calibrate,
                                      workers=workers, runs_dir=runs_dir)
    _emit(as_json, {k: {m: r["summary"] for m, r in v.items()} for k, v in res.items()},
          (Path(out_dir) / "plan.md").read_text())
