"""uSD logs of a multi-robot flight -> one Flight on a common time base -> data set
(paper, "Data Collection": 100 Hz logs, on-board microsecond clocks synchronized
before take-off by a broadcast radio packet, clock drift negligible for < 2 min).

A folder of logs is described by ``flights.toml``::

    rate_hz = 100                     # common time base (optional, default 100)
    [[flight]]
    name = "L2S swap 1"
    robots = [{file = "cf3/log00", type = "small"}, {file = "cf7/log00", type = "large"}]

Every robot logs the ``fixedFrequency`` event with the variables of ``VARIABLES``
(config.txt of the uSD deck: ``on:fixedFrequency``, 100, 2, then the names).

The robots' clocks, the common grid and the usable pieces are timebase.py's (the
radio log's reader, radiolog.py, shares them); its names are re-exported here for
this module's importers.
"""
from __future__ import annotations

from pathlib import Path

from ..config import Config
from ..data.dataset import Dataset, DatasetError
from ..data.from_logs import Flight, flights_to_dataset
from .manifest import load_manifest
from .radiolog import radiolog_to_flights
from .timebase import (COMPRESSED, MIN_PIECE, ONBOARD_FA, PLAUSIBLE, PWM_FULL, PWM_ON, QUAT_NORM, SYNC_EVENT,
                       VARIABLES, LogError, RobotLog, align, clock_offsets, resample)
from .usdlog import UsdLogError, read

__all__ = ["COMPRESSED", "MIN_PIECE", "ONBOARD_FA", "PLAUSIBLE", "PWM_FULL", "PWM_ON", "QUAT_NORM", "SYNC_EVENT",
           "VARIABLES", "LogError", "RobotLog", "align", "clock_offsets", "resample", "logs_to_flights",
           "logs_to_dataset"]


def logs_to_flights(cfg: Config, folder: str | Path, allow_truncated: bool = False, z_min: float = 0.02,
                    max_gap_s: float = 0.05, allow_outside: bool = False) -> tuple[list[Flight], list[dict]]:
    """Every flight of ``folder/flights.toml`` -> its usable pieces; per-flight reports.
    ``allow_outside``: the manifest may name logs outside ``folder`` (manifest.py).
    ``folder`` may also be the radio log of ``ns2 fly`` (a file: radiolog.py)."""
    folder = Path(folder)
    if folder.is_file():
        flights, reports = radiolog_to_flights(cfg, folder, z_min=z_min)
        if not flights:
            raise LogError(f"{folder}: no usable flight piece in the radio log (motors off, on the ground or gaps "
                           "everywhere)")
        return flights, reports
    man = load_manifest(folder, allow_outside)
    rate = man["rate_hz"]
    flights, reports = [], []
    for k, fl in enumerate(man["flight"]):
        name = fl["name"]
        types = [r["type"] for r in fl["robots"]]
        unknown = [t for t in types if t not in cfg.robot_types]
        if unknown:
            raise LogError(f"{folder / 'flights.toml'}: flight {name!r}: robot types {unknown} are not in the "
                           f"config {cfg.robot_types}")
        robots, notes = [], []
        for r in fl["robots"]:
            log = read(r["path"], allow_truncated=allow_truncated)
            if log.note:
                notes.append(f"{r['file']}: {log.note}")
            try:
                robots.append(RobotLog.from_usd(log))
            except (LogError, UsdLogError) as e:
                raise LogError(f"{folder / r['file']}: {e}") from e
        planes = man.get("ground_plane_m", {})
        ground = [planes.get(t) for t in types] if isinstance(planes, dict) else None
        labelled = [r.get("label", True) is not False for r in fl["robots"]]
        ids = [str(r.get("id", r["file"])) for r in fl["robots"]]
        try:
            pieces, rep = align(types, robots, rate, max_gap_s=max_gap_s, z_min=z_min, ground_z=ground,
                                labelled=labelled, name=name, ids=ids)
        except LogError as e:
            raise LogError(f"{folder / 'flights.toml'}: flight {name!r}: {e}") from e
        reports.append(dict(rep, name=name, notes=notes, robots=ids,
                            not_labelled=[i for i, lab in zip(ids, labelled) if not lab]))
        flights += pieces
    if not flights:
        raise LogError("no usable flight piece in the logs (motors off, on the ground or gaps everywhere)")
    return flights, reports


def logs_to_dataset(cfg: Config, folder: str | Path, **kw) -> tuple[Dataset, list[dict]]:
    """Every flight of ``folder/flights.toml`` -> one data set (labels, neighbour sets);
    keyword arguments as ``logs_to_flights``."""
    flights, reports = logs_to_flights(cfg, folder, **kw)
    try:
        ds = flights_to_dataset(cfg, flights)
    except DatasetError as e:
        raise LogError(f"{folder}: the logs give an unusable data set: {e}") from None
    if len(ds) == 0:
        raise LogError(f"{folder}: no sample with a valid label in the logs")
    ds.extra = dict(ds.extra, generator="usd-logs", source=str(folder), flights=[r["name"] for r in reports])
    return ds, reports
