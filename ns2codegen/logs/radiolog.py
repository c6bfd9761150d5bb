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
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..config import Config
from .align import MIN_PIECE, PWM_FULL, VARIABLES, LogError, RobotLog, align

FA_ONBOARD = "ns2.faHat"   # the app's prediction in flight (g)
BASE = VARIABLES["p"][0]   # the packets that carry it are a robot's samples
GAP_PERIODS = 2.5


class RadioLogError(LogError):
    """A radio log that cannot be read (names the file and the line)."""


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def read(path) -> list[dict]:
    """The flights of a radio log: ``[{"line": n, "robots": {name: type}, "sync": seq,
    "samples": {name: [(line, t_ms, host_ms, {variable: value})]}}]``."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise RadioLogError(f"{path}: cannot read the radio log ({getattr(e, 'strerror', None) or e})") from e
    flights: list[dict] = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        where = f"{path}: line {n}"
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as e:
            raise RadioLogError(f"{where}: not JSON ({e.msg})") from None
        if not isinstance(rec, dict):
            raise RadioLogError(f"{where}: not a JSON object")
        if "flight" in rec:
            h = rec["flight"]
            robots = h.get("robots") if isinstance(h, dict) else None
            if not (isinstance(robots, dict) and robots and all(isinstance(t, str) for t in robots.values())):
                raise RadioLogError(f"{where}: flight.robots must map each robot's name to its robot type")
            flights.append({"line": n, "robots": dict(robots), "sync": h.get("sync"),
                            "samples": {r: [] for r in robots}})
            continue
        if not flights:
            raise RadioLogError(f"{where}: a log packet before the first flight header line")
        robot = rec.get("robot")
        if robot not in flights[-1]["robots"]:
            raise RadioLogError(f"{where}: robot: {robot!r} is not a robot of the flight of line "
                                f"{flights[-1]['line']} ({', '.join(flights[-1]['robots'])})")
        for key in ("t_ms", "host_ms"):
            if not _number(rec.get(key)):
                raise RadioLogError(f"{where}: {key}: missing or not a finite number")
        values = {k: v for k, v in rec.items() if k not in ("robot", "t_ms", "host_ms")}
        bad = next((k for k, v in values.items() if not _number(v)), None)
        if bad is not None:
            raise RadioLogError(f"{where}: {bad}: {values[bad]!r} is not a finite number")
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
    """Every flight of a radio log -> its usable pieces (ns2codegen.logs.align) and reports."""
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
