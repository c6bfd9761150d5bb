"""`ns2 swarm-params`, `ns2 flash`, `ns2 fly`: the ground side (docs/flying.md)."""
from __future__ import annotations

import click

from .common import _emit, _export_config, _json_option, main


@main.command("swarm-params")
@click.argument("export_dir", type=click.Path(file_okay=False))
@click.argument("swarm_file", type=click.Path(dir_okay=False))
@click.option("--out", type=click.Path(dir_okay=False), default=None,
              help="write the updated swarm file here [default: update SWARM_FILE in place]")
@_json_option
def swarm_params(export_dir, swarm_file, out, as_json):
    """Write the app's firmware_params (ns2.selfType, ns2type masks, ns2gain) for the export
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
