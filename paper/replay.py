"""Replay a real flight in the simulator: the same team flies the logged setpoints
(``ctrltargetZ``: what the robots' high-level commanders sent to their controllers)
from the logged start, every robot as a Crazyflie (host/sim/cloop.py) with a learned f_a in
the loop (the collection of 16 June 2020 flew the authors' network: import it with
``ns2 real import-authors`` and export it; or fly the prediction the real robots
logged, learned="logged"), each robot on the supply voltage its real robot logged.
The simulated flight comes back as a
``Flight`` with the same time base and setpoints, so paper/flightstats.py measures
both the same way (the sim-to-real table, docs/simulator.md).

What is not the real flight: the controller is the project's (ns2_pilot with its
default gains), or with controller="authors" the position law and gains of the
authors' firmware controller (paper/c/ctrl_authors.c, gains.authors_gains) under the
project's attitude loop; the robots' masses and thrust maps are the config's (the
hover-measured masses of experiments/real.py when given its real.toml), and the
interactions are the simulator's ground truth."""
from __future__ import annotations

import numpy as np

from ns2codegen.config import Config
from ns2codegen.data.from_logs import Flight

from ns2codegen.vehicle import G
from ns2host.sim.cloop import CLoopSwarm, NS2Controller, Robot, Setpoints
from ns2host.sim.roughness import Roughness

from .controller import AuthorsController
from .flightstats import setpoint_derivatives
from .gains import authors_gains, read_law_gains


def pieces_by_flight(flights: list[Flight]) -> dict[str, list[Flight]]:
    """The usable pieces of each real flight (ns2codegen.logs cuts a flight at gaps)."""
    out: dict = {}
    for fl in flights:
        out.setdefault(fl.name, []).append(fl)
    return out


GRID_S = 0.01   # s: the replay's time base, the setpoints' and the prediction's


def _on_grid(pieces: list[Flight], field: str):
    """(grid, values [G, ...]) of one logged ``field`` ([T, N, ...]) of all the pieces
    joined on a GRID_S time base from the first logged sample, each column linear
    over its finite samples (across the cut gaps and missing ones)."""
    t = np.concatenate([p.t for p in pieces])
    x = np.concatenate([getattr(p, field) for p in pieces])
    order = np.argsort(t)
    t, x = t[order], x[order]
    grid = np.arange(t[0], t[-1] + 1e-9, GRID_S)
    flat = x.reshape(len(x), -1)
    cols = [np.interp(grid, t[ok], c[ok]) for c, ok in ((c, np.isfinite(c)) for c in flat.T)]
    return grid, np.stack(cols, 1).reshape((len(grid),) + x.shape[1:])


def _at(grid: np.ndarray, tau: float) -> int:
    """The grid index of the time tau (s) since the grid's start, held at its ends."""
    return int(np.clip(round(tau / GRID_S), 0, len(grid) - 1))


def logged_setpoints(pieces: list[Flight]):
    """(setpoints(t), start positions, t0, duration) of one real flight: the logged
    position setpoints of all its pieces joined (linear across the cut gaps), the
    velocity and acceleration setpoints their derivatives after a 0.1 s moving
    average (the setpoint is logged in millimetres)."""
    if any(p.p_d is None for p in pieces) or not all(np.isfinite(p.p_d).all() for p in pieces):
        raise ValueError(f"flight {pieces[0].name!r}: no complete position setpoint logged")
    grid, p = _on_grid(pieces, "p_d")
    v, a = setpoint_derivatives(grid, p)
    n = p.shape[1]

    def sp(tau, state=None):
        k = _at(grid, tau)
        return Setpoints(p[k], v[k], a[k], np.zeros(n))

    return sp, p[0], float(grid[0]), float(grid[-1] - grid[0])


def _logged(pieces: list[Flight], field: str, what: str):
    """``at(tau)`` -> [N]: a logged per-robot ``field`` ([T, N]) of all the pieces on the
    time base of logged_setpoints (tau = 0 at the first logged sample), linear across
    cut gaps and missing samples."""
    if any(getattr(p, field) is None for p in pieces):
        raise ValueError(f"flight {pieces[0].name!r}: no {what} logged")
    if not np.concatenate([np.isfinite(getattr(p, field)) for p in pieces]).any(axis=0).all():
        raise ValueError(f"flight {pieces[0].name!r}: a robot's {what} is never logged")
    grid, x = _on_grid(pieces, field)

    def at(tau):
        return x[_at(grid, tau)]

    return at


def logged_prediction(pieces: list[Flight]):
    """``fa(tau)`` -> [N] g: the on-board prediction each robot flew (ctrlFa.Faz)."""
    return _logged(pieces, "fa_onboard_g", "on-board prediction")


def logged_battery(pieces: list[Flight]):
    """``battery(tau)`` -> [N] V: each robot's logged supply voltage (pm.vbat)."""
    return _logged(pieces, "battery_V", "battery voltage")


BATTERIES = ("logged", "model")


def replay(cfg: Config, pieces: list[Flight], gen_dir, learned: str | None = "float",
           rough: Roughness | None = None, seed: int = 0, controller: str = "ns2",
           law: dict | None = None, battery: str = "logged") -> Flight:
    """Fly one real flight's setpoints with its team in the simulator; the drones'
    log as a Flight (time as the real flight's, estimated states, setpoints).
    controller: "ns2" (the project's) or "authors" (the one that flew it, each robot
    with its own gains: gains.authors_gains); learned: cloop.CLoopSwarm's, or
    "logged": the "authors" robots fly the prediction the real robots flew
    (logged_prediction), not a network of ``gen_dir``; law: with controller "authors",
    every robot flies the z law read off the real logs (vehicle.read_law_gains; READ_LAW's
    form) instead of its stored gains; battery: "logged", every robot flies on the supply
    voltage its real robot logged (flights of one collection ran from 3.2 to 3.9 V: the
    thrust of a PWM, and so the headroom, follows it), or "model": the simulator's own
    (``rough``'s sag, or the clean simulator's constant)."""
    if battery not in BATTERIES:
        raise ValueError(f"battery must be one of {BATTERIES}, got {battery!r}")
    if controller not in ("ns2", "authors"):
        raise ValueError(f"controller must be 'ns2' or 'authors', got {controller!r}")
    if learned == "logged" and controller != "authors":
        raise ValueError("learned='logged' is flown by controller='authors' only")
    sp, start, t0, duration = logged_setpoints(pieces)
    types = list(pieces[0].types)
    robots = pieces[0].robots or [None] * len(types)
    if law is not None and controller != "authors":
        raise ValueError("law is flown by controller='authors' only")
    if controller != "authors":
        authors = None
    elif law is not None:
        authors = [read_law_gains(t, law) for t in types]
    else:
        authors = [authors_gains(t, r) for t, r in zip(types, robots)]
    given = logged_prediction(pieces) if learned == "logged" else None
    own = None if given is not None else learned
    supply = logged_battery(pieces) if battery == "logged" else None

    def robot(i: int) -> Robot:   # robot i flies column i of the logged prediction and supply voltage
        ctrl = (NS2Controller(own) if controller == "ns2" else
                AuthorsController(authors[i], own, None if given is None else lambda t: given(t)[i]))
        return Robot(types[i], tuple(start[i]), ctrl, battery=3.9 if supply is None else lambda t: supply(t)[i])

    sw = CLoopSwarm(cfg, [robot(i) for i in range(len(types))], gen_dir, aero=True, seed=seed, rough=rough)
    log = sw.run(duration, sp)
    return Flight(types, log["t"] + t0, log["p"], log["v"], log["q"], log["pwm"], log["battery_V"],
                  name=pieces[0].name, p_d=log["p_d"], fa_onboard_g=log["fa_hat"][:, :, 2] * 1e3 / G,
                  robots=pieces[0].robots, w=log["w"])
