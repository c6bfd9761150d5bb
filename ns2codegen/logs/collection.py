"""The Neural-Swarm2 authors' data collection of 16 June 2020
(``training/datacollection21_06_16_2020`` of aerorobotics/neural-swarm, in
``../shared/neural-swarm-data``) described as a ``flights.toml``.

Facts from the collection's ``readme.txt``: cf50, cf51, cf52 are small robots
(Crazyflie 2.1), cf101, cf102 large ones (Crazyflie 2.1 on a larger frame), cf100 a
large Crazyflie 2.0 with the old IMU whose own force estimates must not be used:
it is a neighbour, never labelled.  The ground plane (the z of a robot standing on
the floor) is 0.05 m for small and 0.06 m for large robots.  One folder per
scenario (``swap_sl``, ``randomwalk_ssl``, ``takeoff_s``, ...); the file
``cf<id>_<nn>`` is robot cf<id> in flight nn; the files of one folder with the same
nn were flown together (take-off folders: every file is a flight of its own, the
readme: "run with different drones").
"""
from __future__ import annotations

import re
from pathlib import Path

from ..errors import Ns2Error
from ..fileio import atomic_write_bytes

ROBOT_TYPES = {"cf50": "small", "cf51": "small", "cf52": "small",
               "cf100": "large", "cf101": "large", "cf102": "large"}
NOT_LABELLED = {"cf100": "Crazyflie 2.0 with the old IMU (readme: do not use its force estimates)"}
GROUND_PLANE_M = {"small": 0.05, "large": 0.06}
COLLECTION = "training/datacollection21_06_16_2020"
_FILE = re.compile(r"^(cf\d+)_(\d+)$")


class CollectionError(Ns2Error, ValueError):
    """The folder is not the 16 June 2020 collection as expected."""


def flights(root: str | Path) -> list[dict]:
    """Every flight of the collection under ``root`` (the folder the tarballs were
    unpacked into), in a fixed order: scenario folder, flight number."""
    base = Path(root) / COLLECTION
    if not base.is_dir():
        raise CollectionError(f"{base}: not found (unpack ../shared/neural-swarm-data/*.tar.xz into {root})")
    out = []
    for folder in sorted(p for p in base.iterdir() if p.is_dir()):
        groups: dict[str, list[str]] = {}
        for f in sorted(folder.iterdir()):
            m = _FILE.match(f.name)
            if not m:
                continue
            if m.group(1) not in ROBOT_TYPES:
                raise CollectionError(f"{f}: robot {m.group(1)} is not one of the collection's {sorted(ROBOT_TYPES)}")
            key = f.name if folder.name.startswith("takeoff") else m.group(2)
            groups.setdefault(key, []).append(m.group(1))
        for key in sorted(groups):
            robots = sorted(groups[key], key=lambda r: int(r[2:]))
            number = key.split("_")[-1]
            out.append({"name": f"{folder.name}/{key}", "scenario": folder.name, "number": number,
                        "robots": [{"id": r, "file": f"{COLLECTION}/{folder.name}/{r}_{number}",
                                    "type": ROBOT_TYPES[r], "label": r not in NOT_LABELLED} for r in robots]})
    if not out:
        raise CollectionError(f"{base}: no flight logs found")
    return out


def manifest_text(root: str | Path) -> str:
    """``flights.toml`` of the collection (deterministic)."""
    lines = ["# The Neural-Swarm2 authors' collection of 16 June 2020 (ns2codegen.logs.collection)",
             "rate_hz = 100", "",
             "[ground_plane_m]   # z of a robot standing on the floor (collection readme)"]
    lines += [f"{t} = {z}" for t, z in GROUND_PLANE_M.items()]
    for fl in flights(root):
        lines += ["", "[[flight]]", f'name = "{fl["name"]}"', f'scenario = "{fl["scenario"]}"', "robots = ["]
        for r in fl["robots"]:
            lines.append(f'  {{file = "{r["file"]}", type = "{r["type"]}", id = "{r["id"]}"'
                         + ("" if r["label"] else ", label = false") + "},")
        lines.append("]")
    return "\n".join(lines) + "\n"


def write_manifest(root: str | Path) -> Path:
    path = Path(root) / "flights.toml"
    atomic_write_bytes(path, manifest_text(root).encode())
    return path
