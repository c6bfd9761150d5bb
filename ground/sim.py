"""``ns2 fly --sim``: the same mission (ground/mission.py), above the link, against
simulated robots (the project's C-in-the-loop simulator, ns2host.sim.cloop).

A ``SimRobot`` answers what a Crazyflie with the app built from the export would:
the parameters the app declares (its source), ``ns2.modelId`` is the low 32 bits of ``NS2_MODEL_ID`` read from the export's
generated header (what the firmware built from it carries), the trajectory memory
has the stock firmware's size, parameters are kept as set.  The mission's waits run
on a virtual clock; the commands (take off, start, land, stop) are recorded with
their times.  ``SimSwarm.fly`` then flies those commands in the simulator, as the
high-level commander would (hover at the take-off point, the uploaded poly4d
pieces from the start command on, a descent from the land command), with the robot
types, gains and learned-term switches the mission set, and writes the same radio
log (the mission's JSON lines) and what the robots' uSD cards would hold
(``flights.toml`` and one file per robot, read by ``ns2 logs-to-data``).

What a dry run does not rehearse: the radio (links, retries), the take-off and
landing polynomials of the firmware's commander (hover and a cosine descent
instead), and the safety paths during the flight (the log arrives after it).
"""
from __future__ import annotations

import re
import threading
from pathlib import Path

import numpy as np

from ns2codegen.vehicle import G
from ns2plan.output import DEG, TRAJECTORY_MEMORY_BYTES, read_poly4d
from .swarm import GAIN1, GAIN3, Swarm

LOG_EVERY = 5           # the simulator logs at 100 Hz; the radio log blocks run at 20 Hz
GROUND_Z = 0.03         # where a landing ends (m)


class Clock:
    """Virtual time for the mission's waits: ``sleep`` only advances it."""

    def __init__(self):
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += dt


def app_params() -> set[str]:
    """The parameters the app declares (PARAM_ADD and NS2_GAIN3 in firmware/app/src/ns2_app.c)."""
    from ns2host.cbuild import REPO

    out, group = set(), None
    for line in (REPO / "firmware/app/src/ns2_app.c").read_text().splitlines():
        if m := re.match(r"PARAM_GROUP_START\((\w+)\)", line):
            group = m.group(1)
        elif m := re.match(r"PARAM_ADD\([^,]+, (\w+),", line):
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
    """The swarm file's enabled robots as ``SimRobot``s on one virtual clock."""

    def __init__(self, swarm: Swarm, export_dir):
        self.swarm, self.export_dir = swarm, Path(export_dir)
        self.clock = Clock()
        mid = header_model_id(export_dir)
        names = app_params()
        self.robots = {r.name: SimRobot(r.name, self.clock, mid, names) for r in swarm.enabled}

    def _setpoints(self, t0: float, start_pos: np.ndarray):
        from ns2host.sim.cloop import Setpoints

        rs = list(self.robots.values())

        def sp(t, state=None):
            T = t0 + t
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

    def fly(self, cfg, recorder, usd_dir=None, seed: int = 0) -> dict:
        """Fly the recorded commands in the simulator; every log record to ``recorder``,
        the uSD files to ``usd_dir``.  Returns the flight's arrays (cloop's log)."""
        from ns2host.sim.cloop import CLoopSwarm
        from ns2host.sim import usdlogs

        rs = list(self.robots.values())
        if any(r.when("takeoff") is None for r in rs):
            return {}
        by_name = {r.name: r for r in self.swarm.robots}
        types = [cfg.robot_types[int(r.params.get("ns2.selfType", 0))] for r in rs]
        takeoff = {r.name: next(args for _, w, args in r.commands if w == "takeoff") for r in rs}
        t0 = max(r.when("takeoff") + takeoff[r.name][1] for r in rs)   # every robot up: the simulation starts
        start = np.array([[*by_name[r.name].initial_position[:2], takeoff[r.name][0]] for r in rs])
        end = max(t for r in rs for t, _, _ in r.commands)
        enable = [int(r.params.get("ns2.enable", 1)) for r in rs]
        learned = None if not any(enable) else ("fixed" if int(rs[0].params.get("ns2.fixed", 1)) else "float")
        sim = CLoopSwarm(cfg, types, self.export_dir, start, learned=learned, aero=True,
                         gains=[r.gains() for r in rs], seed=seed)
        log = sim.run(max(end - t0, 0.1), self._setpoints(t0, start))
        for k in range(0, len(log["t"]), LOG_EVERY):
            t_ms = int(round((t0 + log["t"][k]) * 1000.0))
            for i, r in enumerate(rs):
                p, v, e = log["p"][k, i], log["v"][k, i], log["p"][k, i] - log["p_d"][k, i]
                recorder(r.name, t_ms, {
                    "ns2.faHat": float(log["fa_hat"][k, i, 2] * 1000.0 / G), "ns2.ctrlStatus": int(log["status"][k, i]),
                    "ns2.ex": float(e[0]), "ns2.ey": float(e[1]), "ns2.ez": float(e[2]),
                    "pm.vbat": float(log["battery_V"][k, i]), "stateEstimate.x": float(p[0]),
                    "stateEstimate.y": float(p[1]), "stateEstimate.z": float(p[2]), "stateEstimate.vx": float(v[0]),
                    "stateEstimate.vy": float(v[1]), "stateEstimate.vz": float(v[2])})
        if usd_dir is not None:
            usd_dir = Path(usd_dir)
            usd_dir.mkdir(parents=True, exist_ok=True)
            usdlogs.write_manifest(usd_dir, [usdlogs.write_flight(usd_dir, "flight", types, log, seed)])
        return log
