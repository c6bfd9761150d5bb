"""`ns2 sysid`, `ns2 logs-to-data`: real Crazyflies (load cell, uSD logs) to vehicle files and data."""
from __future__ import annotations


import click

from .common import (
    _config, _config_option, _emit, _json_option, _parent_ok, _vehicle_option, main,
)


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
@click.argument("folder", type=click.Path())
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="data set to write (.npz)")
@_config_option
@_vehicle_option
@click.option("--allow-truncated", is_flag=True,
              help="use logs without a valid CRC (power loss): keep their complete entries")
@click.option("--z-min", type=float, default=0.02, show_default=True,
              help="samples below this height (m) count as on the ground and are not used")
@click.option("--allow-outside-paths", is_flag=True,
              help="let flights.toml name log files outside FOLDER (absolute paths, '..', links)")
@_json_option
def logs_to_data(folder, out, config_path, vehicle_files, allow_truncated, z_min, allow_outside_paths, as_json):
    """Crazyflie uSD logs of FOLDER (listed in FOLDER/flights.toml), or the radio log of
    ns2 fly (a .jsonl file) -> data set (.npz): clock alignment, common time base, labels
    f_a,z, neighbours by the interaction volume."""
    from ns2codegen.logs.align import logs_to_dataset

    cfg = _config(config_path, vehicle_files)
    _parent_ok(out)
    ds, reports = logs_to_dataset(cfg, folder, allow_truncated=allow_truncated, z_min=z_min,
                                  allow_outside=allow_outside_paths)
    ds.save(out)
    _emit(as_json, {"out": out, "samples": len(ds), "scenarios": ds.scenario_names, "flights": reports},
          f"wrote {out}: {len(ds)} samples from {len(reports)} flights, scenarios {ds.scenario_names}")
