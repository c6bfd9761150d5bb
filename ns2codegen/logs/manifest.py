"""The flight manifest ``flights.toml`` of a folder of uSD logs (docs/flights.md,
docs/inputs.md)::

    rate_hz = 100                     # common time base (optional, default 100)
    [ground_plane_m]                  # optional: z of a robot of each type standing on the floor
    small = 0.03
    [[flight]]
    name = "L2S swap 1"               # optional, default "flight <k>"
    scenario = "L2S"                  # optional
    robots = [{file = "cf3/log00", type = "small", id = "cf3"},           # id: optional, default file
              {file = "cf7/log00", type = "large", label = false}]       # label: optional, default true

Checked here, before any log is read: known keys only, every value of its type,
rate_hz in (0, MAX_RATE_HZ], at least one flight and one robot per flight, each
log file at most once per flight, and every path inside the manifest's folder
(relative, no ``..`` out of it, no symbolic link out of it) unless the caller
allows other paths.  Every error is one line naming the file and the field.
"""
from __future__ import annotations

import math
from pathlib import Path

from ..config import brief, read_toml
from ..errors import Ns2Error

MANIFEST = "flights.toml"
MAX_RATE_HZ = 1000.0
TOP_KEYS = ("rate_hz", "ground_plane_m", "flight")
FLIGHT_KEYS = ("name", "scenario", "robots")
ROBOT_KEYS = ("file", "type", "id", "label")
MAX_GROUND_M = 100.0


class ManifestError(Ns2Error, ValueError):
    """A flight manifest that cannot be used."""


def _known(d: dict, where: str, known) -> None:
    unknown = [k for k in d if k not in known]
    if unknown:
        raise ManifestError(f"{where}{unknown[0]}: unknown key (known: {', '.join(known)})")


def _text(value, most: int = 200) -> bool:
    return isinstance(value, str) and 0 < len(value) <= most and value.isprintable()


def load_manifest(folder: str | Path, allow_outside: bool = False) -> dict:
    """``folder/flights.toml`` checked and normalized: ``{"rate_hz": float,
    "ground_plane_m": {type: float}, "flight": [{"name": str, ["scenario": str,]
    "robots": [{"file": str, "path": Path (resolved), "type": str, ["id": str,]
    ["label": bool]}, ...]}, ...]}``.
    ``allow_outside``: log paths may leave the folder (absolute, ``..``, links)."""
    folder = Path(folder)
    path = folder / MANIFEST
    man = read_toml(path, "flight list (the flights and each robot's log file and type)", ManifestError)
    _known(man, f"{path}: ", TOP_KEYS)
    rate = man.get("rate_hz", 100.0)
    if not (isinstance(rate, (int, float)) and not isinstance(rate, bool) and math.isfinite(rate)
            and 0 < rate <= MAX_RATE_HZ):
        raise ManifestError(f"{path}: rate_hz must be a number in (0, {MAX_RATE_HZ:g}] Hz, got {brief(rate)}")
    planes = man.get("ground_plane_m", {})
    if not isinstance(planes, dict):
        raise ManifestError(f"{path}: ground_plane_m must be a table (robot type = z in m), got {brief(planes)}")
    for t, z in planes.items():
        if not (isinstance(z, (int, float)) and not isinstance(z, bool) and math.isfinite(z)
                and abs(z) <= MAX_GROUND_M):
            raise ManifestError(f"{path}: ground_plane_m.{t} must be a number in [-{MAX_GROUND_M:g}, "
                                f"{MAX_GROUND_M:g}] m, got {brief(z)}")
    flights = man.get("flight")
    if not (isinstance(flights, list) and flights):
        raise ManifestError(f"{path}: flight must be a non-empty array of tables ([[flight]]), got {brief(flights)}")
    root = folder.resolve()
    out = []
    for k, fl in enumerate(flights):
        where = f"{path}: flight[{k}]"
        if not isinstance(fl, dict):
            raise ManifestError(f"{where} must be a table ([[flight]]), got {brief(fl)}")
        _known(fl, where + ".", FLIGHT_KEYS)
        name = fl.get("name", f"flight {k}")
        for key, value in (("name", name), ("scenario", fl.get("scenario", "-"))):
            if not _text(value):
                raise ManifestError(f"{where}.{key} must be a printable string of 1 to 200 characters, "
                                    f"got {brief(value)}")
        robots = fl.get("robots")
        if not (isinstance(robots, list) and robots):
            raise ManifestError(f"{where}.robots must be a non-empty array [{{file = ..., type = ...}}, ...], "
                                f"got {brief(robots)}")
        seen: dict[Path, int] = {}
        entries = []
        for i, r in enumerate(robots):
            rw = f"{where}.robots[{i}]"
            if not isinstance(r, dict):
                raise ManifestError(f"{rw} must be a table {{file = ..., type = ...}}, got {brief(r)}")
            _known(r, rw + ".", ROBOT_KEYS)
            for key in ("file", "type", "id"):
                if (key in r or key != "id") and not _text(r.get(key), 4096):
                    raise ManifestError(f"{rw}.{key} must be a non-empty printable string, got {brief(r.get(key))}")
            if not isinstance(r.get("label", True), bool):
                raise ManifestError(f"{rw}.label must be true or false, got {brief(r['label'])}")
            file = (folder / r["file"]).resolve()
            if not allow_outside and not file.is_relative_to(root):
                raise ManifestError(f"{rw}.file {brief(r['file'])} is outside the folder {folder} "
                                    "(logs-to-data --allow-outside-paths reads it anyway)")
            if file in seen:
                raise ManifestError(f"{rw}.file {brief(r['file'])} is also robots[{seen[file]}] of this flight: "
                                    "one log file per robot")
            seen[file] = i
            entries.append(dict(r, path=file))
        ids = [str(r.get("id", r["file"])) for r in entries]
        if len(set(ids)) != len(ids):
            raise ManifestError(f"{where}.robots: the robot id {next(i for i in ids if ids.count(i) > 1)!r} is "
                                "given twice: one id per robot")
        out.append(dict(fl, name=name, robots=entries))
    return {"rate_hz": float(rate), "ground_plane_m": {t: float(z) for t, z in planes.items()}, "flight": out}
