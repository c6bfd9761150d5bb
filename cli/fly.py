"""`ns2 swarm-params`, `ns2 flash`, `ns2 fly`: the ground side (docs/flying.md)."""
from __future__ import annotations

import click

from .common import _emit, _export_config, _json_option, _parent_ok, main


def _live() -> bool:
    """Live lines (progress, per-robot status) only on a terminal, as the progress bars."""
    import sys

    return sys.stderr.isatty()


@main.command("swarm-params")
@click.argument("export_dir", type=click.Path(file_okay=False))
@click.argument("swarm_file", type=click.Path(dir_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), default=None,
              help="write the updated swarm file here [default: update SWARM_FILE in place]")
@_json_option
def swarm_params(export_dir, swarm_file, out, as_json):
    """Write the app's firmware_params (ns2.selfType, the ns2type type table, ns2gain) for the export
    EXPORT_DIR into every robot of SWARM_FILE (Crazyswarm2's crazyflies.yaml); the rest of
    the file (comments, order, other keys) stays as it was."""
    from ns2ground import swarm as sw

    cfg = _export_config(export_dir)
    s = sw.write_params(swarm_file, cfg, out)
    result = {"out": str(out or swarm_file),
              "robots": {r.name: {"ns2_type": r.ns2_type, "radio_id": r.radio_id,
                                  **{g: dict(r.firmware_params[g]) for g in sw.GROUPS}} for r in s.robots}}
    _emit(as_json, result, f"wrote {out or swarm_file}: parameters of {len(s.robots)} robots "
          f"({', '.join(f'{r.name}={r.ns2_type}' for r in s.robots)})")


@main.command("fly")
@click.argument("export_dir", type=click.Path(file_okay=False))
@click.argument("swarm_file", type=click.Path(dir_okay=False))
@click.option("--plan", "plan_dir", type=click.Path(file_okay=False), required=True,
              help="the planner's folder (<name>.bin per robot, or ns2 plan's robot<i>_<type>.bin in order)")
@click.option("--log", "log_path", type=click.Path(dir_okay=False), required=True,
              help="flight log to append to (JSON lines: every log packet of every robot)")
@click.option("--height", type=click.FloatRange(min=0.1, max=2.0), default=0.5, show_default=True,
              help="take-off height (m)")
@click.option("--takeoff-s", type=click.FloatRange(min=0.0, min_open=True), default=2.5, show_default=True,
              help="time to climb to each plan's first point (s)")
@click.option("--land-s", type=click.FloatRange(min=0.0, min_open=True), default=2.5, show_default=True,
              help="time to descend at the end or on a safety stop (s)")
@click.option("--min-battery", type=float, default=3.3, show_default=True, help="land everyone below this (V)")
@click.option("--sim", is_flag=True, help="dry run: the same mission in the simulator (no radio); also writes "
              "the robots' uSD logs (flights.toml, for ns2 logs-to-data) into LOG's folder, <stem>-usd/")
@click.option("--seed", type=int, default=0, show_default=True, help="with --sim: the simulator's noise")
@click.option("--sim-fault", "sim_faults", multiple=True, metavar="KIND[:ROBOT]@SECONDS",
              help="with --sim: a fault at SECONDS after take-off, to rehearse the safety paths: lost-link:ROBOT, "
              "low-battery:ROBOT, app-status:ROBOT, ctrl-c (repeatable)")
@_json_option
def fly(export_dir, swarm_file, plan_dir, log_path, height, takeoff_s, land_s, min_battery, sim, seed, sim_faults,
        as_json):
    """Fly the plan with every enabled robot of SWARM_FILE (cflib): the model fingerprint of
    EXPORT_DIR checked on every robot first, parameters, ns2.sync, trajectories uploaded,
    take off, start together, land (docs/flying.md)."""
    from ns2ground import cf, mission
    from ns2ground import swarm as sw

    if sim_faults and not sim:
        raise click.UsageError("--sim-fault rehearses a dry run: give --sim")
    cfg = _export_config(export_dir)
    s = sw.load(swarm_file, cfg)
    plans = mission.plans_for(s, plan_dir)
    settings = mission.Settings(height, takeoff_s, land_s, min_battery)

    links = {}

    def status(last):
        line = "  ".join(f"{n}: link {getattr(links.get(n), 'quality', float('nan')):.0f}% "
                         f"{v.get('pm.vbat', float('nan')):.2f} V faHat {v.get('ns2.faHat', float('nan')):+.1f} g "
                         f"e {v.get('ns2.ez', float('nan')):+.3f} m" for n, v in sorted(last.items()))
        click.echo("\r" + line, nl=False, err=True)

    _parent_ok(log_path)
    if sim:
        _dry_run(s, cfg, export_dir, plans, log_path, settings, sim_faults, seed, as_json)
        return
    swarm, opened = cf.open_swarm({r.name: r.uri for r in s.enabled})
    links.update(opened)
    try:
        rep = mission.fly(links, s, cfg, export_dir, plans, log_path, settings, status if _live() else None)
    finally:
        swarm.close_links()
    if _live():
        click.echo("", err=True)
    _emit(as_json, rep, f"flew {len(links)} robots ({', '.join(links)}): log {log_path}")


def _dry_run(s, cfg, export_dir, plans, log_path, settings, sim_faults, seed, as_json):
    """``ns2 fly --sim``: the mission against simulated robots flown in step with it
    (ns2ground.sim); the landing after an abort is flown to its end and logged."""
    import signal
    from pathlib import Path

    from ns2ground import mission
    from ns2ground.sim import Fault, SimSwarm

    try:
        faults = [Fault.parse(f, [r.name for r in s.enabled]) for f in sim_faults]
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--sim-fault") from None
    dry = SimSwarm(s, export_dir, cfg, faults, seed)
    rec = mission.Recorder(log_path, dry.clock)
    usd = Path(log_path).with_name(Path(log_path).stem + "-usd")
    aborted = None
    ctrl_c = signal.signal(signal.SIGINT, lambda *_: setattr(dry.clock, "interrupt", True))   # at the next wait
    try:
        rep = mission.fly(dry.robots, s, cfg, export_dir, plans, log_path, settings, clock=dry.clock, recorder=rec)
    except mission.Abort as e:
        aborted = e
    finally:
        signal.signal(signal.SIGINT, ctrl_c)
        try:
            flown = dry.finish(usd)
        finally:
            rec.close()
    if aborted is not None:
        raise mission.Abort(f"{aborted} (dry run: uSD logs {usd})") from aborted
    rep.update(usd=str(usd), samples=len(flown["t"]), simulated_s=float(flown["t"][-1]))
    _emit(as_json, rep, f"flew {len(dry.robots)} simulated robots ({', '.join(dry.robots)}): log {log_path}, "
          f"uSD logs {usd}")


@main.command("flash")
@click.argument("image", type=click.Path(dir_okay=False), default="build/app/cf2.bin")
@click.option("--uri", default=None, help="one robot, e.g. radio://0/80/2M/E7E7E7E701")
@click.option("--swarm", "swarm_file", type=click.Path(dir_okay=False), default=None,
              help="every enabled robot of this Crazyswarm2 crazyflies.yaml")
@_json_option
def flash_cmd(image, uri, swarm_file, as_json):
    """Write IMAGE (default build/app/cf2.bin) to one robot or a swarm through cflib's
    bootloader, one robot after the other; say which robots failed and why."""
    from ns2ground import flash
    from ns2ground.swarm import SwarmFileError, radio_id, read_robots

    if (uri is None) == (swarm_file is None):
        raise click.UsageError("give --uri or --swarm")
    if uri is not None:
        try:
            radio_id(uri)
        except ValueError as e:
            raise SwarmFileError(f"--uri {uri}: {e}") from None
        robots = {uri: uri}
    else:
        robots = read_robots(swarm_file)

    def progress(name, msg, pct):
        click.echo(f"\r{name}: {msg} {pct:3d}%", nl=False, err=True)

    result = flash.flash(image, robots, progress if _live() else None)
    if _live():
        click.echo("", err=True)
    failed = {n: why for n, why in result.items() if why is not None}
    _emit(as_json, {"image": image, "robots": result},
          "\n".join(f"{n}: {'flashed' if why is None else 'FAILED: ' + why}" for n, why in result.items()))
    if failed:
        raise flash.FlashError(f"{len(failed)} of {len(result)} robots not flashed: "
                               + "; ".join(f"{n}: {why}" for n, why in failed.items()))
