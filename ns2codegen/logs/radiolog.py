"""The radio log of ``ns2 fly`` (JSON lines, docs/flying.md) -> flights on a common
time base, the input of ``ns2 logs-to-data LOG.jsonl``.

A flight starts with a header line ``{"flight": {"robots": {name: robot type},
"sync": seq}}``; each later line is one log packet of one robot: ``{"robot": name,
"t_ms": the robot's clock, "host_ms": the ground's clock, variable: value, ...}``
(the app's ``ns2`` group, ``stateEstimate``, ``motor``, ``pm``: ns2ground.cf.LOG_BLOCKS).
A file may hold several flights (``ns2 fly`` appends).

Per robot, the samples are the packets that carry ``stateEstimate.x``; every other
variable is interpolated at their times from its own packets (the log blocks arrive
apart).  Clock offset of a robot: the smallest ``host_ms - t_ms`` over its packets
(the packet that reached the ground fastest), so the common clock is the ground's
to within the spread of the radio's fastest deliveries (a few ms; the dry run's
packets all arrive at the same delay).  The grid rate is the log rate (the median
sample spacing), a gap counts beyond 2.5 periods.  Every bad line is one error
naming the file and the line.

What the reader guarantees (docs/inputs.md): any file, whatever its bytes, gives
either flights whose every value was checked or a ``RadioLogError`` of one line
naming the file, and the line where one line is at fault: text that is not UTF-8
(a binary file, UTF-16 or UTF-32 text; UTF-8's byte-order mark is skipped), a line
that is not one JSON object, nested deeper than ``MAX_NESTING`` levels (checked
before the JSON parser, which would recurse), a number beyond ``VALUE_MAX`` (or of
more digits than Python converts), a robot name that is not printable or longer
than ``NAME_MAX``, and values outside the physical range of the uSD reader
(``timebase.PLAUSIBLE``, unit quaternions, clocks of at least 0).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..config import Config
from .timebase import MIN_PIECE, PLAUSIBLE, PWM_FULL, QUAT_NORM, VARIABLES, LogError, RobotLog, align

FA_ONBOARD = "ns2.faHat"   # the app's prediction in flight (g)
BASE = VARIABLES["p"][0]   # the packets that carry it are a robot's samples
GAP_PERIODS = 2.5
MAX_NESTING = 8            # a line nests 3 levels at most ({"flight": {"robots": {...}}})
VALUE_MAX = 1e15           # |any number| (clocks in ms are exact in float64 far beyond it)
NAME_MAX = 64              # characters of a robot's name
BOMS = ((b"\x00\x00\xfe\xff", "UTF-32"), (b"\xff\xfe\x00\x00", "UTF-32"), (b"\xfe\xff", "UTF-16"),
        (b"\xff\xfe", "UTF-16"))
# each logged variable's physical range, as the uSD reader checks it (timebase.PLAUSIBLE)
RANGE = {**{n: PLAUSIBLE[k] for k in ("p", "v", "battery_V") for n in VARIABLES[k]},
         **{n: (PLAUSIBLE["pwm"][0] * PWM_FULL, PLAUSIBLE["pwm"][1] * PWM_FULL) for n in VARIABLES["pwm"]},
         **{n: (-QUAT_NORM[1], QUAT_NORM[1]) for n in VARIABLES["q"]}}


class RadioLogError(LogError):
    """A radio log that cannot be read (names the file and the line)."""


def _number(x) -> bool:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(x) and abs(x) <= VALUE_MAX
    except OverflowError:   # an integer beyond any float
        return False


def _not_number(x) -> str:
    """Why ``x`` is refused as a value (``_number(x)`` is false)."""
    finite = isinstance(x, float) and math.isfinite(x) or isinstance(x, int) and not isinstance(x, bool)
    return f"is beyond +-{VALUE_MAX:g}" if finite else "is not a finite number"


def _nesting(line: str) -> int:
    """The deepest nesting of JSON arrays and objects in ``line``, outside strings."""
    depth = deepest = 0
    in_str = escaped = False
    for ch in line:
        if in_str:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def _text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as e:
        raise RadioLogError(f"{path}: cannot read the radio log ({e.strerror or e})") from e
    for bom, enc in BOMS:
        if data.startswith(bom):
            raise RadioLogError(f"{path}: {enc} text (byte-order mark {bom.hex(' ')}): ns2 fly's radio log is UTF-8")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise RadioLogError(f"{path}: line {line}: not UTF-8 text (byte 0x{data[e.start]:02x}): not ns2 fly's "
                            f"radio log") from None


def _record(where: str, line: str):
    """One line's JSON value (one-line errors naming ``where``)."""
    if (line.count("[") + line.count("{") > MAX_NESTING) and _nesting(line) > MAX_NESTING:
        raise RadioLogError(f"{where}: not JSON of a radio log: nested deeper than {MAX_NESTING} levels")
    try:
        return json.loads(line)
    except json.JSONDecodeError as e:
        raise RadioLogError(f"{where}: not JSON ({e.msg})") from None
    except (ValueError, RecursionError) as e:   # e.g. an integer of more digits than Python converts
        raise RadioLogError(f"{where}: not JSON ({' '.join(str(e).split())[:120]})") from None


def _quote(x, limit: int = 60) -> str:
    r = repr(x)
    return r if len(r) <= limit else r[:limit - 3] + "..."


def read(path) -> list[dict]:
    """The flights of a radio log: ``[{"line": n, "robots": {name: type}, "sync": seq,
    "samples": {name: [(line, t_ms, host_ms, {variable: value})]}}]``."""
    path = Path(path)
    text = _text(path)
    flights: list[dict] = []
    for n, line in enumerate(text.split("\n"), 1):   # the lines an editor numbers (not str.splitlines)
        line = line.removesuffix("\r")
        if not line.strip():
            continue
        where = f"{path}: line {n}"
        rec = _record(where, line)
        if not isinstance(rec, dict):
            raise RadioLogError(f"{where}: not a JSON object")
        if "flight" in rec:
            h = rec["flight"]
            robots = h.get("robots") if isinstance(h, dict) else None
            if not (isinstance(robots, dict) and robots and all(isinstance(t, str) for t in robots.values())):
                raise RadioLogError(f"{where}: flight.robots must map each robot's name to its robot type")
            bad = next((r for r in robots if not (r and len(r) <= NAME_MAX and r.isprintable())), None)
            if bad is not None:
                raise RadioLogError(f"{where}: flight.robots: {_quote(bad)}: a robot's name is 1 to {NAME_MAX} "
                                    f"printable characters")
            sync = h.get("sync")
            if sync is not None and not _number(sync):
                raise RadioLogError(f"{where}: flight.sync: {_quote(sync)} {_not_number(sync)}")
            flights.append({"line": n, "robots": dict(robots), "sync": sync,
                            "samples": {r: [] for r in robots}})
            continue
        if not flights:
            raise RadioLogError(f"{where}: a log packet before the first flight header line")
        robot = rec.get("robot")
        if not isinstance(robot, str) or robot not in flights[-1]["robots"]:
            raise RadioLogError(f"{where}: robot: {_quote(robot)} is not a robot of the flight of line "
                                f"{flights[-1]['line']} ({', '.join(flights[-1]['robots'])})")
        for key in ("t_ms", "host_ms"):
            if not _number(rec.get(key)):
                raise RadioLogError(f"{where}: {key}: missing or not a finite number (within +-{VALUE_MAX:g})")
        if rec["t_ms"] < 0:
            raise RadioLogError(f"{where}: t_ms: {rec['t_ms']!r} is before the robot's boot")
        values = {k: v for k, v in rec.items() if k not in ("robot", "t_ms", "host_ms")}
        bad = next((k for k, v in values.items() if not _number(v)), None)
        if bad is not None:
            raise RadioLogError(f"{where}: {bad if bad.isprintable() else _quote(bad)}: {_quote(values[bad])} "
                                f"{_not_number(values[bad])}")
        bad = next((k for k, v in values.items() if k in RANGE and not RANGE[k][0] <= v <= RANGE[k][1]), None)
        if bad is not None:
            raise RadioLogError(f"{where}: {bad}: {values[bad]!r} is outside the physical range "
                                f"[{RANGE[bad][0]:g}, {RANGE[bad][1]:g}]: corrupt log")
        if all(q in values for q in VARIABLES["q"]):
            qn = math.sqrt(sum(float(values[q]) ** 2 for q in VARIABLES["q"]))
            if not QUAT_NORM[0] <= qn <= QUAT_NORM[1]:
                raise RadioLogError(f"{where}: stateEstimate.qw/qx/qy/qz: norm {qn:.3g}, not a unit quaternion")
        flights[-1]["samples"][robot].append((n, float(rec["t_ms"]), float(rec["host_ms"]), values))
    if not flights:
        raise RadioLogError(f"{path}: no flight header line (ns2 fly's radio log, docs/flying.md)")
    return flights


def _robot_log(path: Path, name: str, samples: list) -> tuple[RobotLog, float]:
    """One robot's samples on its own clock (s) and its clock offset (s, ground minus robot)."""
    where = f"{path}: robot {name}"
    series: dict[str, tuple[list, list]] = {}
    for _, t, _, vals in samples:
        for k, v in vals.items():
            ts, vs = series.setdefault(k, ([], []))
            ts.append(t)
            vs.append(v)
    need = [n for names in VARIABLES.values() for n in names]
    missing = [n for n in need if len(series.get(n, ((), ()))[0]) < 2]
    if missing:
        raise RadioLogError(f"{where}: no samples of {missing} (the log blocks of ns2 fly, ns2ground.cf.LOG_BLOCKS)")
    base = series[BASE][0]
    t = np.array(base) * 1e-3
    if len(t) < MIN_PIECE:
        raise RadioLogError(f"{where}: only {len(t)} samples")
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        line = [s[0] for s in samples if BASE in s[3]][k]
        raise RadioLogError(f"{path}: line {line}: t_ms of robot {name} does not increase")

    def at(names):
        cols = []
        for n in names:
            ts, vs = series[n]
            order = np.argsort(ts, kind="stable")
            cols.append(np.interp(t, np.array(ts)[order] * 1e-3, np.array(vs, float)[order]))
        return np.stack(cols, 1)

    fa = at([FA_ONBOARD])[:, 0] if len(series.get(FA_ONBOARD, ((), ()))[0]) >= 2 else None
    offset = min(h - tm for _, tm, h, _ in samples) * 1e-3
    return RobotLog(t, at(VARIABLES["p"]), at(VARIABLES["v"]), at(VARIABLES["q"]), at(VARIABLES["pwm"]) / PWM_FULL,
                    at(VARIABLES["battery_V"])[:, 0], None, fa_onboard_g=fa), offset


def radiolog_to_flights(cfg: Config, path, z_min: float = 0.02) -> tuple[list, list[dict]]:
    """Every flight of a radio log -> its usable pieces (ns2codegen.logs.timebase) and reports."""
    path = Path(path)
    out, reports = [], []
    for k, fl in enumerate(read(path)):
        name = f"{path.name} flight {k} (line {fl['line']})"
        unknown = [t for t in fl["robots"].values() if t not in cfg.robot_types]
        if unknown:
            raise RadioLogError(f"{path}: line {fl['line']}: flight.robots: robot types {unknown} are not in the "
                                f"config {cfg.robot_types}")
        robots, offsets = [], []
        for rname, samples in fl["samples"].items():
            r, off = _robot_log(path, rname, samples)
            robots.append(r)
            offsets.append(off)
        h0 = min(r.t[0] + o for r, o in zip(robots, offsets))   # the common clock: the ground's, from here
        for r, o in zip(robots, offsets):
            r.sync_s = h0 - o                                     # the robot's clock at that instant
        period = float(np.median(np.concatenate([np.diff(r.t) for r in robots])))
        rate = 1.0 / period
        try:
            pieces, rep = align(list(fl["robots"].values()), robots, rate, max_gap_s=GAP_PERIODS * period,
                                z_min=z_min, name=name, ids=list(fl["robots"]))
        except LogError as e:
            raise RadioLogError(f"{path}: line {fl['line']}: {e}") from e
        reports.append(dict(rep, name=name, sync="ground receive time (radio log)", rate_hz=round(rate, 3),
                            notes=[], robots=list(fl["robots"]), not_labelled=[]))
        out += pieces
    return out, reports
