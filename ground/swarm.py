"""The swarm file: Crazyswarm2's ``crazyflies.yaml``, read and updated in place.

The one loader of the ground side.  What it reads (Crazyswarm2's layout)::

    robots:
      cf1:
        enabled: true
        uri: radio://0/80/2M/E7E7E7E701
        initial_position: [0.0, 0.0, 0.0]
        type: cf21
        firmware_params: {...}
    robot_types:
      cf21: {ns2_type: small, ...}      # ns2_type: the export's robot type
    all: {...}

A robot's ns2 robot type is ``robot_types.<type>.ns2_type``, else its ``type`` when
that names a robot type of the export's config.  Its radio id (the app's
``configblockGetRadioAddress() & 0xFF``, the bit of ``ns2type.mask1/mask2``) is the
last byte of the address in its uri.

``write_params`` puts the app's parameters for an export (``ns2.selfType``, the
``ns2type`` masks of the whole swarm, the ``ns2gain`` defaults of the robot's
vehicle) into each robot's ``firmware_params`` with ruamel.yaml's round trip:
comments, order and every other key of the user's file stay as they were.
"""
from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ns2codegen.config import Config
from ns2codegen.errors import Ns2Error
from ns2codegen.fileio import atomic_write_bytes
from ns2codegen.vehicle import default_gains, vehicle

GROUPS = ("ns2", "ns2type", "ns2gain")   # the app's parameter groups (firmware/app/src/ns2_app.c)
GAIN3 = ("Lp", "Kv", "Gv", "Lq", "Kw", "Gw", "Kwd")   # ns2gain.<name>x/y/z
GAIN1 = {"intVMax": "int_v_max", "intWMax": "int_w_max", "faMaxN": "fa_max_N"}
MASK_BITS = 32                              # ns2type.mask1/mask2 are uint32
URI = re.compile(r"^radio://\d+/\d+/(250K|1M|2M)/([0-9A-Fa-f]{10})(\?.*)?$")


class SwarmFileError(Ns2Error, ValueError):
    """A swarm file that cannot be used (names the file, the robot and the key)."""


@dataclass
class Robot:
    name: str
    uri: str
    enabled: bool
    initial_position: list[float]
    cs_type: str                  # Crazyswarm2 type (robot_types key)
    ns2_type: str                 # robot type of the export's config
    radio_id: int                 # last address byte
    firmware_params: dict = field(default_factory=dict)


@dataclass
class Swarm:
    path: Path
    robots: list[Robot]

    @property
    def enabled(self) -> list[Robot]:
        return [r for r in self.robots if r.enabled]


def _yaml():
    from ruamel.yaml import YAML   # [fly] extra

    y = YAML(typ="rt")
    y.preserve_quotes = True
    y.width = 4096
    return y


def _read(path: Path):
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise SwarmFileError(f"{path}: cannot read the swarm file ({e.strerror or e})") from e
    try:
        doc = _yaml().load(text)
    except Exception as e:  # ruamel's parser and scanner errors share no public base
        first = " ".join(str(e).split())[:200]
        raise SwarmFileError(f"{path}: not YAML: {first}") from e
    if not isinstance(doc, dict) or not isinstance(doc.get("robots"), dict) or not doc["robots"]:
        raise SwarmFileError(f"{path}: robots: missing or empty (Crazyswarm2's crazyflies.yaml layout)")
    return doc


def radio_id(uri: str) -> int:
    m = URI.match(uri)
    if not m:
        raise ValueError("not a radio uri (radio://<dongle>/<channel>/<250K|1M|2M>/<10 hex digits>)")
    return int(m.group(2), 16) & 0xFF


def _link(path: Path, name: str, entry) -> tuple[str, bool, int]:
    """uri, enabled and radio id of a robot entry."""
    where = f"{path}: robots.{name}"
    if not isinstance(entry, dict):
        raise SwarmFileError(f"{where}: not a mapping")
    if not isinstance(entry.get("uri"), str):
        raise SwarmFileError(f"{where}.uri: missing or not a string")
    enabled = entry.get("enabled", True)
    if not isinstance(enabled, bool):
        raise SwarmFileError(f"{where}.enabled: must be true or false")
    try:
        return entry["uri"], enabled, radio_id(entry["uri"])
    except ValueError as e:
        raise SwarmFileError(f"{where}.uri: {entry['uri']!r}: {e}") from None


def read_robots(path) -> dict[str, str]:
    """name -> uri of the enabled robots (no export needed: for ns2 flash)."""
    path = Path(path)
    doc = _read(path)
    out = {}
    for name, entry in doc["robots"].items():
        uri, enabled, _ = _link(path, str(name), entry)
        if enabled:
            out[str(name)] = uri
    if not out:
        raise SwarmFileError(f"{path}: robots: no robot is enabled")
    return out


def _robot(path: Path, doc, name: str, entry, types: list[str]) -> Robot:
    where = f"{path}: robots.{name}"
    _, enabled, rid = _link(path, name, entry)
    if not isinstance(entry.get("type"), str):
        raise SwarmFileError(f"{where}.type: missing or not a string")
    pos = entry.get("initial_position", [0.0, 0.0, 0.0])
    if not (isinstance(pos, list) and len(pos) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                           for x in pos)):
        raise SwarmFileError(f"{where}.initial_position: must be three numbers")
    cs_type = entry["type"]
    rt = (doc.get("robot_types") or {}).get(cs_type)
    ns2_type = rt.get("ns2_type") if isinstance(rt, dict) and "ns2_type" in rt else cs_type
    if ns2_type not in types:
        key = f"robot_types.{cs_type}.ns2_type" if isinstance(rt, dict) and "ns2_type" in rt else f"robots.{name}.type"
        raise SwarmFileError(f"{path}: {key}: {ns2_type!r} is not a robot type of the export {types} "
                             f"(set robot_types.{cs_type}.ns2_type)")
    fp = entry.get("firmware_params") or {}
    if not isinstance(fp, dict):
        raise SwarmFileError(f"{where}.firmware_params: not a mapping")
    return Robot(name, entry["uri"], enabled, [float(x) for x in pos], cs_type, ns2_type, rid, dict(fp))


def _check_ids(path: Path, robots: list[Robot], types: list[str]) -> None:
    seen = {}
    for r in robots:
        if r.radio_id in seen:  # the app's peer id and type-mask bit
            raise SwarmFileError(f"{path}: robots.{r.name}.uri: radio id {r.radio_id} (last address byte) "
                                 f"is also robots.{seen[r.radio_id]}'s")
        seen[r.radio_id] = r.name
        if types.index(r.ns2_type) > 0 and r.radio_id >= MASK_BITS:
            raise SwarmFileError(f"{path}: robots.{r.name}.uri: radio id {r.radio_id} of a {r.ns2_type} robot "
                                 f"must be below {MASK_BITS} (bit of ns2type.mask1/mask2)")


def load(path, cfg: Config) -> Swarm:
    """The swarm file's robots, their ns2 types from ``cfg`` (the export's config)."""
    path = Path(path)
    doc = _read(path)
    robots = [_robot(path, doc, str(n), e, cfg.robot_types) for n, e in doc["robots"].items()]
    _check_ids(path, robots, cfg.robot_types)
    if len(cfg.robot_types) > 3:
        raise SwarmFileError(f"{path}: the app knows 3 robot types (ns2type.mask1/mask2), "
                             f"the export has {len(cfg.robot_types)}")
    return Swarm(path, robots)


def params(swarm: Swarm, cfg: Config, robot: Robot) -> dict[str, dict[str, float | int]]:
    """The app's parameters of ``robot`` for an export: group -> name -> value, in the
    order they are set (selfType before the gains: writing a new type loads its default
    gains in the app, firmware/app/src/ns2_app.c).  The gains are the defaults of the
    robot's vehicle, except those the swarm file sets in the robot's
    ``firmware_params.ns2gain``."""
    types = cfg.robot_types
    masks = [0, 0]
    for r in swarm.robots:
        t = types.index(r.ns2_type)
        if t > 0:
            masks[t - 1] |= 1 << r.radio_id
    g = default_gains(vehicle(cfg, robot.ns2_type))
    gains = {f"{n}{ax}": round(float(g[n][i]), 9) for n in GAIN3 for i, ax in enumerate("xyz")}
    gains.update({p: round(float(g[k]), 9) for p, k in GAIN1.items()})
    user = robot.firmware_params.get("ns2gain") or {}   # the user's own gains in the swarm file stay
    where = f"{swarm.path}: robots.{robot.name}.firmware_params.ns2gain"
    if not isinstance(user, dict):
        raise SwarmFileError(f"{where}: not a mapping")
    for k, v in user.items():
        if k not in gains:
            raise SwarmFileError(f"{where}.{k}: not a gain of the app ({', '.join(gains)})")
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
            raise SwarmFileError(f"{where}.{k}: {v!r} is not a finite number")
        gains[k] = float(v)
    return {"ns2": {"selfType": types.index(robot.ns2_type)},
            "ns2type": {"mask1": masks[0], "mask2": masks[1]},
            "ns2gain": gains}


def write_params(path, cfg: Config, out=None) -> Swarm:
    """Write the app's parameters (``params``) into every robot's ``firmware_params`` of
    the swarm file ``path`` (or a copy at ``out``), nothing else of the file changed."""
    path = Path(path)
    swarm = load(path, cfg)
    doc = _read(path)
    from ruamel.yaml.comments import CommentedMap

    for r in swarm.robots:
        entry = doc["robots"][r.name]
        if entry.get("firmware_params") is None:
            entry["firmware_params"] = CommentedMap()
        fp = entry["firmware_params"]
        for group, values in params(swarm, cfg, r).items():
            if not isinstance(fp.get(group), dict):
                fp[group] = CommentedMap()
            fp[group].update(values)
    buf = io.StringIO()
    _yaml().dump(doc, buf)
    atomic_write_bytes(Path(out) if out else path, buf.getvalue().encode())
    return load(Path(out) if out else path, cfg)
