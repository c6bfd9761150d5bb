"""`ns2 sim swaps|rings|adapt|calibrate`: the paper's swap and ring experiments and the
simulator's calibration against the real flights (ns2exp), on the group `ns2 sim`."""
from __future__ import annotations

from pathlib import Path

import click

from .common import _emit, _export_config, _gen_option, _json_option, _progress, _quiet_option, _scheduler_option
from .sim import _rough, _rough_option, sim

# BL-tuned's gains of the committed gain search (make sim's, docs/simulator.md)
GAIN_SEARCH = Path(__file__).resolve().parents[1] / "docs" / "results" / "runs" / "sim" / "gain_search.json"


def _sim_experiment(name: str):
    """The options every simulator experiment shares: model, results folder, C path, output."""
    def deco(f):
        for opt in reversed([
                _gen_option(help="export folder of a model trained on simulated flights (and its config)"),
                click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True,
                             help=f"results folder: {name}.md, {name}.json, plots"),
                click.option("--learned", type=click.Choice(["float", "fixed"]), default="fixed", show_default=True,
                             help="which C path of the model flies the NN case"),
                _rough_option, _quiet_option, _json_option]):
            f = opt(f)
        return sim.command(name)(f)
    return deco


@_sim_experiment("swaps")
@click.option("--swaps", type=click.IntRange(min=1), default=6, show_default=True, help="swaps per case")
def sim_swaps(gen_dir, out_dir, swaps, learned, simulator, quiet, as_json):
    """Swap experiments S2S, L2S, SS2L, SL2S, LL2S, LL2S*: BL, BL-tuned (gain search, written to
    OUT/gain_search.json once), NN, NN-default, Mellinger; swaps.json, swaps.md and plots in OUT."""
    from ns2exp.swarm import CONTROLLERS, SWAP_CASES, swap_experiments

    cfg = _export_config(gen_dir)
    with _progress(quiet, len(SWAP_CASES) * len(CONTROLLERS), "flight", "sim swaps") as update:
        res = swap_experiments(cfg, gen_dir, out_dir, swaps=swaps, learned=learned, progress=update,
                               rough=_rough(simulator))
    _emit(as_json, res, (Path(out_dir) / "swaps.md").read_text())


@_sim_experiment("rings")
@click.option("--duration", type=click.FloatRange(min=4.0), default=None,
              help="simulated seconds per flight  [default: 13: 2 s of hover, the authors' 10 s of rings, 1 s]")
def sim_rings(gen_dir, out_dir, duration, learned, simulator, quiet, as_json):
    """5-robot intertwined rings and the 16-robot three rings, the controllers of `sim swaps`
    (the gain search of OUT/gain_search.json, run if missing); rings.json, rings.md in OUT."""
    from ns2exp.swarm import CONTROLLERS, RING_CASES, RING_DURATION_S, ring_experiments

    cfg = _export_config(gen_dir)
    with _progress(quiet, len(RING_CASES) * len(CONTROLLERS), "flight", "sim rings") as update:
        res = ring_experiments(cfg, gen_dir, out_dir, duration=duration or RING_DURATION_S, learned=learned,
                               progress=update, rough=_rough(simulator))
    _emit(as_json, res, (Path(out_dir) / "rings.md").read_text())


@_sim_experiment("adapt")
@click.option("--tuning", "tuning_file", type=click.Path(dir_okay=False), default=None,
              help="BL-tuned's gains: the \"tuning\" of a gain search (`ns2 sim swaps`' gain_search.json)  "
              "[default: the checkout's docs/results/runs/sim/gain_search.json, make sim's]")
@click.option("--swaps", type=click.IntRange(min=1), default=6, show_default=True, help="swaps per flight")
@click.option("--seed", "seeds", type=int, multiple=True, default=(0, 1, 2), show_default=True,
              help="seeds of the swap and ring flights (repeat)")
@click.option("--case", "cases", type=click.Choice(["S2S", "L2S", "SS2L", "SL2S", "LL2S", "LL2S*"]), multiple=True,
              default=("S2S", "L2S"), show_default=True, help="swap cases (repeat)")
@click.option("--rings/--no-rings", default=True, show_default=True, help="the 5-robot rings too")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="fly this many flights at once (processes)")
@click.option("--composite", "track_gains", type=click.FloatRange(min=0.0, min_open=True, max=1e6), multiple=True,
              help="also fly NN+adapt with Neural-Fly's composite law at this ns2adapt.trackGain (g/(m/s)/s at P = 1; "
              "repeat)")
@click.option("--baselines/--no-baselines", default=True, show_default=True,
              help="fly BL-tuned too (NN and NN+adapt are always flown)")
def sim_adapt(gen_dir, out_dir, learned, simulator, quiet, as_json, tuning_file, swaps, seeds, cases, rings, workers,
              track_gains, baselines):
    """The on-board adaptation judged in flight (issue 53 item 5): the swaps (plain, and
    after the bottom robot hovered alone) with the bottom robot carrying an unmodelled 3 g,
    the 5-robot rings with one small robot carrying it, and S2S swaps with the supply falling
    to the low-battery voltage; BL-tuned, NN, NN+adapt (and the composite law's arms of
    --composite); adapt.json and adapt.md in OUT."""
    import json

    from ns2exp.simadapt import controllers, experiment, jobs

    _export_config(gen_dir)
    tuning_file = Path(tuning_file) if tuning_file else GAIN_SEARCH
    if not tuning_file.is_file():
        raise click.ClickException(f"{tuning_file}: no such file (--tuning, a gain search's gain_search.json)")
    tuning = json.loads(tuning_file.read_text()).get("tuning")
    if not isinstance(tuning, dict):
        raise click.ClickException(f"{tuning_file}: no \"tuning\" mapping of a gain search")
    kw = {"seeds": seeds, "swaps": swaps, "learned": learned, "rough": _rough(simulator), "cases": cases,
          "rings": ["5-robot rings"] if rings else [], "battery_seeds": (seeds[0],),
          "arms": controllers(track_gains, baselines)}
    with _progress(quiet, len(jobs(gen_dir, tuning, **kw)), "flight", "sim adapt") as update:
        res = experiment(gen_dir, out_dir, tuning, workers=workers, progress=update, **kw)
    _emit(as_json, res, (Path(out_dir) / "adapt.md").read_text())


@sim.command("calibrate")
@click.option("--logs", "logs_dir", type=click.Path(file_okay=False), default="build/neural-swarm-data",
              show_default=True, help="the unpacked real collection with its flights.toml (`ns2 real data`)")
@click.option("--data-dir", type=click.Path(file_okay=False), default="build/real", show_default=True,
              help="`ns2 real data`'s folder: real.toml (hover masses) and data_report.json (hover per robot)")
@_gen_option("build/real/authors-gen", "export of the network that flew the real flights (the authors', "
             "`ns2 real import-authors` + `ns2 export`): in the loop of the replays")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="build/sim/calibration",
              show_default=True, help="calibration.json, calibration.md and the fitted parameter files rough.toml and "
              "read_law.toml (host/sim/params/ and paper/params/' form)")
@click.option("--per-scenario", type=click.IntRange(min=1), default=None,
              help="replay only the first N flights of each swap scenario (default: every swap flight)")
@click.option("--refit/--no-refit", default=True, show_default=True,
              help="fit the roughness and the z law again (else compare with host/sim/params/rough.toml and "
                   "paper/params/read_law.toml)")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="replay this many flights at once (processes)")
@_scheduler_option
@_quiet_option
@_json_option
def sim_calibrate(logs_dir, data_dir, gen_dir, out_dir, per_scenario, refit, workers, quiet, as_json):
    """Measure the real flights' roughness, fit host/sim/roughness.py to it, replay the real
    swaps in the clean and the rough simulator: the calibration and sim-to-real tables, and
    the fitted parameter files (copy them over host/sim/params/rough.toml and
    paper/params/read_law.toml to adopt the fit)."""
    from ns2codegen.logs.align import logs_to_flights
    from ns2codegen.results import command_line
    from ns2exp.calibrate import calibrate, first_per_folder, swap_flights
    from ns2exp.real import collection_config
    from ns2paper.replay import pieces_by_flight
    from ns2host.sim.roughness import Roughness

    cfg, hover = collection_config(data_dir)    # 16 June 2020 as that day weighed its robots
    if not (Path(logs_dir) / "flights.toml").is_file():
        raise click.ClickException(f"{Path(logs_dir) / 'flights.toml'} missing: run `ns2 real data` first")
    flights, _ = logs_to_flights(cfg, logs_dir)
    type_of = {rid: t for fl in flights for rid, t in zip(fl.robots, fl.types)}
    names = None
    if per_scenario is not None:
        names = first_per_folder(pieces_by_flight(swap_flights(flights)), per_scenario)
    res = calibrate(cfg, gen_dir, flights, hover, type_of, out_dir, workers=workers, names=names,
                    rough=None if refit else Roughness(), command=command_line())
    _emit(as_json, res, (Path(out_dir) / "calibration.md").read_text())
