"""A flight of the swarm: the order of things and the safety paths (docs/flying.md).

``fly`` works on robots with the interface of ``ns2ground.cf.CfRobot`` (name, lost,
param, has_param, set_param, trajectory_memory_size, upload, takeoff, start, land,
stop, start_logs):
  1. every robot's ``ns2.modelId`` against the export (no app, or another model:
     one line naming the robot, nothing sent);
  2. every plan against the robot's trajectory memory (read from the robot) and
     its first point against the robot's initial position;
  3. the app's parameters of the swarm file and the export (ns2, ns2type, ns2gain);
  4. ``ns2.sync`` with one sequence number on every robot (log alignment);
  5. the trajectories uploaded and defined, the logs started;
  6. take off (to the height of the plan's first point), start the trajectories
     together, land.
From 5 on, a lost link, a low battery, an app status error or Ctrl-C lands every
robot that still answers; every log packet is on disk as it arrives.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from ns2codegen.errors import Ns2Error
from ns2plan.output import POLY4D_BYTES, read_poly4d
from . import fingerprint
from .swarm import Swarm, params


class Abort(Ns2Error, RuntimeError):
    """The flight was ended early; every robot was told to land."""


START_TOLERANCE_M = 0.25   # a plan's first point against the robot's initial_position (x, y)


@dataclass
class Settings:
    takeoff_height_m: float = 0.5     # when a plan starts lower than 0.1 m
    takeoff_s: float = 2.5
    land_s: float = 2.5
    min_battery_V: float = 3.3
    poll_s: float = 0.05


def plans_for(swarm: Swarm, plan_dir) -> dict[str, bytes]:
    """Each enabled robot's ``<name>.bin`` in ``plan_dir``; else the planner's
    ``robot<i>_<type>.bin`` files in order, their types equal to the robots'."""
    plan_dir = Path(plan_dir)
    robots = swarm.enabled
    if all((plan_dir / f"{r.name}.bin").is_file() for r in robots):
        files = {r.name: plan_dir / f"{r.name}.bin" for r in robots}
    else:
        planned = sorted(plan_dir.glob("robot*_*.bin"), key=lambda p: int(p.stem[5:].split("_")[0]))
        if len(planned) != len(robots):
            raise Ns2Error(f"{plan_dir}: {len(planned)} planned robots (robot<i>_<type>.bin) for "
                           f"{len(robots)} enabled robots of {swarm.path}, and no <name>.bin for each")
        for p, r in zip(planned, robots):
            if p.stem.split("_", 1)[1] != r.ns2_type:
                raise Ns2Error(f"{p}: a {p.stem.split('_', 1)[1]} robot's plan for robots.{r.name} ({r.ns2_type})")
        files = {r.name: p for p, r in zip(planned, robots)}
    out = {}
    for name, p in files.items():
        data = p.read_bytes()
        try:
            read_poly4d(data)
        except ValueError as e:
            raise Ns2Error(f"{p}: {e}") from None
        out[name] = data
    return out


def duration_s(plan: bytes) -> float:
    return float(sum(d for d, _ in read_poly4d(plan)))


def start_point(plan: bytes):
    """x, y, z of a plan's first point."""
    return [float(x) for x in read_poly4d(plan)[0][1][:3, 0]]


class WallClock:
    """Real time (the simulator's dry run passes a virtual clock, ground/sim.py)."""

    now = staticmethod(time.monotonic)
    sleep = staticmethod(time.sleep)


class Recorder:
    """The flight log: JSON lines, each on disk as it arrives (docs/flying.md, read by
    ``ns2 logs-to-data``, ns2codegen/logs/radiolog.py).  A flight starts with a header
    line ``{"flight": {"robots": {name: ns2 type}, "sync": seq}}``; then one line per
    log packet: ``{"robot", "t_ms"`` (the robot's clock), ``"host_ms"`` (the ground's
    clock since the header), ``variable: value, ...}``.  The file is appended to and
    opened only when a flight begins (a refused flight writes nothing)."""

    def __init__(self, path, clock=WallClock):
        self.path, self.clock = Path(path), clock
        self.f = None
        self.t0 = clock.now()
        self.last: dict[str, dict] = {}

    def begin(self, robots: dict[str, str], sync: int) -> None:
        if self.f is None:
            self.f = open(self.path, "a", buffering=1)
        self.t0 = self.clock.now()
        self.f.write(json.dumps({"flight": {"robots": robots, "sync": sync}}) + "\n")

    def __call__(self, robot: str, t_ms: int, data: dict) -> None:
        if self.f is None or self.f.closed:   # a packet still on its way when the flight ended
            return
        self.last.setdefault(robot, {}).update(data)
        host_ms = int(round((self.clock.now() - self.t0) * 1000.0))
        self.f.write(json.dumps({"robot": robot, "t_ms": t_ms, "host_ms": host_ms, **data}) + "\n")

    def close(self) -> None:
        if self.f is not None:
            self.f.close()


def preflight(robots: dict, swarm: Swarm, cfg, export_dir, plans: dict[str, bytes]) -> int:
    """Steps 1-5 (nothing flies yet); returns the sync sequence number."""
    expected, h = fingerprint.export_id(export_dir)
    for name, rb in robots.items():
        fingerprint.check(name, rb.param(fingerprint.PARAM) if rb.has_param(fingerprint.PARAM) else None, expected, h)
    for name, rb in robots.items():
        size = rb.trajectory_memory_size()
        if len(plans[name]) > size:
            raise Ns2Error(f"{name}: its plan has {len(plans[name]) // POLY4D_BYTES} pieces ({len(plans[name])} bytes), "
                           f"the robot's trajectory memory holds {size // POLY4D_BYTES} ({size} bytes): "
                           f"plan with longer pieces (ns2 plan --steps-per-piece)")
    by_name = {r.name: r for r in swarm.robots}
    for name in robots:
        x, y, _ = start_point(plans[name])
        x0, y0, _ = by_name[name].initial_position
        if max(abs(x - x0), abs(y - y0)) > START_TOLERANCE_M:
            raise Ns2Error(f"{swarm.path}: robots.{name}.initial_position: ({x0:g}, {y0:g}) but its plan starts at "
                           f"({x:.2f}, {y:.2f}): the robot would take off elsewhere")
    for name, rb in robots.items():
        for group, values in params(swarm, cfg, by_name[name]).items():
            for k, v in values.items():
                rb.set_param(f"{group}.{k}", v)
    seq = int(time.time()) & 0xFFFF_FFFF
    for rb in robots.values():
        rb.set_param("ns2.sync", seq)
    return seq


def _check(robots: dict, rec: Recorder, s: Settings) -> None:
    for name, rb in robots.items():
        if rb.lost.is_set():
            raise Abort(f"{name}: link lost")
        last = rec.last.get(name, {})
        if last.get("pm.vbat", 99.0) < s.min_battery_V:
            raise Abort(f"{name}: battery {last['pm.vbat']:.2f} V below {s.min_battery_V} V")
        if last.get("ns2.status", 0) < 0:
            raise Abort(f"{name}: app status {last['ns2.status']}")


def _wait(robots, rec, s: Settings, seconds: float, status, clock) -> None:
    end = clock.now() + seconds
    while clock.now() < end:
        _check(robots, rec, s)
        if status is not None:
            status(rec.last)
        clock.sleep(s.poll_s)


def land_all(robots: dict, s: Settings) -> list[str]:
    """Land every robot whose link still works; returns the ones that were told."""
    told = []
    for name, rb in robots.items():
        if not rb.lost.is_set():
            try:
                rb.land(s.land_s)
                told.append(name)
            except Exception:  # noqa: BLE001  one robot's failure must not keep the others up
                pass
    return told


def fly(robots: dict, swarm: Swarm, cfg, export_dir, plans: dict[str, bytes], log_path,
        s: Settings = Settings(), status=None, clock=WallClock, recorder: Recorder | None = None) -> dict:
    """The whole flight; returns a report.  Raises ``Abort`` (after landing) on the safety paths.
    ``status(last)`` is called at every poll with each robot's last logged values;
    ``recorder``: the caller's (kept open, e.g. to record a dry run's landing after an abort)."""
    seq = preflight(robots, swarm, cfg, export_dir, plans)
    pieces = {name: rb.upload(plans[name]) for name, rb in robots.items()}
    rec = recorder or Recorder(log_path, clock)
    types = {r.name: r.ns2_type for r in swarm.robots}
    rec.begin({name: types[name] for name in robots}, seq)
    try:
        for rb in robots.values():
            rb.start_logs(rec)
        try:
            for name, rb in robots.items():   # up to the plan's first point
                z = start_point(plans[name])[2]
                rb.takeoff(z if z >= 0.1 else s.takeoff_height_m, s.takeoff_s)
            _wait(robots, rec, s, s.takeoff_s, status, clock)
            for rb in robots.values():   # one burst, nothing between (group mask: ns2ground.cf.GROUP)
                rb.start()
            _wait(robots, rec, s, max(duration_s(p) for p in plans.values()), status, clock)
        except (Abort, KeyboardInterrupt) as e:
            told = land_all(robots, s)
            why = "Ctrl-C" if isinstance(e, KeyboardInterrupt) else str(e)
            raise Abort(f"flight ended early ({why}): landing {', '.join(told) or 'no robot (no link)'}; "
                        f"log {rec.path}") from e
        land_all(robots, s)
        _wait(robots, rec, s, s.land_s, status, clock)
        for rb in robots.values():
            rb.stop()
    finally:
        if recorder is None:
            rec.close()
    return {"sync": seq, "pieces": pieces, "log": str(rec.path)}
