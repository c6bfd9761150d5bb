"""The flight manifest ``flights.toml`` of a folder of uSD logs (docs/flights.md,
docs/inputs.md)::

    rate_hz = 100                     # common time base (optional, default 100)
    [[flight]]
    name = "L2S swap 1"               # optional, default "flight <k>"
    robots = [{file = "cf3/log00", type = "small"}, {file = "cf7/log00", type = "large"}]

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
TOP_KEYS = ("rate_hz", "flight")
FLIGHT_KEYS = ("name", "robots")
ROBOT_KEYS = ("file", "type")


class ManifestError(Ns2Error, ValueError):
    """A flight manifest that cannot be used."""


def _known(d: dict, where: str, known) -> None:
    unknown = [k for k in d if k not in known]
    if unknown:
        raise ManifestError(f"{where}{unknown[0]}: unknown key (known: {', '.join(known)})")


def load_manifest(folder: str | Path, allow_outside: bool = False) -> dict:
    """``folder/flights.toml`` checked and normalized: ``{"rate_hz": float, "flight":
    [{"name": str, "robots": [{"file": str, "path": Path (resolved), "type": str}, ...]}, ...]}``.
    ``allow_outside``: log paths may leave the folder (absolute, ``..``, links)."""
    folder = Path(folder)
    path = folder / MANIFEST
    man = read_toml(path, "flight list (the flights and each robot's log file and type)", ManifestError)
    _known(man, f"{path}: ", TOP_KEYS)
    rate = man.get("rate_hz", 100.0)
    if not (isinstance(rate, (int, float)) and not isinstance(rate, bool) and math.isfinite(rate)
            and 0 < rate <= MAX_RATE_HZ):
        raise ManifestError(f"{path}: rate_hz must be a number in (0, {MAX_RATE_HZ:g}] Hz, got {brief(rate)}")
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
        if not (isinstance(name, str) and 0 < len(name) <= 200 and name.isprintable()):
            raise ManifestError(f"{where}.name must be a printable string of 1 to 200 characters, got {brief(name)}")
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
            for key in ROBOT_KEYS:
                if not (isinstance(r.get(key), str) and r[key] and r[key].isprintable()):
                    raise ManifestError(f"{rw}.{key} must be a non-empty printable string, got {brief(r.get(key))}")
            file = (folder / r["file"]).resolve()
            if not allow_outside and not file.is_relative_to(root):
                raise ManifestError(f"{rw}.file {brief(r['file'])} is outside the folder {folder} "
                                    "(logs-to-data --allow-outside-paths reads it anyway)")
            if file in seen:
                raise ManifestError(f"{rw}.file {brief(r['file'])} is also robots[{seen[file]}] of this flight: "
                                    "one log file per robot")
            seen[file] = i
            entries.append({"file": r["file"], "path": file, "type": r["type"]})
        out.append({"name": name, "robots": entries})
    return {"rate_hz": float(rate), "flight": out}
