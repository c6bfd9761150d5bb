"""``ns2 fly --sim``: the same mission (ground/mission.py), above the link, against
simulated robots (the project's C-in-the-loop simulator, ns2host.sim.cloop).

A ``SimRobot`` answers what a Crazyflie with the app built from the export would:
the parameters the app declares (its source), ``ns2.modelId`` is the low 32 bits of
``NS2_MODEL_ID`` read from the export's generated header (what the firmware built
from it carries), the trajectory memory has the stock firmware's size, parameters
are kept as set.  The mission's waits run on a virtual clock, and the simulator
flies in step with it: from the take-off command on, every ``sleep`` of the
mission flies the swarm that long in the simulator, as the high-level commander
would (hover at the take-off point, the uploaded poly4d pieces from the start
command on, a descent from the land command), with the robot types, gains and
learned-term switches the mission set, each robot under its radio id with the
type table the mission wrote (so its peers' types are looked up as the app looks
them up, whatever their ids); the robots' log packets (20 Hz, the
variables of ns2ground.cf.LOG_BLOCKS) reach the mission as they are flown.  So the
safety paths run as in a flight: ``Fault``s (``--sim-fault``) lose a robot's link
(it hears nothing more and flies its plan on), report a low battery or an app
status error from a time on, or press Ctrl-C (a real Ctrl-C also lands the dry
run), and the mission lands the swarm; ``finish`` flies the landing to its end.
It writes the same radio log (the mission's JSON lines) and what the robots' uSD
cards would hold (``flights.toml`` and one file per robot); ``ns2 logs-to-data``
reads both.

What a dry run does not rehearse: the radio (latency, retries), the take-off and
landing polynomials of the firmware's commander (hover and a cosine descent
instead).
"""
from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ns2codegen.vehicle import G
from ns2codegen.logs.align import PWM_FULL
from ns2plan.output import DEG, TRAJECTORY_MEMORY_BYTES, read_poly4d
from .swarm import ADAPT, GAIN1, GAIN3, TYPE_PARAMS, Swarm

LOG_EVERY = 5           # the simulator logs at 100 Hz; the radio log blocks run at 20 Hz
GROUND_Z = 0.03         # where a landing ends (m)


class Clock:
    """Virtual time for the mission's waits: ``sleep`` advances it (and the simulator
    with it, ``on_advance``); a pending interrupt (Ctrl-C) is raised there."""

    def __init__(self):
        self.t = 0.0
        self.on_advance = None
        self.interrupt = False

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += dt
        if self.on_advance is not None:
            self.on_advance(self.t)
        if self.interrupt:
            self.interrupt = False
            raise KeyboardInterrupt


FAULTS = ("lost-link", "low-battery", "app-status", "ctrl-c")
LOW_BATTERY_V = 3.0     # what a robot with a failing battery reports
APP_STATUS_ERROR = -3   # an app status below zero (ns2_pilot's error codes are negative)


@dataclass(frozen=True)
class Fault:
    """A fault of the dry run at ``at_s`` seconds after the first take-off command."""
    kind: str
    robot: str | None
    at_s: float

    @staticmethod
    def parse(text: str, robots) -> "Fault":
        """``KIND[:ROBOT]@SECONDS``, e.g. ``lost-link:cf7@3``, ``ctrl-c@2.5``."""
        m = re.fullmatch(r"([a-z-]+)(?::([^@]+))?@([0-9.]+)", text)
        if not m or m.group(1) not in FAULTS:
            raise ValueError(f"{text!r}: not KIND[:ROBOT]@SECONDS with KIND one of {', '.join(FAULTS)}")
        kind, robot, at = m.group(1), m.group(2), float(m.group(3))
        if (robot is None) != (kind == "ctrl-c"):
            raise ValueError(f"{text!r}: {'ctrl-c takes no robot' if kind == 'ctrl-c' else kind + ' needs :ROBOT'}")
        if robot is not None and robot not in robots:
            raise ValueError(f"{text!r}: {robot} is not an enabled robot ({', '.join(robots)})")
        return Fault(kind, robot, at)


def app_params() -> set[str]:
    """The parameters the app declares (PARAM_ADD[_WITH_CALLBACK] and NS2_GAIN3 in firmware/app/src/ns2_app.c)."""
    from ns2host.cbuild import REPO

    out, group = set(), None
    for line in (REPO / "firmware/app/src/ns2_app.c").read_text().splitlines():
        if m := re.match(r"PARAM_GROUP_START\((\w+)\)", line):
            group = m.group(1)
        elif m := re.match(r"PARAM_ADD(?:_WITH_CALLBACK)?\([^,]+, (\w+),", line):
            out.add(f"{group}.{m.group(1)}")
        elif m := re.match(r"NS2_GAIN3\((\w+)\)", line):
            out |= {f"{group}.{m.group(1)}{ax}" for ax in "xyz"}
    return out


def header_model_id(export_dir) -> int:
    """``ns2.modelId`` of an app built from the export: NS2_MODEL_ID & 0xFFFFFFFF."""
    text = (Path(export_dir) / "ns2_model_config.h").read_text()
    return int(re.search(r"#define NS2_MODEL_ID (0x[0-9a-fA-F]+)", text).group(1), 16) & 0xFFFF_FFFF


class SimRobot:
    """A simulated Crazyflie with the app, as ``ns2ground.cf.CfRobot`` is used by the mission."""

    def __init__(self, name: str, clock: Clock, model_id: int, names: set[str]):
        self.name, self.clock, self.names = name, clock, names
        self.lost = threading.Event()   # a simulated link is never lost
        self.params = {"ns2.modelId": model_id, "ns2.enable": 1, "ns2.fixed": 1}
        self.pieces: list = []
        self.commands: list[tuple[float, str, tuple]] = []
        self.log_cb = None

    def param(self, full: str):
        return self.params.get(full)

    def has_param(self, full: str) -> bool:
        return full in self.names

    def set_param(self, full: str, value) -> None:
        if full not in self.names or full == "ns2.modelId":
            raise ValueError(f"{self.name}: {full}: not a writable parameter of the app")
        self.params[full] = value

    def trajectory_memory_size(self) -> int:
        return TRAJECTORY_MEMORY_BYTES

    def upload(self, data: bytes) -> int:
        self.pieces = read_poly4d(data)
        return len(self.pieces)

    def _cmd(self, what: str, *args) -> None:
        if not self.lost.is_set():   # a robot without a link hears nothing
            self.commands.append((self.clock.now(), what, args))

    def takeoff(self, height: float, duration: float) -> None:
        self._cmd("takeoff", height, duration)

    def start(self) -> None:
        self._cmd("start")

    def land(self, duration: float) -> None:
        self._cmd("land", duration)

    def stop(self) -> None:
        self._cmd("stop")

    def start_logs(self, callback) -> None:
        self.log_cb = callback

    def when(self, what: str) -> float | None:
        return next((t for t, w, _ in self.commands if w == what), None)

    def gains(self) -> dict:
        g = {}
        for name in GAIN3:
            vals = [self.params.get(f"ns2gain.{name}{ax}") for ax in "xyz"]
            if all(v is not None for v in vals):
                g[name] = [float(v) for v in vals]
        g.update({k: float(self.params[f"ns2gain.{p}"]) for p, k in GAIN1.items() if f"ns2gain.{p}" in self.params})
        return g


def _adapt(params: dict):
    """The on-board adaptation's parameters a robot was given (PARAM ns2adapt, the app's boot
    values for the others) as an ns2codegen.onboard.AdaptCfg, or None when it is off
    (enable not 1) or a value is out of range (the app then flies the network alone, status
    BAD_PARAM; `ns2 swarm-params` refuses such a file)."""
    from ns2codegen.onboard import AdaptCfg, adapt_cfg_ok

    if int(params.get("ns2adapt.enable", 0)) != 1:
        return None
    cfg = AdaptCfg(**{f: float(params[f"ns2adapt.{p}"]) for p, f in ADAPT.items()
                      if p != "enable" and f"ns2adapt.{p}" in params})
    return cfg if adapt_cfg_ok(cfg) else None


def _eval(pieces, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """p, v, a of poly4d pieces at time t (held at the end), as pptraj.c evaluates them."""
    for d, c in pieces:
        if t <= d:
            break
        t -= d
    else:
        t = d  # after the last piece: its end, held
    s = min(max(t, 0.0), d)
    k = np.arange(DEG + 1)
    pw = s ** k
    dpw = np.concatenate([[0.0], k[1:] * s ** (k[1:] - 1)])
    ddpw = np.concatenate([[0.0, 0.0], k[2:] * (k[2:] - 1) * s ** (k[2:] - 2)])
    return c[:3] @ pw, c[:3] @ dpw, c[:3] @ ddpw


class SimSwarm:
    """The swarm file's enabled robots as ``SimRobot``s on one virtual clock, flown in
    the simulator in step with it."""

    def __init__(self, swarm: Swarm, export_dir, cfg, faults=(), seed: int = 0):
        self.swarm, self.export_dir, self.cfg, self.seed = swarm, Path(export_dir), cfg, seed
        self.clock = Clock()
        self.clock.on_advance = self._advance
        mid = header_model_id(export_dir)
        names = app_params()
        self.robots = {r.name: SimRobot(r.name, self.clock, mid, names) for r in swarm.enabled}
        self.faults = sorted(faults, key=lambda f: f.at_s)
        self.reports: dict[str, dict] = {}   # robot -> values it reports from a fault on
        self.sim = None
        self.t0 = self.flown = 0.0           # the simulation's start and end so far (mission time)
        self.logs: list[dict] = []
        self.samples = 0

    def _setpoints(self, start_pos: np.ndarray):
        from ns2host.sim.cloop import Setpoints

        rs = list(self.robots.values())

        def sp(t, state=None):
            T = self.t0 + t
            n = len(rs)
            p, v, a = start_pos.copy(), np.zeros((n, 3)), np.zeros((n, 3))
            for i, r in enumerate(rs):
                ts, tl = r.when("start"), r.when("land")
                if ts is not None and T >= ts:
                    p[i], v[i], a[i] = _eval(r.pieces, (min(T, tl) if tl is not None else T) - ts)
                    if tl is not None and T >= tl:
                        v[i], a[i] = 0.0, 0.0
                if tl is not None and T >= tl:
                    dur = next(args[0] for _, w, args in r.commands if w == "land")
                    z0 = p[i, 2]
                    s = min((T - tl) / dur, 1.0)
                    p[i, 2] = z0 + (GROUND_Z - z0) * 0.5 * (1.0 - np.cos(np.pi * s))
                    v[i, 2] = (GROUND_Z - z0) * 0.5 * np.pi / dur * np.sin(np.pi * s) if s < 1.0 else 0.0
            return Setpoints(p, v, a, np.zeros(n))

        return sp

    def _start(self) -> None:
        """The simulation, from the last take-off command: every robot hovering at its
        take-off point, the types, gains and switches the mission set."""
        from ns2host.sim.cloop import CLoopSwarm, NS2Controller, Robot

        rs = list(self.robots.values())
        by_name = {r.name: r for r in self.swarm.robots}
        types = [self.cfg.robot_types[int(r.params.get("ns2.selfType", 0))] for r in rs]
        # each robot's radio id, and its peers' types as its app looks them up: in the type
        # table the mission wrote (PARAM ns2type.t0..t15; all 0, the first type, if none was)
        ids = [by_name[r.name].radio_id for r in rs]
        tables = [[int(r.params.get(f"ns2type.{k}", 0)) for k in TYPE_PARAMS] for r in rs]
        height = {r.name: next(args[0] for _, w, args in r.commands if w == "takeoff") for r in rs}
        self.start_pos = np.array([[*by_name[r.name].initial_position[:2], height[r.name]] for r in rs])
        enable = [int(r.params.get("ns2.enable", 1)) for r in rs]
        learned = None if not any(enable) else ("fixed" if int(rs[0].params.get("ns2.fixed", 1)) else "float")
        self.types = types
        self.t0 = self.flown = max(r.when("takeoff") for r in rs)
        robots = [Robot(t, tuple(p), NS2Controller(learned, _adapt(r.params)), r.gains(), radio_id=i,
                        type_table=tuple(tab))
                  for t, p, r, i, tab in zip(types, self.start_pos, rs, ids, tables)]
        self.sim = CLoopSwarm(self.cfg, robots, self.export_dir, aero=True, seed=self.seed)

    def _fault(self, f: Fault) -> None:
        if f.kind == "ctrl-c":
            self.clock.interrupt = True
        elif f.kind == "lost-link":
            self.robots[f.robot].lost.set()
        else:
            self.reports.setdefault(f.robot, {}).update(
                {"pm.vbat": LOW_BATTERY_V} if f.kind == "low-battery" else {"ns2.status": APP_STATUS_ERROR})

    def _advance(self, t: float) -> None:
        """Fly the simulation up to mission time ``t``; the faults due by then happen."""
        while self.faults and self.faults[0].at_s <= t:
            self._fault(self.faults.pop(0))
        if self.sim is None:
            if any(r.when("takeoff") is None for r in self.robots.values()):
                return
            self._start()
        from ns2host.sim.cloop import ATT_HZ

        steps = int(np.floor((t - self.flown) * ATT_HZ + 1e-9))
        if steps <= 0:
            return
        log = self.sim.run(steps / ATT_HZ, self._setpoints(self.start_pos))
        self.flown += steps / ATT_HZ
        self.logs.append(log)
        for k in range(len(log["t"])):
            if (self.samples + k) % LOG_EVERY == 0:
                self._emit(log, k)
        self.samples += len(log["t"])

    def _emit(self, log: dict, k: int) -> None:
        """One log packet of every robot with a link (the variables of ns2ground.cf.LOG_BLOCKS)."""
        t_ms = int(round((self.t0 + log["t"][k]) * 1000.0))
        for i, r in enumerate(self.robots.values()):
            if r.lost.is_set() or r.log_cb is None:
                continue
            p, v, e = log["p"][k, i], log["v"][k, i], log["p"][k, i] - log["p_d"][k, i]
            q, pwm = log["q"][k, i], np.round(np.clip(log["pwm"][k, i], 0.0, 1.0) * PWM_FULL)
            data = {"ns2.faHat": float(log["fa_hat"][k, i, 2] * 1000.0 / G), "ns2.status": int(log["pilot_status"][k, i]),
                    "ns2.ex": float(e[0]), "ns2.ey": float(e[1]), "ns2.ez": float(e[2]),
                    "pm.vbat": float(log["battery_V"][k, i]), "ns2.ctrlStatus": int(log["status"][k, i]),
                    **{f"stateEstimate.{c}": float(x) for c, x in zip(("x", "y", "z", "vx", "vy", "vz"), (*p, *v))},
                    **{f"stateEstimate.q{c}": float(x) for c, x in zip("wxyz", q)},
                    **{f"motor.m{j + 1}": int(pwm[j]) for j in range(4)},
                    **{f"ns2adapt.{v}": float(log[f"adapt_{v}"][k, i]) for v in ("bias", "scale", "trP", "label")},
                    **{f"ns2adapt.{v}": int(log[f"adapt_{v}"][k, i]) for v in ("status", "lstatus")}}
            data.update(self.reports.get(r.name, {}))
            r.log_cb(r.name, t_ms, data)

    def finish(self, usd_dir=None, margin_s: float = 0.3) -> dict:
        """Fly on until every landing the robots were told of is over (after an abort the
        mission does not wait for it), write the uSD files to ``usd_dir``; returns the
        whole flight's arrays (cloop's log), empty when nothing took off."""
        from ns2host.sim import usdlogs

        ends = [t + (args[0] if w == "land" else 0.0) for r in self.robots.values() for t, w, args in r.commands]
        if ends:
            self.clock.t = max(self.clock.t, max(ends) + margin_s)
            self._advance(self.clock.t)
        if not self.logs:
            return {}
        log = {k: np.concatenate([x[k] for x in self.logs]) for k in self.logs[0] if k != "trace"}
        if usd_dir is not None:
            usd_dir = Path(usd_dir)
            usd_dir.mkdir(parents=True, exist_ok=True)
            usdlogs.write_manifest(usd_dir, [usdlogs.write_flight(usd_dir, "flight", self.types, log, self.seed)])
        return log
