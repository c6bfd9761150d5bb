"""What every command shares: the ``ns2`` group, its error handling, the common options
and the one way of reporting (text or ``--json``) and showing progress."""
from __future__ import annotations

import json
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path

import click

from ns2codegen.config import Config
from ns2codegen.errors import Ns2Error, Ns2Warning

# the extra that installs a module the core does not need (pyproject.toml)
_EXTRAS = {"scipy": "sysid", "matplotlib": "sim", "cffi": "target", "unicorn": "target", "capstone": "target",
           "elftools": "target", "serial": "target", "cvxpy": "plan", "clarabel": "plan", "cflib": "fly",
           "ruamel": "fly"}
_COMMAND_EXTRAS = {"sysid": "sysid", "hil": "target", "sim": "sim", "plan": "plan"}


class _Errors(click.Group):
    """Every expected error (``Ns2Error``) becomes one line and exit status 1, and so
    does a missing optional dependency (it names the extra to install)."""

    def invoke(self, ctx):
        shown = warnings.showwarning

        def show(message, category, *args, **kw):  # our warnings: one line, like errors
            if issubclass(category, Ns2Warning):
                click.echo(f"Warning: {' '.join(str(message).split())}", err=True)
            else:
                shown(message, category, *args, **kw)

        try:
            with warnings.catch_warnings():
                warnings.showwarning = show
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


def _set_scheduler(ctx, param, value):
    if value is not None:
        from ns2codegen.executor import use_scheduler

        use_scheduler(value)
    return value


def _scheduler_option(f):
    return click.option("--scheduler", default=None, expose_value=False, callback=_set_scheduler,
                        metavar="ADDRESS",
                        help="run the jobs (trials, flights, replays) on the workers of this Dask scheduler "
                             "(tcp://host:8786), or 'local-cluster' for a Dask cluster of --workers processes "
                             "here; sets NS2_SCHEDULER [default: NS2_SCHEDULER, else forked processes here]")(f)


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
