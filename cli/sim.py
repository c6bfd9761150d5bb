"""`ns2 sim collect`: simulated flights (the group `ns2 sim`; its experiment commands,
swaps, rings and calibrate, are cli/simexp.py's)."""
from __future__ import annotations

import click

from .common import (
    _emit, _export_config, _gen_option, _json_option, _parent_ok, _progress,
    _quiet_option, _scheduler_option, _vehicle_option, main,
)


@main.group()
def sim():
    """Swarm simulator with the firmware controller in the loop."""


_rough_option = click.option(
    "--sim", "simulator", type=click.Choice(["rough", "clean"]), default="rough", show_default=True,
    help="rough: a real Crazyflie's unmodelled effects, fitted to the real flights (host/sim/roughness.py, "
         "`ns2 sim calibrate`); clean: without them")


def _rough(simulator: str):
    from ns2host.sim.roughness import Roughness

    return Roughness() if simulator == "rough" else None


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
@_rough_option
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="data set to write (.npz)")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="fly this many flights at once (processes; the same data set)")
@_scheduler_option
@_quiet_option
@_json_option
def sim_collect(gen_dir, seconds_per_team, learned, seed, usd_dir, vehicle_files, simulator, out, workers, quiet,
                as_json):
    """Fly every team of 1-3 robots (random walks and swaps) and build a data set from the logs."""
    from ns2host.sim.collect import collect, teams

    cfg = _export_config(gen_dir, vehicle_files)
    _parent_ok(out)
    team_list = teams(cfg)
    with _progress(quiet, sum(1 if len(t) == 1 else 2 for t in team_list), "flight", "sim collect") as update:
        ds = collect(cfg, gen_dir, seconds_per_team, seed=seed, learned=None if learned == "none" else learned,
                     usd_dir=usd_dir, progress=update, rough=_rough(simulator), workers=workers)
    ds.save(out)
    _emit(as_json, {"out": out, "samples": len(ds), "teams": len(team_list), "scenarios": ds.scenario_names},
          f"wrote {out}: {len(ds)} samples from {len(team_list)} teams, scenarios {ds.scenario_names}")
