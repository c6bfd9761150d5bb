"""`ns2 hil`: the library on a board or in QEMU, compared with the host bit for bit."""
from __future__ import annotations

from pathlib import Path

import click

from .common import (
    _emit, _export_config, _gen_option, _json_option, _progress,
    _quiet_option, main,
)


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
