"""`ns2` command line, the top layer: it may import every other package."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from ns2codegen.config import ONBOARD_WIDTHS, Config, ConfigError
from ns2codegen.errors import Ns2Error


class _Errors(click.Group):
    """Every expected error (``Ns2Error``) becomes one line and exit status 1."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except Ns2Error as e:
            raise click.ClickException(str(e)) from e


@click.group(cls=_Errors)
@click.version_option(package_name="ns2codegen")
def main():
    """Neural-Swarm2 deep sets: training, export to C, verification."""


def _config(path, vehicle_files=()) -> Config:
    return Config.load(path).with_vehicle_files(vehicle_files)


_vehicle_option = click.option(
    "--vehicle", "vehicle_files", type=click.Path(dir_okay=False), multiple=True,
    help="vehicle parameter file of `ns2 sysid` (replaces that robot type's parameters; repeatable)")


@main.command("gen-data")
@click.option("--kind", type=click.Choice(["downwash", "max"]), default="downwash", show_default=True,
              help="analytic downwash + ground effect, or the paper's 2-group max example")
@click.option("--samples-per-scenario", type=click.IntRange(min=1), default=2000, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--noise", type=click.FloatRange(min=0.0), default=0.0, help="label noise std (g)")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None)
@click.option("--out", type=click.Path(dir_okay=False), required=True)
def gen_data(kind, samples_per_scenario, seed, noise, config_path, out):
    """Generate an analytic training data set (.npz, format in README)."""
    from ns2codegen.data import analytic

    cfg = _config(config_path)
    if kind == "downwash":
        ds = analytic.downwash_dataset(cfg, samples_per_scenario, seed=seed, noise_g=noise)
    else:
        ds = analytic.max_dataset(cfg, samples_per_scenario, seed=seed)
    _parent_ok(out)
    ds.save(out)
    click.echo(f"wrote {out}: {len(ds)} samples, {len(ds.scenario_names)} scenarios")


def _parent_ok(path) -> None:
    from ns2codegen.fileio import OutputError

    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise OutputError(f"output folder {parent} does not exist")


@main.command()
@click.option("--data", "data_paths", type=click.Path(dir_okay=False), required=True, multiple=True,
              help="data set (.npz); repeat to train on several (e.g. curriculum rounds)")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None)
@click.option("--out", type=click.Path(dir_okay=False), required=True)
@click.option("--epochs", type=click.IntRange(min=1), default=None)
@click.option("--seed", type=int, default=None)
@click.option("--batch-size", type=click.IntRange(min=1), default=None)
@click.option("--lr", type=click.FloatRange(min=0.0, min_open=True), default=None)
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
@click.option("--quiet", is_flag=True)
def train(data_paths, config_path, out, epochs, seed, batch_size, lr, hidden, layers, width, phi_first, onboard,
          device, vehicle_files, quiet):
    """Train the heterogeneous deep set; writes a checkpoint and prints the report."""
    from tqdm import tqdm

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
    ds = Dataset.concat([Dataset.load(p) for p in data_paths])
    _parent_ok(out)
    n_epochs = epochs or cfg.train["epochs"]
    with tqdm(total=int(len(ds) * (1 - cfg.train["validation_fraction"])) * n_epochs, unit="sample",
              disable=quiet, file=sys.stderr, unit_scale=True) as bar:
        model, report = run(cfg, ds, epochs=epochs, seed=seed, batch_size=batch_size, lr=lr,
                            progress=bar.update, device=device)
    save_checkpoint(out, model, cfg, {"seed": report["seed"], "data_hash": ds.content_hash(),
                                      "data_files": [Path(p).name for p in data_paths], "report": report})
    v = report["validation"]
    click.echo(json.dumps({"checkpoint": out, "validation_mse": v["mse"], "label_variance": v["label_var"],
                           "mse_per_scenario": v["mse_per_scenario"],
                           "samples_per_second": report["samples_per_second"]}, indent=2))


@main.command()
@click.argument("checkpoint", type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="firmware/generated",
              show_default=True)
def export(checkpoint, out_dir):
    """Export CHECKPOINT to C headers (float + fixed point) and a manifest."""
    from ns2codegen.export import export as run

    man = run(checkpoint, out_dir)
    err = man["fixed_vs_float_error_g"]
    click.echo(f"wrote {out_dir}: model {man['model_hash'][:16]}, Lipschitz bound "
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
def sysid(type_name, static_csv, step_csv, mass_g, out):
    """Fit psi_1, psi_2, psi_3 and lambda (Table cfprops) from load-cell data; write the
    vehicle parameter file and one plot per fit next to it."""
    from ns2codegen import sysid as sid

    static = sid.read_csv(static_csv, ("pwm", "vbat_V", "force_g"), ("force_max_g",))
    step = sid.read_csv(step_csv, ("time_s", "pwm", "vbat_V", "force_g")) if step_csv else None
    res = sid.identify(type_name, static, step, mass_g=mass_g)
    paths = sid.write_results(out, res, static, step)
    click.echo(json.dumps({"vehicle": res["vehicle"], "fit": res["sysid"], "files": [str(p) for p in paths]},
                          indent=2))


@main.command("logs-to-data")
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), required=True)
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None)
@_vehicle_option
@click.option("--allow-truncated", is_flag=True,
              help="use logs without a valid CRC (power loss): keep their complete entries")
@click.option("--z-min", type=float, default=0.02, show_default=True,
              help="samples below this height (m) count as on the ground and are not used")
def logs_to_data(folder, out, config_path, vehicle_files, allow_truncated, z_min):
    """Crazyflie uSD logs of FOLDER (listed in FOLDER/flights.toml) -> data set (.npz):
    clock alignment, common time base, labels f_a,z, neighbours by the interaction volume."""
    from ns2codegen.logs.align import logs_to_dataset

    cfg = _config(config_path, vehicle_files)
    _parent_ok(out)
    ds, reports = logs_to_dataset(cfg, folder, allow_truncated=allow_truncated, z_min=z_min)
    ds.save(out)
    click.echo(json.dumps({"out": out, "samples": len(ds), "scenarios": ds.scenario_names, "flights": reports},
                          indent=2))


@main.command()
@click.option("--port", default=None, help="serial port of a board running the HIL image")
@click.option("--qemu", is_flag=True, help="build the HIL image and run it in qemu-system-arm (netduinoplus2)")
@click.option("--gen", "gen_dir", type=click.Path(file_okay=False), default="firmware/generated", show_default=True)
@click.option("--queries", type=click.IntRange(min=1), default=1000, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--timeout", type=click.FloatRange(min=0.01), default=1.0, show_default=True)
def hil(port, qemu, gen_dir, queries, seed, timeout):
    """Serial hardware-in-the-loop: run random queries on the target, compare bit for bit."""
    from ns2host import hil as hil_mod
    from ns2host import target
    from ns2host.cbuild import CModel

    from ns2codegen.checkpoint import CheckpointError
    from ns2codegen.queries import random_queries

    if bool(port) == bool(qemu):
        raise click.UsageError("give exactly one of --port or --qemu")
    cfg_path = Path(gen_dir) / "ns2_model_manifest.json"
    if not cfg_path.is_file():
        raise CheckpointError(f"{cfg_path} missing: run `ns2 export` first")
    cmodel = CModel(gen_dir)
    cfg = Config.load()
    q = random_queries(cfg, queries, seed=seed, wild=0.05, max_given=min(20, hil_mod.MAX_NEIGHBORS))
    proc = None
    if qemu:
        proc, port = hil_mod.start_qemu(target.build_hil_image(Path(gen_dir)))
    try:
        client = hil_mod.HilClient(port, timeout=timeout)
        try:
            report = hil_mod.run(client, q, cmodel)
        except hil_mod.HilError as e:
            raise click.ClickException(f"HIL target on {port}: {e}") from e
        finally:
            client.close()
    finally:
        if proc is not None:
            proc.kill()
    click.echo(json.dumps(report, indent=2))
    if report["mismatches"]:
        raise click.ClickException(f"{report['mismatches']} of {queries} results differ from the host")


@main.group()
def sim():
    """Swarm simulator with the firmware controller in the loop."""


@sim.command("collect")
@click.option("--gen", "gen_dir", type=click.Path(file_okay=False), default="firmware/generated", show_default=True)
@click.option("--seconds-per-team", type=click.FloatRange(min=1.0), default=60.0, show_default=True)
@click.option("--learned", type=click.Choice(["none", "float", "fixed"]), default="none", show_default=True,
              help="fly with the model of --gen as feed-forward (curriculum learning)")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--usd-dir", type=click.Path(file_okay=False), default=None,
              help="also write every robot's log as a Crazyflie uSD file here (+ flights.toml)")
@_vehicle_option
@click.option("--out", type=click.Path(dir_okay=False), required=True)
def sim_collect(gen_dir, seconds_per_team, learned, seed, usd_dir, vehicle_files, out):
    """Fly every team of 1-3 robots (random walks and swaps) and build a data set from the logs."""
    from ns2host.sim.collect import collect, teams

    cfg = _config(None, vehicle_files)
    _parent_ok(out)
    ds = collect(cfg, gen_dir, seconds_per_team, seed=seed, learned=None if learned == "none" else learned,
                 usd_dir=usd_dir)
    ds.save(out)
    click.echo(f"wrote {out}: {len(ds)} samples from {len(teams(cfg))} teams, scenarios {ds.scenario_names}")


@sim.command("swaps")
@click.option("--gen", "gen_dir", type=click.Path(file_okay=False), required=True,
              help="export folder of a model trained on simulated flights")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True)
@click.option("--swaps", type=click.IntRange(min=1), default=6, show_default=True)
@click.option("--learned", type=click.Choice(["float", "fixed"]), default="fixed", show_default=True)
def sim_swaps(gen_dir, out_dir, swaps, learned):
    """Swap experiments S2S, L2S, SS2L, SL2S, LL2S: baseline vs learned; table and plots."""
    from ns2exp.swarm import swap_experiments

    res = swap_experiments(Config.load(), gen_dir, out_dir, swaps=swaps, learned=learned)
    click.echo((Path(out_dir) / "swaps.md").read_text())
    click.echo(json.dumps({k: round(v["improvement"], 2) for k, v in res.items()}))


@sim.command("rings")
@click.option("--gen", "gen_dir", type=click.Path(file_okay=False), required=True)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True)
@click.option("--duration", type=click.FloatRange(min=4.0), default=16.0, show_default=True)
@click.option("--learned", type=click.Choice(["float", "fixed"]), default="fixed", show_default=True)
def sim_rings(gen_dir, out_dir, duration, learned):
    """5-robot intertwined rings and the 16-robot three rings: baseline vs learned."""
    from ns2exp.swarm import ring_experiments

    ring_experiments(Config.load(), gen_dir, out_dir, duration=duration, learned=learned)
    click.echo((Path(out_dir) / "rings.md").read_text())


@main.command("plan")
@click.option("--checkpoint", type=click.Path(dir_okay=False), default=None,
              help="deep set for the NN planner [default: build/plan/model.pt, trained on simulated flights if missing]")
@click.option("--problem", "problem_path", type=click.Path(dir_okay=False), default=None,
              help="plan one problem (JSON: robots, axes, limits) instead of the paper's experiments")
@click.option("--baseline", is_flag=True, help="with --problem: plan with f_a = 0 (BL)")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True)
@click.option("--scenarios", default="SL,SS,LL,SSL,SLL", show_default=True)
@click.option("--dims", type=click.Choice(["2", "3", "both"]), default="both", show_default=True)
@click.option("--trials", type=click.IntRange(min=1), default=5, show_default=True)
@click.option("--max-samples", type=click.IntRange(min=1), default=None,
              help="samples per RRT run, Stage 1's stopping rule [default: RRTParams.max_samples]")
@click.option("--time-limit", type=click.FloatRange(min=1.0), default=300.0, show_default=True,
              help="wall-clock safety net in seconds for Stage 1 and again for Stage 2, per plan (the sample and "
                   "iteration counts stop them first, so a seed gives the same plan on any machine)")
def plan_cmd(checkpoint, problem_path, baseline, out_dir, scenarios, dims, trials, max_samples, time_limit):
    """Interaction-aware motion planning (AO-RRT + SCP): the paper's experiments, or one problem."""
    from ns2exp import planning as ex
    from ns2plan.problem import PlanningError, RRTParams, SCPParams

    cfg = Config.load()
    rrt = RRTParams(total_time_s=time_limit, rrt_time_s=min(RRTParams.rrt_time_s, time_limit))
    if max_samples is not None:
        rrt = RRTParams(**{**rrt.__dict__, "max_samples": max_samples})
    scp_params = SCPParams(time_limit_s=time_limit)
    try:
        if checkpoint is None and not (problem_path and baseline):
            checkpoint = ex.default_checkpoint(cfg, Path("build/plan"), log=click.echo)
        if problem_path:
            report = ex.plan_problem_file(cfg, problem_path, None if baseline else checkpoint, out_dir, rrt, scp_params)
            click.echo(json.dumps({k: report[k] for k in ("valid", "timings", "robots")}, indent=1))
            if not report["valid"]:
                raise click.ClickException(f"the plan violates a limit (see {out_dir}/plan.json)")
            return
        names = [s.strip() for s in scenarios.split(",") if s.strip()]
        unknown = [s for s in names if s not in ex.SCENARIOS]
        if unknown:
            raise click.UsageError(f"unknown scenarios {unknown}; choose from {list(ex.SCENARIOS)}")
        from ns2codegen.export import export as run_export

        gen = Path(out_dir) / "gen"
        run_export(checkpoint, gen)
        ex.planning_experiments(cfg, checkpoint, gen, out_dir, names, (2, 3) if dims == "both" else (int(dims),),
                                trials, rrt, scp_params, log=click.echo)
        click.echo((Path(out_dir) / "plan.md").read_text())
    except PlanningError as e:
        raise click.ClickException(str(e)) from e


if __name__ == "__main__":
    main()
