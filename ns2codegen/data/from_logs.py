"""Flight logs -> training data set (paper, "Data Collection").

A flight is a team of robots flown together; every robot's log (time, position,
velocity, attitude quaternion, motor PWM, battery voltage, on a common uniform
time base) gives labels f_a,z (``labels.residual_force``) and, at every labelled
time step, a sample whose neighbour set holds the other robots inside the
interaction volume V(type_i, type_j) plus the environment.  The scenario of a
sample is the mix of its robot's team (Table "data_collection": e.g. a small
robot flying with one large robot is "L->S").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import Config
from ..queries import Queries
from .dataset import Dataset, scenario_name
from ..selection import boxes_f32, clamp, env_state, membership, relative_state, volumes_f32
from .labels import G, five_point_derivative, residual_force


@dataclass
class Flight:
    types: list[str]        # robot type of each robot
    t: np.ndarray           # [T] s
    p: np.ndarray           # [T, N, 3]
    v: np.ndarray           # [T, N, 3]
    q: np.ndarray           # [T, N, 4]
    pwm: np.ndarray         # [T, N, 4] normalized
    battery_V: np.ndarray   # [T, N]
    labelled: list[bool] | None = None      # robots whose labels are used (default all); the others are neighbours only
    fa_onboard_g: np.ndarray | None = None  # [T, N] the on-board prediction flown, NaN where not logged
    name: str = ""
    p_d: np.ndarray | None = None           # [T, N, 3] the logged position setpoint, NaN where not logged
    robots: list[str] | None = None         # each robot's id (e.g. "cf100"), where known
    w: np.ndarray | None = None             # [T, N, 3] body rates (rad/s, the filtered gyro), NaN where not logged


def labelled_steps(cfg: Config, flights: list[Flight]):
    """(flight, robot i, time steps with a label, f_a [T, 3] N) of every labelled robot,
    in the order of the data set's samples."""
    for fl in flights:
        labelled = fl.labelled if fl.labelled is not None else [True] * len(fl.types)
        for i, ty in enumerate(fl.types):
            if not labelled[i]:
                continue
            veh = cfg.vehicle(ty)
            fa = residual_force(fl.t, fl.v[:, i], fl.q[:, i], fl.pwm[:, i], fl.battery_V[:, i],
                                veh["mass_g"] / 1000.0, veh["psi1"], veh["lambda"])
            yield fl, i, np.flatnonzero(~np.isnan(fa[:, 2])), fa


def candidates(cfg: Config, fl: Flight, i: int, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The neighbours robot i hands to the C at ``steps``: every other robot of the
    flight in flight order, types [T, S] and x_ij [T, S, 6] in float32 (``selection``)."""
    others = [j for j in range(len(fl.types)) if j != i]
    tidx = np.array([cfg.robot_types.index(t) for t in fl.types])
    rel = np.zeros((len(steps), len(others), 6), np.float32)
    for s, j in enumerate(others):
        rel[:, s] = relative_state(fl.p[steps, i], fl.v[steps, i], fl.p[steps, j], fl.v[steps, j])
    return np.broadcast_to(tidx[others], rel.shape[:2]).astype(np.int64), rel


def lag_steps(fl: Flight, history_ms: list[int]) -> list[int]:
    """Each lag of ``history_ms`` in log samples of ``fl`` (its uniform period)."""
    if not history_ms:
        return []
    h = float(np.median(np.diff(fl.t)))
    return [max(1, int(round(ms * 1e-3 / h))) for ms in history_ms]


def past_steps(cfg: Config, fl: Flight, steps: np.ndarray) -> list[np.ndarray]:
    """The samples ``model.history_ms`` before ``steps``, one array per lag: the flight
    piece's first sample where the piece is younger than the lag."""
    return [np.maximum(steps - lag, 0) for lag in lag_steps(fl, cfg.history_ms)]


def neighbor_rows(cfg: Config, fl: Flight, i: int, steps: np.ndarray):
    """The neighbour rows of robot i at time steps ``steps`` as the drone forms them
    (``ns2codegen.selection``: float32 relative states, the C's volume test, order
    and max_neighbors cut, inputs clamped to their boxes), environment last.  With
    the config's ``model.history_ms``, each row also holds the same neighbour's state
    that long before (6 values per lag, clamped to the same box; the flight piece's
    first sample where the piece is shorter): the selection is decided now.
    Returns (sample index into steps, neighbour type, x [rows, 6 (1 + lags)] float32)."""
    tidx = cfg.robot_types.index(fl.types[i])
    boxes = boxes_f32(cfg)
    ntype, rel = candidates(cfg, fl, i, steps)
    _, _, acc = membership(volumes_f32(cfg), np.full(len(steps), tidx), ntype, rel, np.ones(ntype.shape, bool),
                           cfg.num_robot_types, cfg.model["max_neighbors"])
    ts, ss = np.nonzero(acc)                                                   # by time, then slot order
    rob = [clamp(rel[ts, ss], boxes[ntype[ts, ss]])]
    env = [clamp(env_state(fl.p[steps, i], fl.v[steps, i]), boxes[cfg.env_index])]
    for past in past_steps(cfg, fl, steps):
        _, rel_past = candidates(cfg, fl, i, past)
        rob.append(clamp(rel_past[ts, ss], boxes[ntype[ts, ss]]))
        env.append(clamp(env_state(fl.p[past, i], fl.v[past, i]), boxes[cfg.env_index]))
    return (np.concatenate([ts, np.arange(len(steps))]),
            np.concatenate([ntype[ts, ss], np.full(len(steps), cfg.env_index)]),
            np.concatenate([np.concatenate(rob, 1), np.concatenate(env, 1)]))


def flight_queries(cfg: Config, flights: list[Flight]) -> Queries:
    """The data set's samples (``flights_to_dataset``, same order) as the C API
    receives them: own state in float32 and every other robot as a neighbour; with
    ``model.history_ms`` every neighbour's x_ij also at each lag and the robot's own
    [p; v] at each lag (ns2_predict_*_hist), the samples of ``past_steps``."""
    parts = []
    for fl, i, steps, _ in labelled_steps(cfg, flights):
        ntype, rel = candidates(cfg, fl, i, steps)
        past = past_steps(cfg, fl, steps)
        rel = np.concatenate([rel] + [candidates(cfg, fl, i, ps)[1] for ps in past], -1)
        own = np.stack([np.concatenate([fl.p[ps, i], fl.v[ps, i]], -1) for ps in past], 1) if past \
            else np.zeros((len(steps), 0, 6))
        parts.append(Queries(np.full(len(steps), cfg.robot_types.index(fl.types[i]), np.uint8),
                             fl.p[steps, i].astype(np.float32), fl.v[steps, i].astype(np.float32),
                             np.full(len(steps), ntype.shape[1], np.int64), ntype.astype(np.uint8), rel,
                             own.astype(np.float32)))
    return Queries.concat(parts)


WAKE_DZ_M = (0.1, 0.6)   # a neighbour this much higher is "above" (the swaps' passages)


def sample_info(cfg: Config, flights: list[Flight], dz_m: tuple = WAKE_DZ_M) -> dict:
    """Per sample of ``flights_to_dataset`` (same order), what a score needs beyond the
    data set: ``flight`` (index into ``flight_names``), ``robot`` (index into
    ``robot_ids``, one per flight name and robot), ``t_s`` (the flight's own clock),
    ``onboard_g`` (the prediction flown, NaN where not logged), ``load_factor``
    ((v_dot_z + g) / g: d label / d mass, to relabel with another mass exactly), and
    ``above_xy_m`` (the horizontal distance to the nearest other robot ``dz_m`` higher,
    inf when none is)."""
    names: list[str] = []
    robots: list[str] = []
    cols: dict = {k: [] for k in ("flight", "robot", "t_s", "onboard_g", "load_factor", "above_xy_m")}
    for fl, i, steps, _ in labelled_steps(cfg, flights):
        if fl.name not in names:
            names.append(fl.name)
        rid = f"{fl.name}#{fl.robots[i] if fl.robots else i}"
        if rid not in robots:
            robots.append(rid)
        h = float(np.median(np.diff(fl.t)))
        vdot = five_point_derivative(fl.v[:, i, 2], h)
        above = np.full(len(steps), np.inf)
        for j in range(len(fl.types)):
            if j == i:
                continue
            d = fl.p[steps, j] - fl.p[steps, i]
            xy = np.hypot(d[:, 0], d[:, 1])
            above = np.where((d[:, 2] >= dz_m[0]) & (d[:, 2] <= dz_m[1]), np.minimum(above, xy), above)
        cols["flight"].append(np.full(len(steps), names.index(fl.name)))
        cols["robot"].append(np.full(len(steps), robots.index(rid)))
        cols["t_s"].append(fl.t[steps])
        cols["onboard_g"].append(fl.fa_onboard_g[steps, i] if fl.fa_onboard_g is not None
                                 else np.full(len(steps), np.nan))
        cols["load_factor"].append((vdot[steps] + G) / G)
        cols["above_xy_m"].append(above)
    out = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    out["flight"], out["robot"] = out["flight"].astype(np.int64), out["robot"].astype(np.int64)
    return dict(out, flight_names=names, robot_ids=robots)


def flights_to_dataset(cfg: Config, flights: list[Flight], scenario_names: list[str] | None = None) -> Dataset:
    names = list(scenario_names or [])
    robot_type, label, scenario, time_s = [], [], [], []
    rows_sample, rows_type, rows_state = [], [], []
    n_samples = 0
    t_offset, last = 0.0, None
    for fl, i, steps, fa in labelled_steps(cfg, flights):
        if last is not None and fl is not last:
            t_offset += float(last.t[-1] - last.t[0]) + 1.0  # flights follow each other in time
        last = fl
        ty = fl.types[i]
        name = scenario_name(cfg.robot_types, ty, [fl.types[j] for j in range(len(fl.types)) if j != i])
        if name not in names:
            names.append(name)
        k = len(steps)
        robot_type.append(np.full(k, cfg.robot_types.index(ty)))
        label.append(fa[steps, 2] * 1000.0 / G)
        scenario.append(np.full(k, names.index(name)))
        time_s.append(fl.t[steps] + t_offset)
        s_idx, n_type, x = neighbor_rows(cfg, fl, i, steps)
        rows_sample.append(n_samples + s_idx)
        rows_type.append(n_type)
        rows_state.append(x)
        n_samples += k
    sample_of = np.concatenate(rows_sample) if rows_sample else np.zeros(0, np.int64)
    types = np.concatenate(rows_type) if rows_type else np.zeros(0, np.int64)
    states = np.concatenate(rows_state) if rows_state else np.zeros((0, cfg.input_dim), np.float32)
    order = np.lexsort((types, sample_of))  # by sample, then type (environment last); stable within a type
    counts = np.bincount(sample_of, minlength=n_samples)
    offsets = np.zeros(n_samples + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    cat = lambda a, dt: np.concatenate(a).astype(dt) if a else np.zeros(0, dt)  # noqa: E731
    ds = Dataset(cat(robot_type, np.int64), cat(label, np.float32), cat(scenario, np.int64), cat(time_s, np.float64),
                 offsets, types[order].astype(np.int64), states[order].astype(np.float32),
                 cfg.neighbor_types, names, {"generator": "flight-logs"})
    return ds.validated()
