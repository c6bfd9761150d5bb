"""Data collection in the simulator, as in the paper: teams of 1-3 robots of every
type mix fly random walks (with ground contact height included) and swaps, and
optionally every pair of robot types flies close-range passes (``near_field``:
one robot slowly under the other at vertical gaps from the collision distance to
1.2 m, the near-field downwash that swaps only cross in a tenth of a second) and
flights in which one robot of the pair moves under and over the other, hovering
one (``who``: the truth depends on each robot's own velocity), also with a third
robot hovering nearby; the
drones' logs (their EKF's estimates, from noisy sensors) become a training set through the same path as
real logs (ns2codegen.data.from_logs), never through the ground truth."""
from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import numpy as np

from ns2codegen.config import Config
from ns2codegen.data.dataset import Dataset
from ns2codegen.data.from_logs import Flight, flights_to_dataset
from ns2codegen.executor import run_map

from .cloop import CLoopSwarm, NS2Controller, robots_of
from .roughness import Roughness
from .scenarios import near_field, random_walk, swap, who_moves, who_moves_bystander
from .usdlogs import write_flight, write_manifest


def teams(cfg: Config, max_size: int = 3) -> list[tuple[str, ...]]:
    """Every multiset of 1..max_size robot types (for two types: S, L, SS, SL, LL,
    SSS, SSL, SLL, LLL), which yields all 12 scenarios of Table data_collection."""
    out = []
    for n in range(1, max_size + 1):
        out += list(itertools.combinations_with_replacement(cfg.robot_types, n))
    return out


def bystander_teams(cfg: Config) -> list[tuple[str, str, str]]:
    """Every pair of types with every type hovering beside it (robot 2 of a ``who``
    flight of three): SS+S, SS+L, SL+S, SL+L, LL+S, LL+L for two types."""
    return [(a, b, c) for a, b in itertools.combinations_with_replacement(cfg.robot_types, 2)
            for c in cfg.robot_types]


def flight_log(cfg: Config, team, gen_dir, kind: str, duration: float, seed: int, learned=None,
               near_gap_max: float = 1.2, rough: Roughness | None = None) -> dict:
    """Fly one scenario of ``kind`` with ``team``; the simulator's log (CLoopSwarm.run: the
    drones' estimates and, apart, the ground truth), cut before a crash (crash_cut)."""
    n = len(team)
    if kind == "swap":
        heights = 0.4 + 0.25 * np.arange(n)
        sp, start = swap(n, heights, radius=0.4, duration=2.5, rest=0.5, seed=seed)
    elif kind in ("near", "who"):
        if n != 2 and not (kind == "who" and n == 3):
            raise ValueError(f"{kind} flights are for pairs of robots" + (" or teams of three" if kind == "who" else "")
                             + f", got a team of {n}")
        diameters = [cfg.vehicle(t).get("diameter_m", 0.12) for t in team]
        if kind == "near":
            sp, start, _ = near_field(list(team), diameters, duration, gap_max=near_gap_max, seed=seed)
        elif n == 3:
            sp, start, _, _ = who_moves_bystander(diameters, duration, gap_max=near_gap_max, seed=seed)
        else:
            sp, start, _, _ = who_moves(diameters, duration, gap_max=near_gap_max, seed=seed)
    elif kind == "random":
        sp, start = random_walk(n, seed=seed)
    else:
        raise ValueError(f"unknown flight kind {kind!r}: random, swap, near or who")
    sw = CLoopSwarm(cfg, robots_of(list(team), start, NS2Controller(learned)), gen_dir, aero=True, seed=seed,
                    rough=rough)
    log = sw.run(duration, sp)
    n_keep = crash_cut(log["t"], log["truth_p"])
    if n_keep < len(log["t"]):
        warnings.warn(f"{kind} flight of {'+'.join(team)} (seed {seed}): a robot crashed "
                      f"{CRASH_MARGIN_S:.0f} s after t = {log['t'][n_keep]:.2f} s; the log is cut there")
    return {k: np.asarray(v)[:n_keep] if k != "trace" else v for k, v in log.items()}


def fly(cfg: Config, team, gen_dir, kind: str, duration: float, seed: int, learned=None,
        near_gap_max: float = 1.2, rough: Roughness | None = None) -> Flight:
    """``flight_log`` as the drones log it: the EKF's estimates (labels from estimated
    states, as on the real drone) and the setpoints."""
    log = flight_log(cfg, team, gen_dir, kind, duration, seed, learned, near_gap_max, rough)
    return Flight(list(team), *(log[k] for k in ("t", "p", "v", "q", "pwm", "battery_V")), p_d=log["p_d"])


CRASH_MARGIN_S = 1.0  # s of log dropped before a crash (the loss of control before it)


def crash_cut(t, truth_p) -> int:
    """How many log rows to keep: all, or those up to CRASH_MARGIN_S before the first
    row at which a robot's true position is below the floor (a crash; as after a real
    crash, the rest of the flight's log is useless for learning)."""
    t = np.asarray(t)
    down = np.nonzero((np.asarray(truth_p)[..., 2] < 0.0).any(axis=1))[0]
    if down.size == 0:
        return len(t)
    return int(np.searchsorted(t, t[down[0]] - CRASH_MARGIN_S))


def collect(cfg: Config, gen_dir, seconds_per_team: float, seed: int = 0, learned=None,
            team_list=None, usd_dir=None, near_field_seconds: float = 0.0, near_gap_max: float = 1.2,
            who_moves_seconds: float = 0.0, progress=None, workers: int = 1,
            rough: Roughness | None = None) -> Dataset:
    """Half random walk, half swaps per team (single robots only random walk), plus
    ``near_field_seconds`` of close-range passes per pair of robots (vertical gaps up
    to ``near_gap_max``) and ``who_moves_seconds`` of one robot moving past the
    other, hovering one (same gaps), per pair and per team of three (robots 0 and 1,
    robot 2 hovering nearby: ``bystander_teams`` gives every combination); with
    ``usd_dir`` the (noisy) logs are also written there as Crazyflie uSD files with a
    flights.toml, the input of ``ns2 logs-to-data``.  ``progress(1)`` after every flight.
    ``workers`` > 1 flies that many flights at once in forked processes (same flights,
    same seeds, same data set); ``rough``: the rough simulator (host/sim/roughness.py;
    None: the clean one), where a flight longer than one battery charge
    (``Roughness.flight_limit_s``) is flown as several equal flights."""
    jobs = []
    for k, team in enumerate(team_list or teams(cfg)):
        kinds = ["random"] if len(team) == 1 else ["random", "swap"]
        plan = [(kind, seconds_per_team / len(kinds)) for kind in kinds if seconds_per_team > 0]
        if len(team) == 2:
            plan += [(kind, sec) for kind, sec in (("near", near_field_seconds), ("who", who_moves_seconds)) if sec > 0]
        elif len(team) == 3 and who_moves_seconds > 0:
            plan.append(("who", who_moves_seconds))
        jobs += [(team, kind, sec, s) for j, (kind, seconds) in enumerate(plan)
                 for sec, s in _charges(seconds, seed * 1000 + 10 * k + j, rough)]
    flights = fly_many(fly, [(cfg, team, gen_dir, kind, sec, s, learned, near_gap_max, rough)
                             for team, kind, sec, s in jobs], gen_dir, workers, progress)
    if usd_dir is not None:
        entries = [write_flight(Path(usd_dir), f"{''.join(t[0] for t in team)}_{kind}_{s}", list(team),
                                fl.__dict__, seed=s) for (team, kind, _, s), fl in zip(jobs, flights)]
        write_manifest(Path(usd_dir), entries)
    return flights_to_dataset(cfg, flights)


def _charges(seconds: float, seed: int, rough: Roughness | None) -> list[tuple[float, int]]:
    """(duration, seed) of the flights that fly ``seconds`` on full batteries: one flight
    (this seed) if it fits in a charge, else n equal ones, the first with this seed."""
    limit = rough.flight_limit_s() if rough is not None else np.inf
    n = max(1, int(np.ceil(seconds / limit))) if seconds > 0 else 1
    return [(seconds / n, seed + 1_000_000 * c) for c in range(n)]


def fly_many(fn, args: list, gen_dir, workers: int = 1, progress=None) -> list:
    """[fn(*a) for a in args] (flights: fly or flight_log), ``workers`` at once in forked
    processes (the same results in the same order); ``progress(1)`` after each."""
    if workers > 1 and len(args) > 1:
        from ..cfhost import load_fly
        load_fly(gen_dir)                             # build once, before the workers load it
    return run_map(fn, args, workers, progress)
