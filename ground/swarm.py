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
``configblockGetRadioAddress() & 0xFF``, the peer id of the mocap broadcasts) is the
last byte of the address in its uri: any of 0..255 for any robot type, unique in the
swarm, and not 0 in a swarm of several robots (crazyflie-firmware's peer
localization takes id 0 for a free slot, so no other robot would see that one).

``write_params`` puts the app's parameters for an export (``ns2.selfType``, the type
table ``ns2type.t0..t15`` of the whole swarm, the ``ns2gain`` defaults of the
robot's vehicle) into each robot's ``firmware_params`` with ruamel.yaml's round
trip: comments, order and every other key of the user's file stay as they were.

What the loader guarantees (docs/inputs.md): any file, whatever its bytes, gives
either a swarm whose every field was checked or a ``SwarmFileError`` of one line
naming the file (and the robot and key where one is at fault): a file that is not
UTF-8 text (a binary file, UTF-16 or UTF-32, with or without a byte-order mark;
UTF-8's own byte-order mark is accepted and kept), NUL bytes, more than
``MAX_BYTES``, YAML nested deeper than ``MAX_DEPTH`` levels (or a recursive alias),
robot names that are not ROS names, and every bad field.
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
from ns2codegen.onboard import AdaptCfg, adapt_cfg_ok
from ns2codegen.vehicle import default_gains, vehicle
from ns2host.cbuild import TYPE_TABLE_MAX_TYPES, TYPE_TABLE_WORDS, type_table

GROUPS = ("ns2", "ns2type", "ns2gain", "ns2adapt")   # the app's parameter groups (firmware/app/src/ns2_app.c)
# ns2adapt.<name>: the on-board adaptation's parameters (ns2_adapt.h, docs/adaptation.md) -> AdaptCfg field
ADAPT = {"enable": "enable", "forget": "forget", "p0": "p0", "pMax": "p_max", "biasMax": "bias_max_g",
         "scaleMax": "scale_max", "faMax": "fa_max_g", "labelMax": "label_max_g", "wakeG": "wake_g",
         "gateNbr": "gate_neighbours", "trackGain": "track_gain"}
ADAPT_SWITCHES = ("enable", "gateNbr")   # 0 or 1 (uint8_t)
ADAPT_ENABLE = 0   # off unless the swarm file says ns2adapt: {enable: 1}, as the app boots (not yet judged in flight)
GAIN3 = ("Lp", "Kv", "Gv", "Lq", "Kw", "Gw", "Kwd")   # ns2gain.<name>x/y/z
GAIN1 = {"intVMax": "int_v_max", "intWMax": "int_w_max", "faMaxN": "fa_max_N"}
TYPE_PARAMS = tuple(f"t{k}" for k in range(TYPE_TABLE_WORDS))   # ns2type.t0..t15: the type table's words
# radio://<dongle>/<channel>/<rate>/<address>[?<cflib's link options>], ASCII digits only
URI = re.compile(r"radio://([0-9]{1,3})/([0-9]{1,3})/(250K|1M|2M)/([0-9A-Fa-f]{10})(\?[A-Za-z0-9_=&.-]*)?")
CHANNEL_MAX = 125                         # the nRF24's channels (2400 + n MHz)
NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")   # a ROS name: Crazyswarm2 names its nodes and topics so
MAX_BYTES = 16 * 2 ** 20                  # a crazyflies.yaml of 256 robots is well below 1 MiB
MAX_DEPTH = 32                            # Crazyswarm2's layout nests 5 levels deep
POSITION_MAX_M = 1e3                      # |initial_position| per axis (the app's NS2_PEERS_P_MAX_M)
UTF8_BOM = b"\xef\xbb\xbf"
BOMS = ((b"\x00\x00\xfe\xff", "UTF-32"), (b"\xff\xfe\x00\x00", "UTF-32"), (b"\xfe\xff", "UTF-16"),
        (b"\xff\xfe", "UTF-16"))


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


def _text(path: Path) -> tuple[str, bool]:
    """The file's text and whether it began with UTF-8's byte-order mark."""
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as e:
        raise SwarmFileError(f"{path}: cannot read the swarm file ({e.strerror or e})") from e
    if len(data) > MAX_BYTES:
        raise SwarmFileError(f"{path}: larger than {MAX_BYTES // 2 ** 20} MiB: not a swarm file")
    for bom, enc in BOMS:
        if data.startswith(bom):
            raise SwarmFileError(f"{path}: {enc} text (byte-order mark {bom.hex(' ')}): a swarm file is UTF-8, "
                                 f"as Crazyswarm2 reads it (save it as UTF-8)")
    bom = data.startswith(UTF8_BOM)
    if bom:
        data = data[len(UTF8_BOM):]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise SwarmFileError(f"{path}: line {line}: not UTF-8 text (byte 0x{data[e.start]:02x}): a swarm file is "
                             f"UTF-8, as Crazyswarm2 reads it") from None
    if "\x00" in text:
        line = text.count("\n", 0, text.index("\x00")) + 1
        raise SwarmFileError(f"{path}: line {line}: a NUL byte: not a text file (or UTF-16/32 without a "
                             f"byte-order mark; a swarm file is UTF-8)")
    return text, bom


def _flow_depth(text: str) -> int:
    """The deepest nesting of YAML flow collections ([...], {...}) in ``text``, outside
    quoted scalars and comments, read lexically: ruamel's scanner takes time quadratic
    in it (minutes for a few thousand levels), so the loader bounds it before parsing.
    A bracket inside a plain scalar counts too (it only ever overestimates by unclosed
    ones, which no swarm file has by the dozen)."""
    depth = deepest = 0
    quote = None
    prev = "\n"   # the previous character outside a scalar: a quote or # starts there only
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        if quote == "'":
            if ch == "'":
                if i + 1 < n and text[i + 1] == "'":
                    i += 1
                else:
                    quote = None
        elif quote == '"':
            if ch == "\\":
                i += 1
            elif ch == '"':
                quote = None
        elif ch == "#" and prev in " \t\n":
            j = text.find("\n", i)
            i = n if j < 0 else j
            prev = "\n"
            continue
        elif ch in "'\"" and prev in " \t\n[{,:-?":
            quote = ch
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth = max(depth - 1, 0)
        if quote is None:
            prev = ch
        i += 1
    return deepest


def _too_deep(doc) -> bool:
    """Whether ``doc`` nests deeper than MAX_DEPTH (a recursive alias does): level by
    level over the distinct containers, so shared aliases are visited once a level."""
    level = [doc]
    for _ in range(MAX_DEPTH):
        nxt, seen = [], set()
        for node in level:
            children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else ()
            for c in children:
                if isinstance(c, (dict, list)) and id(c) not in seen:
                    seen.add(id(c))
                    nxt.append(c)
        if not nxt:
            return False
        level = nxt
    return True


def _read(path: Path):
    doc, _ = _read_doc(path)
    return doc


def _read_doc(path: Path):
    """The swarm file's YAML document (checked to be a swarm file's top level) and
    whether the file began with UTF-8's byte-order mark."""
    path = Path(path)
    text, bom = _text(path)
    if text.count("[") + text.count("{") > MAX_DEPTH and _flow_depth(text) > MAX_DEPTH:
        raise SwarmFileError(f"{path}: flow collections ([...], {{...}}) nested deeper than {MAX_DEPTH} levels "
                             f"(Crazyswarm2's crazyflies.yaml nests a few)")
    try:
        doc = _yaml().load(text)
    except RecursionError:
        raise SwarmFileError(f"{path}: not YAML: nested too deep (a swarm file nests a few levels)") from None
    except Exception as e:  # ruamel's parser and scanner errors share no public base
        first = " ".join(str(e).split())[:200]
        raise SwarmFileError(f"{path}: not YAML: {first}") from None
    if _too_deep(doc):
        raise SwarmFileError(f"{path}: nested deeper than {MAX_DEPTH} levels, or a recursive alias "
                             f"(Crazyswarm2's crazyflies.yaml nests a few)")
    if not isinstance(doc, dict) or not isinstance(doc.get("robots"), dict) or not doc["robots"]:
        raise SwarmFileError(f"{path}: robots: missing or empty (Crazyswarm2's crazyflies.yaml layout)")
    for name in doc["robots"]:
        if not (isinstance(name, str) and NAME.fullmatch(name)):
            raise SwarmFileError(f"{path}: robots: {_quote(name)}: a robot's name is a ROS name (a letter or _, "
                                 f"then letters, digits or _, at most 64), as Crazyswarm2 names its nodes")
    if doc.get("robot_types") is not None and not isinstance(doc["robot_types"], dict):
        raise SwarmFileError(f"{path}: robot_types: not a mapping")
    return doc, bom


def _quote(x, limit: int = 60) -> str:
    """A value of the user's file in a one-line message."""
    r = repr(x)
    return r if len(r) <= limit else r[:limit - 3] + "..."


def radio_id(uri: str) -> int:
    m = URI.fullmatch(uri)
    if not m:
        raise ValueError("not a radio uri (radio://<dongle>/<channel>/<250K|1M|2M>/<10 hex digits>)")
    if int(m.group(2)) > CHANNEL_MAX:
        raise ValueError(f"channel {int(m.group(2))}: the radio's channels are 0..{CHANNEL_MAX}")
    return int(m.group(4), 16) & 0xFF


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
        raise SwarmFileError(f"{where}.uri: {_quote(entry['uri'])}: {e}") from None


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


def _finite(x) -> bool:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(x) and abs(x) <= POSITION_MAX_M
    except OverflowError:   # an integer beyond any float
        return False


def _robot(path: Path, doc, name: str, entry, types: list[str]) -> Robot:
    where = f"{path}: robots.{name}"
    _, enabled, rid = _link(path, name, entry)
    if not isinstance(entry.get("type"), str):
        raise SwarmFileError(f"{where}.type: missing or not a string")
    pos = entry.get("initial_position", [0.0, 0.0, 0.0])
    if not (isinstance(pos, list) and len(pos) == 3 and all(_finite(x) for x in pos)):
        raise SwarmFileError(f"{where}.initial_position: must be three finite numbers (m, at most "
                             f"{POSITION_MAX_M:g} in magnitude)")
    cs_type = entry["type"]
    key = cs_type if NAME.fullmatch(cs_type) else _quote(cs_type)
    rt = (doc.get("robot_types") or {}).get(cs_type)
    ns2_type = rt.get("ns2_type") if isinstance(rt, dict) and "ns2_type" in rt else cs_type
    if not isinstance(ns2_type, str) or ns2_type not in types:
        at = f"robot_types.{key}.ns2_type" if isinstance(rt, dict) and "ns2_type" in rt else f"robots.{name}.type"
        raise SwarmFileError(f"{path}: {at}: {_quote(ns2_type)} is not a robot type of the export {types} "
                             f"(set robot_types.{key}.ns2_type)")
    fp = entry.get("firmware_params") or {}
    if not isinstance(fp, dict):
        raise SwarmFileError(f"{where}.firmware_params: not a mapping")
    return Robot(name, entry["uri"], enabled, [float(x) for x in pos], cs_type, ns2_type, rid, dict(fp))


def _check_ids(path: Path, robots: list[Robot], types: list[str]) -> None:
    seen = {}
    for r in robots:
        if r.radio_id in seen:  # the app's peer id and its entry of the type table
            raise SwarmFileError(f"{path}: robots.{r.name}.uri: radio id {r.radio_id} (last address byte) "
                                 f"is also robots.{seen[r.radio_id]}'s")
        seen[r.radio_id] = r.name
    enabled = [r for r in robots if r.enabled]
    zero = next((r for r in enabled if r.radio_id == 0), None)
    if zero is not None and len(enabled) > 1:
        raise SwarmFileError(f"{path}: robots.{zero.name}.uri: radio id 0 (last address byte 00): crazyflie-firmware's "
                             f"peer localization takes id 0 for a free slot, so no other robot would see "
                             f"robots.{zero.name} as a neighbour; give it an address ending in 01..FF")


def load(path, cfg: Config) -> Swarm:
    """The swarm file's robots, their ns2 types from ``cfg`` (the export's config)."""
    path = Path(path)
    doc = _read(path)
    robots = [_robot(path, doc, n, e, cfg.robot_types) for n, e in doc["robots"].items()]
    _check_ids(path, robots, cfg.robot_types)
    if len(cfg.robot_types) > TYPE_TABLE_MAX_TYPES:
        raise SwarmFileError(f"{path}: the app's type table (ns2type.t0..t15, 2 bits per radio id) names "
                             f"{TYPE_TABLE_MAX_TYPES} robot types, the export has {len(cfg.robot_types)}")
    return Swarm(path, robots)


def types_by_id(swarm: Swarm, cfg: Config) -> dict[int, int]:
    """Radio id -> robot type index (of the export's config) of every robot of the swarm."""
    return {r.radio_id: cfg.robot_types.index(r.ns2_type) for r in swarm.robots}


def params(swarm: Swarm, cfg: Config, robot: Robot) -> dict[str, dict[str, float | int]]:
    """The app's parameters of ``robot`` for an export: group -> name -> value, in the
    order they are set (selfType before the gains: writing a new type loads its default
    gains in the app, firmware/app/src/ns2_app.c).  The gains are the defaults of the
    robot's vehicle, except those the swarm file sets in the robot's
    ``firmware_params.ns2gain``."""
    types = cfg.robot_types
    table = type_table(types_by_id(swarm, cfg))
    g = default_gains(vehicle(cfg, robot.ns2_type))
    gains = {f"{n}{ax}": round(float(g[n][i]), 9) for n in GAIN3 for i, ax in enumerate("xyz")}
    gains.update({p: round(float(g[k]), 9) for p, k in GAIN1.items()})
    gains.update(_user_values(swarm, robot, "ns2gain", gains, "a gain"))
    d = {**AdaptCfg().as_dict(), "enable": ADAPT_ENABLE}
    adapt = {p: d[f] for p, f in ADAPT.items()}
    adapt.update(_user_values(swarm, robot, "ns2adapt", adapt, "a parameter of the adaptation"))
    if any(adapt[p] not in (0, 1) for p in ADAPT_SWITCHES) \
            or not adapt_cfg_ok(AdaptCfg(**{f: adapt[p] for p, f in ADAPT.items()})):
        raise SwarmFileError(f"{swarm.path}: robots.{robot.name}.firmware_params.ns2adapt: {adapt} out of range "
                             f"(enable and gateNbr 0 or 1, forget in [0.5, 1], 0 < p0 <= pMax <= 1000, limits in "
                             f"[0, 1000], trackGain in [0, 1e6]; docs/adaptation.md)")
    adapt.update({p: int(adapt[p]) for p in ADAPT_SWITCHES})
    return {"ns2": {"selfType": types.index(robot.ns2_type)},
            "ns2type": dict(zip(TYPE_PARAMS, table)),
            "ns2gain": gains,
            "ns2adapt": adapt}


def _user_values(swarm: Swarm, robot: Robot, group: str, known: dict, what: str) -> dict[str, float]:
    """The values the swarm file sets in the robot's ``firmware_params.<group>`` (they stay):
    each a finite number and one of ``known``."""
    user = robot.firmware_params.get(group) or {}
    where = f"{swarm.path}: robots.{robot.name}.firmware_params.{group}"
    if not isinstance(user, dict):
        raise SwarmFileError(f"{where}: not a mapping")
    out = {}
    for k, v in user.items():
        if k not in known:
            raise SwarmFileError(f"{where}.{k}: not {what} of the app ({', '.join(known)})")
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
            raise SwarmFileError(f"{where}.{k}: {v!r} is not a finite number")
        out[k] = float(v)
    return out


def _shared_nodes(doc) -> set[int]:
    """ids of the mappings and sequences reached by more than one path of ``doc`` (YAML
    aliases): a robot's parameters written into one would be every sharer's."""
    seen, shared, stack = set(), set(), [doc]
    while stack:
        node = stack.pop()
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else ()
        for c in children:
            if isinstance(c, (dict, list)):
                if id(c) in seen:
                    shared.add(id(c))
                else:
                    seen.add(id(c))
                    stack.append(c)
    return shared


def write_params(path, cfg: Config, out=None) -> Swarm:
    """Write the app's parameters (``params``) into every robot's ``firmware_params`` of
    the swarm file ``path`` (or a copy at ``out``), nothing else of the file changed but
    the group ``ns2type``, which is the app's type table and nothing else (keys of an
    older app, ``mask1``/``mask2``, go).  A robot whose ``firmware_params`` (or one of
    the app's groups in it) is an alias of a node shared with others gets its own copy,
    so each robot's type and gains stay its own."""
    path = Path(path)
    swarm = load(path, cfg)
    doc, bom = _read_doc(path)
    from ruamel.yaml.comments import CommentedMap

    shared = _shared_nodes(doc)
    for r in swarm.robots:
        entry = doc["robots"][r.name]
        if entry.get("firmware_params") is None:
            entry["firmware_params"] = CommentedMap()
        elif id(entry["firmware_params"]) in shared:   # an alias (&fp ... *fp): this robot's own copy
            entry["firmware_params"] = CommentedMap(entry["firmware_params"])
        fp = entry["firmware_params"]
        for group, values in params(swarm, cfg, r).items():
            if not isinstance(fp.get(group), dict):
                fp[group] = CommentedMap()
            elif id(fp[group]) in shared:
                fp[group] = CommentedMap(fp[group])
            if group == "ns2type":
                for k in [k for k in fp[group] if k not in values]:
                    del fp[group][k]
            fp[group].update(values)
    buf = io.StringIO()
    _yaml().dump(doc, buf)
    atomic_write_bytes(Path(out) if out else path, (UTF8_BOM if bom else b"") + buf.getvalue().encode())
    return load(Path(out) if out else path, cfg)
