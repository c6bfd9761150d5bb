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
from .dataset import Dataset, scenario_name
from .labels import G, residual_force


@dataclass
class Flight:
    types: list[str]        # robot type of each robot
    t: np.ndarray           # [T] s
    p: np.ndarray           # [T, N, 3]
    v: np.ndarray           # [T, N, 3]
    q: np.ndarray           # [T, N, 4]
    pwm: np.ndarray         # [T, N, 4] normalized
    battery_V: np.ndarray   # [T, N]


def flights_to_dataset(cfg: Config, flights: list[Flight], scenario_names: list[str] | None = None) -> Dataset:
    names = list(scenario_names or [])
    robot_type, label, scenario, time_s = [], [], [], []
    rows_sample, rows_type, rows_state = [], [], []
    n_samples = 0
    t_offset = 0.0
    for fl in flights:
        n = len(fl.types)
        tidx = np.array([cfg.robot_types.index(t) for t in fl.types])
        fa = np.stack([residual_force(fl.t, fl.v[:, i], fl.q[:, i], fl.pwm[:, i], fl.battery_V[:, i],
                                      cfg.vehicle(ty)["mass_g"] / 1000.0, cfg.vehicle(ty)["psi1"],
                                      cfg.vehicle(ty)["lambda"]) for i, ty in enumerate(fl.types)], 1)
        ok = ~np.isnan(fa[:, 0, 2])
        steps = np.flatnonzero(ok)
        for i in range(n):
            name = scenario_name(cfg.robot_types, fl.types[i], [fl.types[j] for j in range(n) if j != i])
            if name not in names:
                names.append(name)
            base = n_samples
            k = len(steps)
            robot_type.append(np.full(k, tidx[i]))
            label.append(fa[steps, i, 2] * 1000.0 / G)
            scenario.append(np.full(k, names.index(name)))
            time_s.append(fl.t[steps] + t_offset)
            sample_ids = base + np.arange(k)
            for j in range(n):
                if j == i:
                    continue
                rel = np.concatenate([fl.p[steps, j] - fl.p[steps, i], fl.v[steps, j] - fl.v[steps, i]], 1)
                lo, hi = cfg.volume(tidx[i], tidx[j])
                inside = np.all((rel[:, :3] >= lo) & (rel[:, :3] <= hi), axis=1)
                rows_sample.append(sample_ids[inside])
                rows_type.append(np.full(inside.sum(), tidx[j]))
                rows_state.append(rel[inside])
            rows_sample.append(sample_ids)
            rows_type.append(np.full(k, cfg.env_index))
            rows_state.append(np.concatenate([-fl.p[steps, i], -fl.v[steps, i]], 1))
            n_samples += k
        t_offset += float(fl.t[-1] - fl.t[0]) + 1.0  # flights follow each other in time
    sample_of = np.concatenate(rows_sample)
    types = np.concatenate(rows_type)
    order = np.lexsort((types, sample_of))  # by sample, then type (environment last)
    counts = np.bincount(sample_of, minlength=n_samples)
    offsets = np.zeros(n_samples + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    ds = Dataset(np.concatenate(robot_type).astype(np.int64), np.concatenate(label).astype(np.float32),
                 np.concatenate(scenario).astype(np.int64), np.concatenate(time_s),
                 offsets, types[order].astype(np.int64), np.concatenate(rows_state)[order].astype(np.float32),
                 cfg.neighbor_types, names, {"generator": "flight-logs"})
    return ds.validated()
