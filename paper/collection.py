"""The Neural-Swarm2 authors' data collections (``training/`` of aerorobotics/neural-swarm,
in ``../shared/neural-swarm-data``) described as ``flights.toml`` manifests.

Three collections, each a unit of the blind splits (``COLLECTIONS``, by date):

* ``2019-12-11`` (``datacollection19_12_11_2019``): swaps and random walks of two robots;
* ``2019-12-20`` (``datacollection20_12_20_2019``): three robots, and one robot over the
  ground (random walks, take-off and landing);
* ``2020-06-16`` (``datacollection21_06_16_2020``): one to three robots, the paper's swaps.

Facts from the collections' ``readme.txt``: cf50, cf51, cf52 are small robots (Crazyflie
2.1), cf101, cf102 large ones (Crazyflie 2.1 on a larger frame), cf100 (2020 only) a large
Crazyflie 2.0 with the old IMU whose own force estimates must not be used: it is a
neighbour, never labelled.  The ground plane (the z of a robot standing on the floor) is
0.05 m for small and 0.06 m for large robots.  One folder per scenario; the file
``cf<id>_<nn>`` is robot cf<id> in flight nn; the files of one folder with the same nn
were flown together (2020's take-off folders: every file is a flight of its own, the
readme: "run with different drones").

The 2019 folders name scenarios their own way (``random_walk_large_small``, ``swap_lsl``,
``takeoff_landing_small``, ``random_walk_small_ground``); every folder maps to the 2020
naming (``randomwalk_sl``, ``swap_sll``, ``takeoff_s``, ``randomwalk_s``: a kind and the
team's types, small first), and each flight's robots must be that team: a folder of
another name, a robot of no known type or a team that is not the folder's is a one-line
error naming the file.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from ns2codegen.errors import Ns2Error
from ns2codegen.fileio import atomic_write_bytes

GROUND_PLANE_M = {"small": 0.05, "large": 0.06}
_FILE = re.compile(r"^(cf\d+)_(\d+)$")
_SCENARIO = re.compile(r"^(swap|randomwalk|takeoff)_([sl]+)$")
LETTER = {"small": "s", "large": "l"}


@dataclass(frozen=True)
class Collection:
    key: str                  # the collection's date, its name in flight names and reports
    folder: str               # path under the unpacked root
    tarballs: tuple           # the files of ../shared/neural-swarm-data that hold it
    robots: dict              # robot id -> type (the readme)
    not_labelled: dict        # robot id -> why its own labels are not used
    folders: dict             # the collection's folder names -> scenario (2020 naming); {}: already so

    def scenario(self, folder: str) -> str:
        """The scenario (``swap_sl``, ...) of one of the collection's folders."""
        sc = self.folders.get(folder, folder if not self.folders else None)
        if sc is None or not _SCENARIO.match(sc):
            raise CollectionError(f"{self.folder}/{folder}: unknown scenario folder for the {self.key} collection "
                                  f"(known: {', '.join(sorted(self.folders)) or 'swap_*, randomwalk_*, takeoff_*'})")
        return sc


_2019_ROBOTS = {"cf50": "small", "cf51": "small", "cf52": "small", "cf101": "large", "cf102": "large"}
COLLECTIONS = (
    Collection("2019-12-11", "training/datacollection19_12_11_2019", ("neural-swarm-2019-12.tar.xz",),
               _2019_ROBOTS, {},
               {"swap_small_small": "swap_ss", "swap_large_small": "swap_sl", "swap_large_large": "swap_ll",
                "random_walk_small_small": "randomwalk_ss", "random_walk_large_small": "randomwalk_sl",
                "random_walk_large_large": "randomwalk_ll"}),
    Collection("2019-12-20", "training/datacollection20_12_20_2019", ("neural-swarm-2019-12.tar.xz",),
               _2019_ROBOTS, {},
               {"swap_sss": "swap_sss", "swap_sls": "swap_ssl", "swap_lsl": "swap_sll",
                "random_walk_sss": "randomwalk_sss", "random_walk_ssl": "randomwalk_ssl",
                "random_walk_sll": "randomwalk_sll", "random_walk_small_ground": "randomwalk_s",
                "random_walk_large_ground": "randomwalk_l", "takeoff_landing_small": "takeoff_s",
                "takeoff_landing_large": "takeoff_l"}),
    Collection("2020-06-16", "training/datacollection21_06_16_2020",
               ("neural-swarm-2020-06-16-swaps.tar.xz", "neural-swarm-2020-06-16-randomwalks-1.tar.xz",
                "neural-swarm-2020-06-16-randomwalks-2.tar.xz"),
               dict(_2019_ROBOTS, cf100="large"),
               {"cf100": "Crazyflie 2.0 with the old IMU (readme: do not use its force estimates)"}, {}),
)
BY_KEY = {c.key: c for c in COLLECTIONS}
JUNE_2020 = BY_KEY["2020-06-16"]
# the 16 June 2020 collection, as the single-collection code (calibration, replays) names it
COLLECTION = JUNE_2020.folder
ROBOT_TYPES = JUNE_2020.robots
NOT_LABELLED = JUNE_2020.not_labelled


class CollectionError(Ns2Error, ValueError):
    """The folder is not a collection as expected."""


def _team(types: list[str]) -> str:
    return "".join(sorted(LETTER[t] for t in types))[::-1]   # small first: "ssl", "sl", "ll"


def flights(root: str | Path, collection: Collection = JUNE_2020) -> list[dict]:
    """Every flight of ``collection`` under ``root`` (the folder the tarballs were unpacked
    into), in a fixed order: scenario folder, flight number.  File paths are relative to
    ``root``; ``name`` is ``<scenario>/<nn>`` (the scenario in 2020 naming)."""
    base = Path(root) / collection.folder
    if not base.is_dir():
        raise CollectionError(f"{base}: not found (unpack ../shared/neural-swarm-data/"
                              f"{', '.join(collection.tarballs)} into {root})")
    out = []
    for folder in sorted(p for p in base.iterdir() if p.is_dir()):
        scenario = collection.scenario(folder.name)
        own_flights = scenario.startswith("takeoff") and not collection.folders
        groups: dict[str, list[str]] = {}
        for f in sorted(folder.iterdir()):
            m = _FILE.match(f.name)
            if not m:
                continue
            if m.group(1) not in collection.robots:
                raise CollectionError(f"{f}: robot {m.group(1)} has no type in the {collection.key} collection's "
                                      f"readme (robots {', '.join(sorted(collection.robots))})")
            key = f.name if own_flights else m.group(2)
            groups.setdefault(key, []).append(m.group(1))
        for key in sorted(groups):
            robots = sorted(groups[key], key=lambda r: int(r[2:]))
            number = key.split("_")[-1]
            team = _team([collection.robots[r] for r in robots])
            want = _SCENARIO.match(scenario).group(2)
            if team != want:
                raise CollectionError(f"{folder}/{robots[0]}_{number}: flight {number} flew robots "
                                      f"{', '.join(robots)} (team {team}), not the folder's team {want}")
            out.append({"name": f"{scenario}/{key if own_flights else number}", "scenario": scenario,
                        "folder": folder.name, "number": number,
                        "robots": [{"id": r, "file": f"{collection.folder}/{folder.name}/{r}_{number}",
                                    "type": collection.robots[r], "label": r not in collection.not_labelled}
                                   for r in robots]})
    if not out:
        raise CollectionError(f"{base}: no flight logs found")
    return out


def manifest_text(root: str | Path, collection: Collection = JUNE_2020, relative_to: str = "") -> str:
    """``flights.toml`` of the collection (deterministic); file paths relative to
    ``root/relative_to``."""
    lines = [f"# The Neural-Swarm2 authors' collection of {collection.key} (ns2paper.collection)",
             "rate_hz = 100", "",
             "[ground_plane_m]   # z of a robot standing on the floor (collection readme)"]
    lines += [f"{t} = {z}" for t, z in GROUND_PLANE_M.items()]
    cut = len(relative_to) + 1 if relative_to else 0
    for fl in flights(root, collection):
        lines += ["", "[[flight]]", f'name = "{fl["name"]}"', f'scenario = "{fl["scenario"]}"', "robots = ["]
        for r in fl["robots"]:
            lines.append(f'  {{file = "{r["file"][cut:]}", type = "{r["type"]}", id = "{r["id"]}"'
                         + ("" if r["label"] else ", label = false") + "},")
        lines.append("]")
    return "\n".join(lines) + "\n"


def write_manifest(root: str | Path) -> Path:
    """``root/flights.toml``: the 16 June 2020 collection (the calibration's flights)."""
    path = Path(root) / "flights.toml"
    atomic_write_bytes(path, manifest_text(root).encode())
    return path


def write_collection_manifest(root: str | Path, collection: Collection) -> Path:
    """``flights.toml`` in the collection's own folder (paths relative to it): the
    folder ``logs_to_flights`` reads for that collection."""
    path = Path(root) / collection.folder / "flights.toml"
    atomic_write_bytes(path, manifest_text(root, collection, collection.folder).encode())
    return path
