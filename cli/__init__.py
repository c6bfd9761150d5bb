"""`ns2` command line, the top layer: it may import every other package.

One convention for every command:
  * the config comes from the checkpoint or export folder a command is given (an
    export folder carries its ``ns2_config.toml``); commands that make a data set or
    a model from scratch take ``--config`` (default: the package's default.toml);
  * every expected error (``Ns2Error``) is one line on stderr and exit status 1;
  * human output on stdout, ``--json`` for machines;
  * progress bars on stderr for everything that takes more than a few seconds
    (off with ``--quiet`` or when stderr is not a terminal).
"""
from __future__ import annotations

import json
import sys
from contextlib import contextmanager
from pathlib import Path

import click

from ns2codegen.config import ONBOARD_WIDTHS, Config
from ns2codegen.errors import Ns2Error

# the extra that installs a module the core does not need (pyproject.toml)
_EXTRAS = {"scipy": "sysid", "matplotlib": "sim", "cffi": "target", "unicorn": "target", "capstone": "target",
           "elftools": "target", "serial": "target", "cvxpy": "plan", "clarabel": "plan"}
_COMMAND_EXTRAS = {"sysid": "sysid", "hil": "target", "sim": "sim", "plan": "plan"}


class _Errors(click.Group):
    """Every expected error (``Ns2Error``) becomes one line and exit status 1, and so
    does a missing optional dependency (it names the extra to install)."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except Ns2Error as e:
            raise click.ClickException(" ".join(str(e).split())) from e  # one line
        except ModuleNotFoundError as e:
            top = (e.name or "").split(".")[0]
            if top not in _EXTRAS:
                raise
            extra = _COMMAND_EXTRAS.get(ctx.invoked_subcommand or "", _EXTRAS[top])
            raise click.ClickException(f"{top} is not installed: this command needs "
                                       f"pip install 'ns2codegen[{extra}]'") from e


@click.group(cls=_Errors, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="ns2codegen", help="print the version and exit")
def main():
    """Neural-Swarm2 deep sets: training, export to C, verification, simulation, planning."""


# ------------------------------------------------------------------ conventions
def _json_option(f):
    return click.option("--json", "as_json", is_flag=True,
                        help="print the result as JSON (for machines) instead of text")(f)


def _quiet_option(f):
    return click.option("--quiet", is_flag=True,
                        help="no progress bar (it is also off when stderr is not a terminal)")(f)


def _config_option(f):
    return click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
                        help="config file (TOML) [default: the package's default.toml]")(f)


_vehicle_option = click.option(
    "--vehicle", "vehicle_files", type=click.Path(dir_okay=False), multiple=True,
    help="vehicle parameter file of `ns2 sysid` (replaces that robot type's parameters; repeatable)")


def _gen_option(default=None, help="export folder (`ns2 export`): its model and the config it carries"):
    return click.option("--gen", "gen_dir", type=click.Path(file_okay=False), default=default,
                        required=default is None, show_default=default is not None, help=help)


def _config(path, vehicle_files=()) -> Config:
    return Config.load(path).with_vehicle_files(vehicle_files)


def _export_config(gen_dir, vehicle_files=()) -> Config:
    from ns2codegen.export import export_config

    return export_config(gen_dir).with_vehicle_files(vehicle_files)


def _emit(as_json: bool, result, text: str) -> None:
    """The one way a command reports: ``text`` for people, ``result`` as JSON for machines."""
    click.echo(json.dumps(result, indent=2, default=float) if as_json else text.rstrip("\n"))


@contextmanager
def _progress(quiet: bool, total=None, unit: str = "it", desc: str | None = None):
    """A tqdm bar on stderr; yields its ``update``.  Without a ``total`` (work that
    reports no steps) it shows the elapsed time, refreshed every second."""
    import threading

    from tqdm import tqdm

    disable = quiet or not sys.stderr.isatty()
    with tqdm(total=total, unit=unit, desc=desc, disable=disable, file=sys.stderr,
              unit_scale=unit == "sample", leave=False) as bar:
        done = threading.Event()

        def tick():
            while not done.wait(1.0):
                bar.refresh()

        ticker = threading.Thread(target=tick, daemon=True)
        if total is None and not disable:
            ticker.start()
        try:
            yield bar.update
        finally:
            done.set()
            if ticker.is_alive():
                ticker.join()


def _parent_ok(path) -> None:
    from ns2codegen.fileio import OutputError

    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise OutputError(f"output folder {parent} does not exist")


# ------------------------------------------------------------------ core
@main.command("gen-data")
@click.option("--kind", type=click.Choice(["downwash", "max"]), default="downwash", show_default=True,
              help="analytic downwash + ground effect, or the paper's 2-group max example")
@click.option("--samples-per-scenario", type=click.IntRange(min=1), default=2000, show_default=True,
              help="samples drawn per scenario (team and flight pattern)")
@click.option("--seed", type=int, default=0, show_default=True, help="random seed (same seed, same data set)")
@click.option("--noise", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="label noise std (g)")
@_config_option
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="data set to write (.npz)")
@_json_option
def gen_data(kind, samples_per_scenario, seed, noise, config_path, out, as_json):
    """Generate an analytic training data set (.npz, format in docs/training.md)."""
    from ns2codegen.data import analytic

    cfg = _config(config_path)
    if kind == "downwash":
        ds = analytic.downwash_dataset(cfg, samples_per_scenario, seed=seed, noise_g=noise)
    else:
        ds = analytic.max_dataset(cfg, samples_per_scenario, seed=seed)
    _parent_ok(out)
    ds.save(out)
    _emit(as_json, {"out": out, "samples": len(ds), "scenarios": ds.scenario_names},
          f"wrote {out}: {len(ds)} samples, {len(ds.scenario_names)} scenarios")


@main.command()
@click.option("--data", "data_paths", type=click.Path(dir_okay=False), required=True, multiple=True,
              help="data set (.npz); repeat to train on several (e.g. curriculum rounds)")
@_config_option
@click.option("--out", type=click.Path(dir_okay=False), required=True,
              help="checkpoint to write (.pt; it carries the config)")
@click.option("--epochs", type=click.IntRange(min=1), default=None, help="training epochs [default: config train.epochs]")
@click.option("--seed", type=int, default=None, help="random seed [default: config train.seed]")
@click.option("--batch-size", type=click.IntRange(min=1), default=None,
              help="mini-batch size [default: config train.batch_size]")
@click.option("--lr", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="Adam learning rate [default: config train.lr]")
@click.option("--hidden", type=click.IntRange(min=1), default=None, help="H (overrides config)")
@click.option("--layers", type=click.IntRange(min=2), default=None, help="L (overrides config)")
@click.option("--width", type=click.IntRange(min=1), default=None,
              help="intermediate layer width (overrides config; paper 40)")
@click.option("--phi-first", type=click.IntRange(min=1), default=None,
              help="width of phi's first hidden layer (overrides config; paper 25)")
@click.option("--onboard", is_flag=True,
              help="the one-tick on-board variant: intermediate widths 24, phi's first layer 16")
@click.option("--device", default="cpu", show_default=True,
              help="torch device to train on: cpu, cuda, cuda:1 ... (the checkpoint is the same format)")
@_vehicle_option
@_quiet_option
@_json_option
def train(data_paths, config_path, out, epochs, seed, batch_size, lr, hidden, layers, width, phi_first, onboard,
          device, vehicle_files, quiet, as_json):
    """Train the heterogeneous deep set; writes a checkpoint and reports the validation error."""
    from ns2codegen.checkpoint import save_checkpoint
    from ns2codegen.data.dataset import Dataset
    from ns2codegen.train import train as run

    import torch

    try:
        torch.empty(0, device=device)
    except (RuntimeError, ValueError, AssertionError) as e:   # AssertionError: torch built without CUDA
        raise click.BadParameter(f"{device!r} is not usable here ({str(e).splitlines()[0]})",
                                 param_hint="--device") from None
    cfg = _config(config_path, vehicle_files)
    overrides = dict(ONBOARD_WIDTHS) if onboard else {}
    overrides.update({k: v for k, v in (("hidden", hidden), ("layers", layers), ("width", width),
                                        ("phi_first", phi_first)) if v is not None})
    if overrides:
        cfg = cfg.with_overrides(**overrides)
    ds = Dataset.concat([Dataset.load(p, cfg.neighbor_types) for p in data_paths])
    _parent_ok(out)
    n_epochs = epochs or cfg.train["epochs"]
    total = int(len(ds) * (1 - cfg.train["validation_fraction"])) * n_epochs
    with _progress(quiet, total, "sample", "train") as update:
        model, report = run(cfg, ds, epochs=epochs, seed=seed, batch_size=batch_size, lr=lr, progress=update,
                            device=device)
    save_checkpoint(out, model, cfg, {"seed": report["seed"], "data_hash": ds.content_hash(),
                                      "data_files": [Path(p).name for p in data_paths], "report": report})
    v = report["validation"]
    result = {"checkpoint": out, "validation_mse": v["mse"], "label_variance": v["label_var"],
              "mse_per_scenario": v["mse_per_scenario"], "samples_per_second": report["samples_per_second"]}
    _emit(as_json, result,
          f"wrote {out}: validation MSE {v['mse']:.4g} g^2 (label variance {v['label_var']:.4g} g^2), "
          f"{report['samples_per_second']:.0f} samples/s\n"
          + "\n".join(f"  {name}: MSE {mse:.4g} g^2" for name, mse in v["mse_per_scenario"].items()))


@main.command()
@click.argument("checkpoint", type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="firmware/generated",
              show_default=True, help="export folder: C headers, manifest and the model's config")
@_quiet_option
@_json_option
def export(checkpoint, out_dir, quiet, as_json):
    """Export CHECKPOINT (.pt) to C headers (float + fixed point), a manifest and its config."""
    from ns2codegen.export import export as run

    with _progress(quiet, None, "step", "export (quantize, prove, measure)"):
        man = run(checkpoint, out_dir)
    err = man["fixed_vs_float_error_g"]
    result = {"out": out_dir, "model_hash": man["model_hash"], "lipschitz": man["lipschitz"]["per_neighbor_input"],
              "overflow_min_margin_bits": man["overflow_proof"]["min_margin_bits"],
              "fixed_vs_float_max_abs_g": {k: err[k]["max_abs_g"] for k in ("box", "typical")}}
    _emit(as_json, result,
          f"wrote {out_dir}: model {man['model_hash'][:16]}, Lipschitz bound "
          f"{man['lipschitz']['per_neighbor_input']:.4g} g per unit input, overflow margin "
          f"{man['overflow_proof']['min_margin_bits']} bits, |fixed-float| max "
          f"{err['box']['max_abs_g']:.3g} g (box), {err['typical']['max_abs_g']:.3g} g (typical)")


@main.command("sysid")
@click.option("--type", "type_name", required=True, help="robot type the parameters are for (config name)")
@click.option("--static", "static_csv", type=click.Path(dir_okay=False), required=True,
              help="load-cell CSV: pwm, vbat_V, force_g [, force_max_g]")
@click.option("--step", "step_csv", type=click.Path(dir_okay=False), default=None,
              help="square-wave response CSV: time_s, pwm, vbat_V, force_g (fits lambda)")
@click.option("--mass-g", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="weighed mass of the vehicle (g); also gives max_thrust_g from psi_3")
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="vehicle parameter file (.toml)")
@_json_option
def sysid(type_name, static_csv, step_csv, mass_g, out, as_json):
    """Fit psi_1, psi_2, psi_3 and lambda (Table cfprops) from load-cell data; write the
    vehicle parameter file and one plot per fit next to it."""
    from ns2codegen import sysid as sid

    static = sid.read_csv(static_csv, ("pwm", "vbat_V", "force_g"), ("force_max_g",))
    step = sid.read_csv(step_csv, ("time_s", "pwm", "vbat_V", "force_g")) if step_csv else None
    res = sid.identify(type_name, static, step, mass_g=mass_g)
    paths = sid.write_results(out, res, static, step)
    result = {"vehicle": res["vehicle"], "fit": res["sysid"], "files": [str(p) for p in paths]}
    _emit(as_json, result, f"wrote {', '.join(map(str, paths))}\n"
          + "\n".join(f"  {k} = {v}" for k, v in res["vehicle"].items()))


@main.command("logs-to-data")
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="data set to write (.npz)")
@_config_option
@_vehicle_option
@click.option("--allow-truncated", is_flag=True,
              help="use logs without a valid CRC (power loss): keep their complete entries")
@click.option("--z-min", type=float, default=0.02, show_default=True,
              help="samples below this height (m) count as on the ground and are not used")
@_json_option
def logs_to_data(folder, out, config_path, vehicle_files, allow_truncated, z_min, as_json):
    """Crazyflie uSD logs of FOLDER (listed in FOLDER/flights.toml) -> data set (.npz):
    clock alignment, common time base, labels f_a,z, neighbours by the interaction volume."""
    from ns2codegen.logs.align import logs_to_dataset

    cfg = _config(config_path, vehicle_files)
    _parent_ok(out)
    ds, reports = logs_to_dataset(cfg, folder, allow_truncated=allow_truncated, z_min=z_min)
    ds.save(out)
    _emit(as_json, {"out": out, "samples": len(ds), "scenarios": ds.scenario_names, "flights": reports},
          f"wrote {out}: {len(ds)} samples from {len(reports)} flights, scenarios {ds.scenario_names}")


# ------------------------------------------------------------------ host side
@main.command()
@click.option("--port", default=None, help="serial port of a board running the HIL image")
@click.option("--qemu", is_flag=True, help="build the HIL image and run it in qemu-system-arm (netduinoplus2)")
@_gen_option("firmware/generated")
@click.option("--queries", type=click.IntRange(min=1), default=1000, show_default=True,
              help="random queries to compare")
@click.option("--seed", type=int, default=0, show_default=True, help="seed of the random queries")
@click.option("--timeout", type=click.FloatRange(min=0.01), default=1.0, show_default=True,
              help="seconds to wait for each answer of the target")
@_quiet_option
@_json_option
def hil(port, qemu, gen_dir, queries, seed, timeout, quiet, as_json):
    """Serial hardware-in-the-loop: run random queries on the target, compare bit for bit."""
    from ns2codegen.queries import random_queries
    from ns2host import hil as hil_mod
    from ns2host import target
    from ns2host.cbuild import CModel

    if bool(port) == bool(qemu):
        raise click.UsageError("give exactly one of --port or --qemu")
    cfg = _export_config(gen_dir)
    cmodel = CModel(gen_dir)
    q = random_queries(cfg, queries, seed=seed, wild=0.05, max_given=min(20, hil_mod.MAX_NEIGHBORS))
    proc = None
    if qemu:
        proc, port = hil_mod.start_qemu(target.build_hil_image(Path(gen_dir)))
    try:
        client = hil_mod.HilClient(port, timeout=timeout)
        try:
            with _progress(quiet, queries, "query", "hil") as update:
                report = hil_mod.run(client, q, cmodel, progress=update)
        except hil_mod.HilError as e:
            raise click.ClickException(f"HIL target on {port}: {e}") from e
        finally:
            client.close()
    finally:
        if proc is not None:
            proc.kill()
    rt = report["round_trip_ms"]
    _emit(as_json, report, f"{report['queries']} queries on {port}: {report['mismatches']} differ from the host; "
          f"{report['retries']} retries" + (f", round trip median {rt['median']:.2f} ms" if rt else ""))
    if report["mismatches"]:
        raise click.ClickException(f"{report['mismatches']} of {queries} results differ from the host")


@main.group()
def sim():
    """Swarm simulator with the firmware controller in the loop."""


@sim.command("collect")
@_gen_option("firmware/generated", "export folder: the controller build, the model for --learned, and the config")
@click.option("--seconds-per-team", type=click.FloatRange(min=1.0), default=60.0, show_default=True,
              help="simulated flight time per team")
@click.option("--learned", type=click.Choice(["none", "float", "fixed"]), default="none", show_default=True,
              help="fly with the model of --gen as feed-forward (curriculum learning)")
@click.option("--seed", type=int, default=0, show_default=True, help="random seed of the flights")
@click.option("--usd-dir", type=click.Path(file_okay=False), default=None,
              help="also write every robot's log as a Crazyflie uSD file here (+ flights.toml)")
@_vehicle_option
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="data set to write (.npz)")
@_quiet_option
@_json_option
def sim_collect(gen_dir, seconds_per_team, learned, seed, usd_dir, vehicle_files, out, quiet, as_json):
    """Fly every team of 1-3 robots (random walks and swaps) and build a data set from the logs."""
    from ns2host.sim.collect import collect, teams

    cfg = _export_config(gen_dir, vehicle_files)
    _parent_ok(out)
    team_list = teams(cfg)
    with _progress(quiet, sum(1 if len(t) == 1 else 2 for t in team_list), "flight", "sim collect") as update:
        ds = collect(cfg, gen_dir, seconds_per_team, seed=seed, learned=None if learned == "none" else learned,
                     usd_dir=usd_dir, progress=update)
    ds.save(out)
    _emit(as_json, {"out": out, "samples": len(ds), "teams": len(team_list), "scenarios": ds.scenario_names},
          f"wrote {out}: {len(ds)} samples from {len(team_list)} teams, scenarios {ds.scenario_names}")


def _sim_experiment(name: str):
    """The options every simulator experiment shares: model, results folder, C path, output."""
    def deco(f):
        for opt in reversed([
                _gen_option(help="export folder of a model trained on simulated flights (and its config)"),
                click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True,
                             help=f"results folder: {name}.md, {name}.json, plots"),
                click.option("--learned", type=click.Choice(["float", "fixed"]), default="fixed", show_default=True,
                             help="which C path of the model flies the NN case"),
                _quiet_option, _json_option]):
            f = opt(f)
        return sim.command(name)(f)
    return deco


@_sim_experiment("swaps")
@click.option("--swaps", type=click.IntRange(min=1), default=6, show_default=True, help="swaps per case")
def sim_swaps(gen_dir, out_dir, swaps, learned, quiet, as_json):
    """Swap experiments S2S, L2S, SS2L, SL2S, LL2S, LL2S*: BL, BL-tuned (gain search, written to
    OUT/gain_search.json once), NN, NN-default, Mellinger; swaps.json, swaps.md and plots in OUT."""
    from ns2exp.swarm import CONTROLLERS, SWAP_CASES, swap_experiments

    cfg = _export_config(gen_dir)
    with _progress(quiet, len(SWAP_CASES) * len(CONTROLLERS), "flight", "sim swaps") as update:
        res = swap_experiments(cfg, gen_dir, out_dir, swaps=swaps, learned=learned, progress=update)
    _emit(as_json, res, (Path(out_dir) / "swaps.md").read_text())


@_sim_experiment("rings")
@click.option("--duration", type=click.FloatRange(min=4.0), default=16.0, show_default=True,
              help="simulated seconds per flight")
def sim_rings(gen_dir, out_dir, duration, learned, quiet, as_json):
    """5-robot intertwined rings and the 16-robot three rings, the controllers of `sim swaps`
    (the gain search of OUT/gain_search.json, run if missing); rings.json, rings.md in OUT."""
    from ns2exp.swarm import CONTROLLERS, RING_CASES, ring_experiments

    cfg = _export_config(gen_dir)
    with _progress(quiet, len(RING_CASES) * len(CONTROLLERS), "flight", "sim rings") as update:
        res = ring_experiments(cfg, gen_dir, out_dir, duration=duration, learned=learned, progress=update)
    _emit(as_json, res, (Path(out_dir) / "rings.md").read_text())


# ------------------------------------------------------------------ planning
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
@_quiet_option
@_json_option
def plan_cmd(checkpoint, model_dir, config_path, problem_path, baseline, out_dir, scenarios, dims, trials,
             max_samples, time_limit, quiet, as_json):
    """Interaction-aware motion planning (AO-RRT + SCP): the paper's experiments, or one problem.
    The config is the checkpoint's; --config only without a checkpoint."""
    from dataclasses import replace

    from ns2exp import planning as ex
    from ns2plan.problem import PlanningError, RRTParams, SCPParams, SearchParams

    rrt = RRTParams(SearchParams(time_s=min(SearchParams.time_s, time_limit)), total_time_s=time_limit)
    if max_samples is not None:
        rrt = replace(rrt, search=replace(rrt.search, max_samples=max_samples))
    scp_params = SCPParams(time_limit_s=time_limit)
    names = [s.strip() for s in scenarios.split(",") if s.strip()]
    unknown = [s for s in names if s not in ex.SCENARIOS]
    if unknown:
        raise click.UsageError(f"unknown scenarios {unknown}; choose from {list(ex.SCENARIOS)}")
    if checkpoint is not None and config_path is not None:
        raise click.UsageError("give --checkpoint or --config: a checkpoint carries its config")
    if problem_path and not Path(problem_path).is_file():
        raise PlanningError(f"problem file not found: {problem_path}")
    cfg = _plan_config(checkpoint, config_path)
    if problem_path:
        ex.load_problem(cfg, problem_path)  # refuse a bad file before any training
    if checkpoint is None and not (problem_path and baseline):
        folder = Path(model_dir) if model_dir else Path(out_dir) / "model"
        checkpoint = ex.default_checkpoint(cfg, folder, log=lambda msg: click.echo(msg, err=True))
        cfg = _plan_config(checkpoint, None)
    if problem_path:
        with _progress(quiet, None, "stage", "plan"):
            report = ex.plan_problem_file(cfg, problem_path, None if baseline else checkpoint, out_dir, rrt,
                                          scp_params)
        summary = {k: report[k] for k in ("valid", "timings", "robots")}
        _emit(as_json, summary, f"wrote {out_dir}: plan " + ("valid" if report["valid"] else "INVALID")
              + f", Stage 1 {report['timings']['stage1_s']:.1f} s, Stage 2 {report['timings']['stage2_s']:.1f} s")
        if not report["valid"]:
            raise click.ClickException(f"the plan violates a limit (see {out_dir}/plan.json)")
        return
    from ns2codegen.export import export as run_export

    gen = Path(out_dir) / "gen"
    run_export(checkpoint, gen)
    dim_list = (2, 3) if dims == "both" else (int(dims),)
    with _progress(quiet, len(dim_list) * len(names) * 2 * trials, "trial", "plan") as update:
        res = ex.planning_experiments(cfg, checkpoint, gen, out_dir, names, dim_list, trials, rrt, scp_params,
                                      log=lambda msg: None if quiet else click.echo(msg, err=True), progress=update)
    _emit(as_json, {k: {m: r["summary"] for m, r in v.items()} for k, v in res.items()},
          (Path(out_dir) / "plan.md").read_text())


def _plan_config(checkpoint, config_path) -> Config:
    """The checkpoint's config when one is given, else --config or the default."""
    if checkpoint is None:
        return _config(config_path)
    from ns2codegen.checkpoint import load_checkpoint

    return load_checkpoint(checkpoint).cfg


if __name__ == "__main__":
    main()
