"""The simulator calibrated on the real flights of 16 June 2020 (``ns2 sim calibrate``):

1. measure the real roughness (paper/flightstats.py on the collection's logs);
2. fit host/sim/roughness.py's parameters to it, each from its own statistic:
   battery (the logged voltage), thrust scatter (the robots' hover thrust within a
   type), IMU vibration (replays of the pair random walks as they flew, the authors'
   controller flying the logged prediction, against the same real flights' free air:
   the fast part of the residual rises with the accelerometer's noise, the
   motor-command noise with the gyro's, each in quadrature), the wake's profile (fit_wake: the
   truth at the logged states of robots under a neighbour against their labels, no
   replay), the wake's lateral push per receiving type (fit_lateral: replays of the
   pair swaps as they flew, the labels' reading of the push, lateral_k_xy, matched to
   the real one), wake turbulence (replays of the pair swaps with the other effects on:
   the real scatter under a neighbour beyond the simulator's, per unit of the
   wake's force; tau from its fast share); and the z
   law that flew (fit_read_law: the authors' law with the gains, the share of the
   prediction taken off and the mass parameter with which replays read back what the
   real swaps read, flightstats.z_law); the fit is written as parameter files
   (rough.toml, read_law.toml: the form of host/sim/params/ and paper/params/) beside the report;
3. replay the real swap flights in the clean and the rough simulator (VARIANTS:
   the project's controller or the authors', with its stored gains or the z law read
   off the logs, the authors' published network in the loop or the prediction the
   real robots logged; paper/replay.py) and compare
   every statistic of step 1, with the truth's lateral constant read off the labels
   on both sides (lateral_k_xy): the calibration table and the sim-to-real swap table.
No swap or ring result of the paper is a fitting target."""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from ns2codegen.config import Config
from ns2codegen.data.from_logs import Flight
from ns2codegen.fileio import atomic_write_files
from ns2codegen.results import commit as source_commit, stamp
from ns2codegen.executor import run_map

from ns2host.sim.cloop import CLoopSwarm, robots_of
from ns2host.sim.roughness import EFFECTS, Roughness, dump_roughness, hp_share
from ns2host.sim.scenarios import random_walk
from ns2host.sim.vehicle import G
from ns2paper import flightstats as fs
from ns2paper.gains import AUTHORS_GAINS, AUTHORS_TYPE, READ_LAW, dump_read_law
from ns2paper.replay import pieces_by_flight, replay


# neural-swarm2.tex, flight tests: "in the L2S case [...] the median z-error is reduced
# from 17 cm to 7 cm" (real flights, BL -> NN, the authors' controller on every robot)
PAPER_L2S_M = {"BL-authors": 0.17, "NN-authors": 0.07}
PROBE = {"seconds": 30.0, "cube": ((-1.0, 1.0), (-1.0, 1.0), (0.6, 1.4)), "seed": 1}
PAIR_SWAPS = ("swap_ss", "swap_sl", "swap_ll")
FIT_FLIGHTS_PER_PAIR = 3      # pair swap flights replayed for the lateral and turbulence fits (the first by name)
READ_LAW_FLIGHTS_PER_FOLDER = 2   # swap flights per folder replayed for the fit of the z law read off the logs
READ_LAW_ITERATIONS = 4
LAW_KEYS = (("kp", "kp_per_s2"), ("kd", "kd_per_s"), ("ki", "ki_per_s3"), ("k_fa", "k_fa"))


def swap_flights(flights: list[Flight]) -> list[Flight]:
    return [f for f in flights if f.name.startswith("swap_")]


def real_statistics(cfg: Config, flights: list[Flight]) -> dict:
    """Step 1 on the real collection: free air and battery over every flight, the wake
    scatter and the swap errors over the swap flights."""
    sw = swap_flights(flights)
    return {"free_air": fs.free_air(cfg, flights), "battery": fs.battery(flights),
            "wake_scatter": fs.wake_scatter(cfg, sw), "swaps": fs.swap_errors(sw)}


def probe_flight(cfg: Config, gen_dir, robot_type: str, rough: Roughness | None) -> Flight:
    """One robot's random walk (PROBE) in the simulator on its own battery, as the drone
    logs it."""
    sp, start = random_walk(1, cube=PROBE["cube"], seed=PROBE["seed"])
    sw = CLoopSwarm(cfg, robots_of([robot_type], start), gen_dir, aero=True, rough=rough, seed=PROBE["seed"])
    log = sw.run(PROBE["seconds"], sp)
    return Flight([robot_type], *(log[k] for k in ("t", "p", "v", "q", "pwm", "battery_V")), p_d=log["p_d"])


FREE_AIR_WALKS = ("randomwalk_ss", "randomwalk_sl", "randomwalk_ll")   # the pair random walks: free-air stretches
FREE_AIR_FLIGHTS_PER_PAIR = 2   # of each, the first ones by name, replayed for the vibration fit and the free-air rows
VIBRATION_PROBE = {"acc_g": 0.1, "gyro_dps": 2.0}


def free_air_pieces(flights: list[Flight]) -> dict:
    """The real flights whose free-air stretches the vibration fit and the calibration
    table's free-air rows replay: FREE_AIR_FLIGHTS_PER_PAIR of each pair random walk
    (the robots apart and above 0.4 m for most of a minute; the collection's one-robot
    walks fly in ground effect, below 0.4 m)."""
    by = pieces_by_flight(flights)
    return {n: by[n] for n in first_per_folder(by, FREE_AIR_FLIGHTS_PER_PAIR, FREE_AIR_WALKS)}


def _quadrature(real: float, base: float, probed: float, probe_value: float) -> float:
    """x such that real^2 = base^2 + (probed^2 - base^2) (x / probe_value)^2 (0 if the
    simulator is already as rough)."""
    gain = (probed ** 2 - base ** 2) / probe_value ** 2
    if gain <= 0:
        raise ValueError(f"the probe did not raise the statistic ({base} -> {probed})")
    return math.sqrt(max(real ** 2 - base ** 2, 0.0) / gain)


def fit_vibration(cfg: Config, gen_dir, flights: list[Flight], base: Roughness,
                  workers: int = 1) -> tuple[dict, dict, dict]:
    """Accelerometer and gyro vibration per robot type: replays of the pair random walks
    (free_air_pieces) flown as the real ones were (the authors' controller with its
    stored gains, the prediction the real robots logged, their logged battery), the
    free-air statistics (flightstats.free_air) of the same flights real and replayed,
    each in quadrature: the fast part of the residual on the accelerometer's noise
    (without vibration, then a probe), then the motor-command noise on the gyro's
    (without gyro vibration, a probe, then again with the first answer as the probe:
    the motors clip).  The turbulence is off: it is fitted after the vibration, on it,
    so the fit does not depend on the turbulence default it starts from."""
    base = base.without("turbulence")
    pieces = free_air_pieces(flights)
    real = fs.free_air(cfg, [p for ps in pieces.values() for p in ps])
    for ty in cfg.robot_types:
        if ty not in real or real[ty]["fast_std_g"] is None:
            raise ValueError(f"no free-air stretch of a {ty} robot in the pair random walks")
    steps = []

    def fly(acc: dict, gyro: dict) -> dict:
        rough = replace(base, vibration_acc_g={**base.vibration_acc_g, **acc},
                        vibration_gyro_dps={**base.vibration_gyro_dps, **gyro})
        sim = fs.free_air(cfg, replay_all(cfg, gen_dir, pieces, rough, workers, controller="authors", learned="logged"))
        steps.append({"acc_g": acc, "gyro_dps": gyro, "free_air": sim})
        return sim

    zero = {ty: 0.0 for ty in cfg.robot_types}
    calm = fly(zero, zero)
    pa = {ty: VIBRATION_PROBE["acc_g"] for ty in cfg.robot_types}
    shaken = fly(pa, zero)
    acc = {ty: round(_quadrature(real[ty]["fast_std_g"], calm[ty]["fast_std_g"], shaken[ty]["fast_std_g"], pa[ty]), 4)
           for ty in cfg.robot_types}
    calm = fly(acc, zero)
    gyro = {ty: VIBRATION_PROBE["gyro_dps"] for ty in cfg.robot_types}
    for _ in range(2):
        probed = fly(acc, gyro)
        gyro = {ty: round(_quadrature(real[ty]["motor_noise"], calm[ty]["motor_noise"], probed[ty]["motor_noise"],
                                      gyro[ty]), 3) if gyro[ty] > 0 else 0.0 for ty in cfg.robot_types}
    return acc, gyro, {"flights": sorted(pieces), "real": real, "steps": steps, "acc_g": acc, "gyro_dps": gyro}


def replay_all(cfg: Config, gen_dir, pieces: dict, rough: Roughness | None, workers: int = 1,
               seed: int = 0, controller: str = "ns2", learned: str = "float", law: dict | None = None) -> list[Flight]:
    """Replay every flight of ``pieces`` (name -> real pieces); ``workers`` processes (or the
    Dask cluster of NS2_SCHEDULER: ns2codegen.executor);
    ``controller``, ``learned``, ``law``: replay.replay's."""
    names = sorted(pieces)
    if workers > 1 and len(names) > 1:
        from ns2host.cfhost import load_fly
        from ns2paper.controller import AUTHORS_LAW
        load_fly(gen_dir, (AUTHORS_LAW,) if controller == "authors" else ())   # build once, before the workers
    return run_map(_replay_one, [(cfg, pieces[n], gen_dir, rough, seed, controller, learned, law) for n in names],
                   workers)


def _replay_one(cfg, pcs, gen_dir, rough, seed, controller, learned, law) -> Flight:
    return replay(cfg, pcs, gen_dir, learned=learned, rough=rough, seed=seed, controller=controller, law=law)


def first_per_folder(names, n: int, folders=None) -> list[str]:
    """The first ``n`` flight names (by name) of each folder (a name is "folder/piece"),
    of every folder or of ``folders``, in order of folder."""
    names = sorted(names)
    folders = sorted({m.split("/")[0] for m in names}) if folders is None else folders
    return [m for f in folders for m in [m for m in names if m.split("/")[0] == f][:n]]


def fit_pieces(flights: list[Flight]) -> dict:
    """The pair swap flights the lateral and turbulence fits replay:
    FIT_FLIGHTS_PER_PAIR per pair."""
    by = pieces_by_flight(swap_flights(flights))
    return {n: by[n] for n in first_per_folder(by, FIT_FLIGHTS_PER_PAIR, PAIR_SWAPS)}


def fit_turbulence(cfg: Config, gen_dir, flights: list[Flight], base: Roughness, workers: int = 1) -> tuple[float, float, dict]:
    """ratio and tau of the wake turbulence: the real within-bin scatter under a
    neighbour beyond the simulator's (the other effects on, turbulence off), per unit
    of the bins' rms force, pooled over the pairs of types by samples; tau from the
    share of that excess variance in the fast part (roughness.hp_share)."""
    pieces = fit_pieces(flights)
    real = fs.wake_scatter(cfg, [p for ps in pieces.values() for p in ps])
    sim = fs.wake_scatter(cfg, replay_all(cfg, gen_dir, pieces, base.without("turbulence"), workers))
    num = den = num_f = 0.0
    rows = {}
    for key, r in real.items():
        s = sim.get(key)
        if s is None:
            continue
        ex = max(r["scatter_g"] ** 2 - s["scatter_g"] ** 2, 0.0)
        ex_f = max(r["fast_scatter_g"] ** 2 - s["fast_scatter_g"] ** 2, 0.0)
        num += r["samples"] * ex
        num_f += r["samples"] * ex_f
        den += r["samples"] * r["mean_abs_g"] ** 2
        rows[key] = {"real": r, "sim_without_turbulence": s}
    if den <= 0:
        raise ValueError("no pair of robots under each other in the fit flights")
    ratio = math.sqrt(num / den)
    share = num_f / num if num > 0 else 1.0
    taus = np.geomspace(0.002, 2.0, 400)
    tau = float(taus[int(np.argmin([abs(hp_share(t) - share) for t in taus]))])
    return ratio, tau, {"pairs": rows, "fast_share_of_excess": round(share, 3), "flights": sorted(pieces)}


LATERAL_FIT_EVERY = 4   # labelled steps: every 4th (40 ms) for the least squares of lateral_k_xy


def lateral_k_xy(cfg: Config, flights: list[Flight]) -> dict:
    """The ground truth's lateral push constant (host/sim/aero.py K_XY) read off
    flights: least squares of their horizontal residual labels (less the truth's
    drag) on the truth's wake push with K_XY = 1 at the same (estimated) states, every
    robot of the swap flights where that push exceeds 0.5 g, per robot type and
    pooled.  The labels see a steady lateral force only in part (the EKF reads some of
    it as tilt), so the reading is compared between real and replayed flights, not
    with the truth's constant."""
    from ns2codegen.data.from_logs import labelled_steps
    from ns2host.sim.aero import C_DRAG, K_XY, calibrated
    from ns2host.sim.vehicle import G, vehicle

    num: dict = {}
    for fl, i, steps, fa in labelled_steps(cfg, swap_flights(flights)):
        steps = steps[::LATERAL_FIT_EVERY]
        model = calibrated([vehicle(cfg, t) for t in fl.types], vehicle(cfg, cfg.robot_types[0]), k_xy=1.0)
        drag = -C_DRAG * model.mass[i] * fl.v[steps, i, :2]
        basis = np.array([model.forces(fl.p[k], fl.v[k])[i, :2] for k in steps]) - drag
        real = fa[steps, :2] - drag
        ok = np.isfinite(real).all(1) & (np.linalg.norm(basis, axis=1) * 1e3 / G > 0.5)
        for key in (fl.types[i], "all"):
            a = num.setdefault(key, [0.0, 0.0, 0])
            a[0] += float((basis[ok] * real[ok]).sum())
            a[1] += float((basis[ok] ** 2).sum())
            a[2] += int(ok.sum())
    return {"truth_k_xy": K_XY, **{key: {"k_xy": round(a[0] / a[1], 3) if a[1] > 0 else None, "samples": a[2]}
                                   for key, a in sorted(num.items())}}


LATERAL_PROBE = -0.15   # the lateral effect's second constant flown (the truth's 0.15 the first)


def fit_lateral(cfg: Config, gen_dir, flights: list[Flight], base: Roughness,
                workers: int = 1) -> tuple[dict, dict]:
    """The wake's lateral push per receiving type (roughness "lateral"): the real pair
    swaps' reading of it (lateral_k_xy, fit_pieces) matched by replays of the same
    flights as they flew (the authors' controller, the prediction the real robots
    logged; the turbulence off).  The reading is linear in the constant flown (the
    labels see the push only in part): replays at the truth's K_XY and at
    LATERAL_PROBE give each type's line, solved for the real reading; a replay at the
    answer is reported as the check."""
    from ns2host.sim.aero import K_XY

    pieces = fit_pieces(flights)
    real = lateral_k_xy(cfg, [p for ps in pieces.values() for p in ps])
    b = base.without("turbulence").plus("lateral")

    def read(k: dict) -> dict:
        return lateral_k_xy(cfg, replay_all(cfg, gen_dir, pieces, replace(b, lateral_k_xy=k), workers,
                                            controller="authors", learned="logged"))

    flown = {K_XY: read({ty: K_XY for ty in cfg.robot_types}),
             LATERAL_PROBE: read({ty: LATERAL_PROBE for ty in cfg.robot_types})}
    fit = {}
    for ty in cfg.robot_types:
        if real.get(ty, {}).get("k_xy") is None:
            raise ValueError(f"no {ty} robot beside a wake in the pair swaps {sorted(pieces)}")
        r0, r1 = flown[K_XY][ty]["k_xy"], flown[LATERAL_PROBE][ty]["k_xy"]
        if r0 is None or r1 is None or r0 == r1:
            raise ValueError(f"the {ty} robots' reading of the lateral push does not move with it")
        fit[ty] = round(K_XY + (real[ty]["k_xy"] - r0) * (LATERAL_PROBE - K_XY) / (r1 - r0), 3)
    check = read(fit)
    return fit, {"flights": sorted(pieces), "real": real, "flown": {str(k): v for k, v in flown.items()},
                 "k_xy": fit, "check": check}


WAKE_FIT_EVERY = 8            # every 8th labelled step of the swap flights for the wake's fit
WAKE_FIT_MIN_Z_M = 0.3        # m: above the ground effect (a calibration of its own)
WAKE_PROFILE_R_M = (0.0, 0.05, 0.10, 0.15, 0.22, 0.30)   # offset bins of the wake profile table (m)


def wake_samples(cfg: Config, flights: list[Flight], every: int = WAKE_FIT_EVERY) -> dict:
    """Every robot of ``flights`` under a neighbour (flightstats.WAKE's gap and
    horizontal range, the nearest such neighbour by gap) above WAKE_FIT_MIN_Z_M, every
    ``every``-th labelled step: per team (types) the logged states P, V [K, N, 3], the
    robot i [K], its real label f_a,z (g), the pair ("small under large") and the
    horizontal offset r (m)."""
    from ns2codegen.data.from_logs import labelled_steps

    w = fs.WAKE
    out: dict = {}
    for fl, i, steps, fa in labelled_steps(cfg, flights):
        steps = steps[::every]
        d = fl.p[steps] - fl.p[steps, i][:, None, :]
        r = np.hypot(d[..., 0], d[..., 1])
        under = (d[..., 2] >= w["gap_m"][0]) & (d[..., 2] <= w["gap_m"][1]) & (r <= w["max_horizontal_m"])
        under[:, i] = False
        ok = under.any(1) & (fl.p[steps, i, 2] > WAKE_FIT_MIN_Z_M) & np.isfinite(fa[steps, 2])
        if not ok.any():
            continue
        j = np.argmin(np.where(under, d[..., 2], np.inf), axis=1)[ok]
        k = steps[ok]
        t = out.setdefault(tuple(fl.types), {"P": [], "V": [], "i": [], "label_g": [], "pair": [], "r_m": []})
        t["P"].append(fl.p[k])
        t["V"].append(fl.v[k])
        t["i"].append(np.full(len(k), i))
        t["label_g"].append(fa[k, 2] * 1e3 / G)
        t["pair"] += [f"{fl.types[i]} under {fl.types[jj]}" for jj in j]
        t["r_m"].append(r[ok][np.arange(len(j)), j])
    return {types: {key: (np.concatenate(v) if key != "pair" else np.array(v)) for key, v in t.items()}
            for types, t in sorted(out.items())}


def _column(samples: dict, key: str) -> np.ndarray:
    """One field of wake_samples over every team, in order."""
    return np.concatenate([t[key] for t in samples.values()])


def wake_truth_g(cfg: Config, samples: dict, sigma0_scale: float = 1.0, spread_scale: float = 1.0) -> np.ndarray:
    """The ground truth's f_a,z (g) at every sample of wake_samples (teams in order),
    with the wake's profile scaled (aero.calibrated)."""
    from ns2host.sim.aero import calibrated, forces_of_snapshots
    from ns2host.sim.vehicle import vehicle

    small = vehicle(cfg, cfg.robot_types[0])
    out = []
    for types, t in samples.items():
        vs = [vehicle(cfg, ty) for ty in types]
        f = forces_of_snapshots(lambda k: calibrated(vs * k, small, sigma0_scale=sigma0_scale,
                                                     spread_scale=spread_scale), t["P"], t["V"])
        out.append(f[np.arange(len(t["i"])), t["i"], 2] * 1e3 / G)
    return np.concatenate(out) if out else np.zeros(0)


def wake_profile(samples: dict, truths: dict) -> dict:
    """Per pair and bin of horizontal offset (WAKE_PROFILE_R_M): the samples, the real
    labels' mean and each truth's mean (g) at the same states (``truths``: label ->
    wake_truth_g)."""
    pair, r, lab = _column(samples, "pair"), _column(samples, "r_m"), _column(samples, "label_g")
    out: dict = {}
    for p in sorted(set(pair)):
        for lo, hi in zip(WAKE_PROFILE_R_M[:-1], WAKE_PROFILE_R_M[1:]):
            m = (pair == p) & (r >= lo) & (r < hi)
            if m.any():
                out.setdefault(p, []).append({"r_m": [lo, hi], "samples": int(m.sum()), "real_g": fs._r(lab[m].mean()),
                                              **{k: fs._r(v[m].mean()) for k, v in truths.items()}})
    return out


def fit_wake_scales(cfg: Config, samples: dict) -> tuple[float, float]:
    """(sigma0_scale, spread_scale), 3 decimals, minimizing the rms of label - truth over
    ``samples`` (wake_samples' form): Nelder-Mead on the logarithms from (1, 1)."""
    from scipy.optimize import minimize

    lab = _column(samples, "label_g")
    rms = lambda x: float(np.sqrt(np.mean((wake_truth_g(cfg, samples, *np.exp(x)) - lab) ** 2)))  # noqa: E731
    res = minimize(rms, np.zeros(2), method="Nelder-Mead", options={"xatol": 0.005, "fatol": 1e-4})
    s0, sp = (round(float(v), 3) for v in np.exp(res.x))
    return s0, sp


def fit_wake(cfg: Config, flights: list[Flight]) -> tuple[float, float, dict]:
    """The wake's profile read off the real flights (roughness.py "wake"): the scales
    of the truth's initial jet width and spreading rate that minimize the rms of real
    label - truth at the logged states of every robot under a neighbour in the swap
    flights (wake_samples; Nelder-Mead on the logarithms from the paper's wake, no
    controller and no replay).  Returns the two scales (3 decimals) and the report:
    samples, rms before and after, per pair and the profile by offset."""
    samples = wake_samples(cfg, swap_flights(flights))
    lab, pair = _column(samples, "label_g"), _column(samples, "pair")
    s0, sp = fit_wake_scales(cfg, samples)
    paper, fitted = wake_truth_g(cfg, samples), wake_truth_g(cfg, samples, s0, sp)
    by_pair = {p: {"samples": int((pair == p).sum()),
                   "rms_paper_g": fs._r(np.sqrt(np.mean((paper - lab)[pair == p] ** 2))),
                   "rms_fitted_g": fs._r(np.sqrt(np.mean((fitted - lab)[pair == p] ** 2)))} for p in sorted(set(pair))}
    return s0, sp, {"samples": int(lab.size), "sigma0_scale": s0, "spread_scale": sp,
                    "rms_paper_g": fs._r(np.sqrt(np.mean((paper - lab) ** 2))),
                    "rms_fitted_g": fs._r(np.sqrt(np.mean((fitted - lab) ** 2))), "by_pair": by_pair,
                    "profile": wake_profile(samples, {"paper_g": paper, "fitted_g": fitted})}


def read_law_pieces(flights: list[Flight]) -> dict:
    """The swap flights the z law's fit replays: READ_LAW_FLIGHTS_PER_FOLDER per swap
    folder (the first ones by name)."""
    by = pieces_by_flight(swap_flights(flights))
    return {n: by[n] for n in first_per_folder(by, READ_LAW_FLIGHTS_PER_FOLDER)}


def law_step(law: dict, real: dict, read: dict, before: tuple[dict, dict] | None = None) -> dict:
    """One step of the z law's fit, per type: each of Kp, Kd, Ki, k_fa scaled by what
    the real flights read over what the replay read (the replay's reading of its own
    law is biased by the motors' delay, the estimator and the correlation of the
    regressors in a wake; the ratio takes that bias out), never below 0; the mass
    parameter moved by the z error's mean the replay misses: by the secant through
    the step ``before`` (its law and reading) where that slope is positive (a heavier
    parameter flies higher), else through the law's stiffness (a steady offset e of a
    law without integral is (m_param - m) g / (m_param Kp))."""
    out = {}
    for ty, zl in law.items():
        r, s = real[ty], read[ty]
        new = dict(zl)
        for k, stat in LAW_KEYS:
            if s[stat] is not None and s[stat] > 1e-3 and r[stat] is not None:
                new[k] = round(max(0.0, zl[k] * r[stat] / s[stat]), 4)
        miss = r["z_error_mean_m"] - s["z_error_mean_m"]
        slope = G / (zl["mass_kg"] * zl["kp"])                  # m of offset per kg of mass parameter
        if before is not None:
            dm = zl["mass_kg"] - before[0][ty]["mass_kg"]
            de = s["z_error_mean_m"] - before[1][ty]["z_error_mean_m"]
            if dm != 0.0 and de / dm > 0.0:
                slope = de / dm
        new["mass_kg"] = round(zl["mass_kg"] + miss / slope, 6)
        out[ty] = new
    return out


def fit_read_law(cfg: Config, gen_dir, flights: list[Flight], rough: Roughness, workers: int = 1,
                 iterations: int = READ_LAW_ITERATIONS) -> tuple[dict, list]:
    """The z law read off the real logs (vehicle.READ_LAW's form): start from the real
    swaps' reading (flightstats.z_law) with the authors' mass parameter, replay the
    read_law_pieces flights with it (the rough simulator, the prediction the real
    robots logged) and take law_step, ``iterations`` times; the law whose replay reads
    closest to the real reading (the largest relative miss over the types' Kp, Kd,
    k_fa, the z error's mean in cm) and every iteration's reading."""
    pieces = read_law_pieces(flights)
    real = fs.z_law(cfg, [p for ps in pieces.values() for p in ps])
    law = {ty: {**{k: real[ty][stat] for k, stat in LAW_KEYS},
                "mass_kg": AUTHORS_GAINS[AUTHORS_TYPE[ty]]["mass_kg"]} for ty in sorted(real)}
    rows, best, before = [], None, None
    for it in range(iterations + 1):
        read = fs.z_law(cfg, replay_all(cfg, gen_dir, pieces, rough, workers, controller="authors",
                                        learned="logged", law=law))
        miss = max(max(abs(read[ty][st] / real[ty][st] - 1.0) for _, st in LAW_KEYS if st != "ki_per_s3")
                   for ty in law)
        miss = max(miss, max(abs(read[ty]["z_error_mean_m"] - real[ty]["z_error_mean_m"]) * 100 for ty in law))
        rows.append({"iteration": it, "law": law, "read": read, "miss": round(miss, 4)})
        if best is None or miss < best[0]:
            best = (miss, law)
        if it < iterations:
            law, before = law_step(law, real, read, before), (law, read)
    return best[1], [{"flights": sorted(pieces), "real": real}] + rows


def thrust_sd(hover_by_robot: dict, robot_type_of: dict) -> float:
    """Relative standard deviation of the robots' hover thrust within a type, pooled over
    the types with two robots or more (hover_masses' by_robot medians)."""
    dev, dof = 0.0, 0
    for ty in set(robot_type_of.values()):
        m = np.array([hover_by_robot[r]["median_g"] for r, t in robot_type_of.items() if t == ty and r in hover_by_robot])
        if len(m) >= 2:
            dev += float(((m / m.mean() - 1.0) ** 2).sum())
            dof += len(m) - 1
    if not dof:
        raise ValueError("no robot type with two hover-weighed robots: thrust scatter unknown")
    return math.sqrt(dev / dof)


def fit(cfg: Config, gen_dir, flights: list[Flight], hover_by_robot: dict, robot_type_of: dict,
        workers: int = 1) -> tuple[Roughness, dict]:
    """Every parameter of Roughness from the real flights (module docstring)."""
    real = real_statistics(cfg, flights)
    bat = real["battery"]
    start = float(np.median([b["start_V"] for b in bat.values()]))
    sag = -float(np.median([b["slope_V_per_min"] for b in bat.values()]))
    s0, sp, wake = fit_wake(cfg, flights)
    base = Roughness(battery_start_V=round(start, 3), battery_sag_V_per_min=round(sag, 4),
                     thrust_sd=round(thrust_sd(hover_by_robot, robot_type_of), 4),
                     wake_sigma0_scale=s0, wake_spread_scale=sp)
    acc, gyro, vib_rows = fit_vibration(cfg, gen_dir, flights, base, workers)
    base = replace(base, vibration_acc_g=acc, vibration_gyro_dps=gyro)
    lateral, lateral_rows = fit_lateral(cfg, gen_dir, flights, base, workers)
    base = replace(base, lateral_k_xy=lateral)
    ratio, tau, turb_rows = fit_turbulence(cfg, gen_dir, flights, base, workers)
    base = replace(base, turbulence_ratio=round(ratio, 3), turbulence_tau_s=round(tau, 4))
    rough = replace(base, hover_motor_noise={ty: real["free_air"][ty]["motor_noise"] for ty in cfg.robot_types})
    return rough, {"real": real, "wake": wake, "vibration": vib_rows, "turbulence": turb_rows,
                   "lateral": lateral_rows}


@dataclass(frozen=True)
class ReplayVariant:
    """One simulator of compare's table: how the real swaps are replayed (replay.replay)."""
    label: str              # its column in calibration.md and key in the JSON
    rough: bool             # the rough simulator (else the clean one)
    controller: str         # "ns2" (the project's) or "authors" (paper/c/ctrl_authors.c)
    learned: str            # "float" (the network of gen_dir) or "logged" (the prediction flown)
    read_law: bool = False  # the z law read off the logs (fit_read_law) instead of the vehicle's


VARIANTS = {v.label: v for v in (
    ReplayVariant("clean", False, "ns2", "float"),
    ReplayVariant("rough", True, "ns2", "float"),
    ReplayVariant("rough, the authors' controller", True, "authors", "float"),
    ReplayVariant("rough, the authors' controller, the prediction flown", True, "authors", "logged"),
    ReplayVariant("rough, the z law read off the logs, the prediction flown", True, "authors", "logged",
                  read_law=True))}


def compare(cfg: Config, gen_dir, flights: list[Flight], rough: Roughness, names: list[str] | None = None,
            workers: int = 1, real_all: dict | None = None, law: dict | None = None) -> dict:
    """Statistics of step 1 for the real flights and five simulators (VARIANTS): clean,
    rough (``rough``), rough with the position law and gains of the controller that
    flew the real flights (paper/c/ctrl_authors.c) and the network of ``gen_dir`` in the
    loop, the same controller flying the prediction the real robots logged instead of
    a network, and that with the z law read off the logs (``law``, READ_LAW by
    default; fit_read_law): free air (flightstats.free_air and z_loop) over replays
    of the pair random walks (free_air_pieces; the real side the same flights), the
    rest over the replayed swap flights (``names``: a subset; the real side is the
    same subset).  The replays fly each robot's logged
    battery, so the battery rows are one probe flight's per type (probe_flight: the
    simulator's own sag) against every real flight.  real_all: fit's statistics of
    every real flight if already measured (its battery is taken).
    Returns {"flights", "free_air_flights", "real", "simulators": {label: ...}}."""
    law = READ_LAW if law is None else law
    by = pieces_by_flight(swap_flights(flights))
    if names is not None:
        by = {n: by[n] for n in names}
    real_sw = [p for ps in by.values() for p in ps]
    free = free_air_pieces(flights)
    real_free = [p for ps in free.values() for p in ps]
    battery = fs.battery(flights) if real_all is None else real_all["battery"]
    out = {"flights": sorted(by), "free_air_flights": sorted(free), "simulators": {},
           "real": {"free_air": fs.free_air(cfg, real_free), "battery": battery, "z_loop": fs.z_loop(cfg, real_free),
                    "z_law": fs.z_law(cfg, real_sw), "wake_scatter": fs.wake_scatter(cfg, real_sw),
                    "wake_lateral": fs.wake_lateral(cfg, real_sw),
                    "swaps": fs.swap_errors(real_sw), "attitude": fs.swap_attitude(real_sw),
                    "unpredicted": fs.unpredicted(cfg, real_sw), "lateral_k_xy": lateral_k_xy(cfg, real_sw)}}
    probed: dict = {}
    for label, v in VARIANTS.items():
        r, zl = (rough if v.rough else None), (law if v.read_law else None)
        w = replay_all(cfg, gen_dir, free, r, workers, controller=v.controller, learned=v.learned, law=zl)
        if v.rough not in probed:   # the simulator's own battery (the replays fly the logged one)
            probed[v.rough] = [probe_flight(cfg, gen_dir, ty, r) for ty in cfg.robot_types]
        sims = replay_all(cfg, gen_dir, by, r, workers, controller=v.controller, learned=v.learned, law=zl)
        out["simulators"][label] = {
            "free_air": fs.free_air(cfg, w), "z_loop": fs.z_loop(cfg, w), "z_law": fs.z_law(cfg, sims),
            "battery": fs.battery(probed[v.rough]),
            "wake_scatter": fs.wake_scatter(cfg, sims), "wake_lateral": fs.wake_lateral(cfg, sims),
            "swaps": fs.swap_errors(sims),
            "attitude": fs.swap_attitude(sims), "lateral_k_xy": lateral_k_xy(cfg, sims),
            "unpredicted": fs.unpredicted(cfg, sims)}
    return out


READ_LAW_LABEL = ", the z law read off the logs"


def paper_l2s(cfg: Config, gen_dir, rough: Roughness | None, swaps: int = 6, law: dict | None = None) -> dict:
    """The paper's L2S swap (experiments/swarm.py's geometry) flown by the controller
    that flew the paper's flights on every robot (swarm.AUTHORS_CONTROLLERS): without
    the learned force (the paper's BL) and with the network of ``gen_dir`` (its NN),
    with its stored gains and with the z law read off the logs (``law``, READ_LAW by
    default).  Median worst z error of the bottom robot over ``swaps`` swaps, beside
    the paper's."""
    from ns2exp.swarm import AUTHORS_CONTROLLERS, run_swaps

    out = {}
    for zl, tag in ((None, ""), (READ_LAW if law is None else law, READ_LAW_LABEL)):
        for c in AUTHORS_CONTROLLERS:
            w = run_swaps(cfg, gen_dir, "L2S", learned="float", swaps=swaps, controller=c, rough=rough,
                          law=zl)["worst_z_error_m"]
            out[c + tag] = {"median_worst_z_error_m": float(np.median(w)), "worst_z_error_m": w,
                            "paper_m": PAPER_L2S_M[c]}
    return out


def roughness_dict(rough: Roughness) -> dict:
    d = asdict(rough)
    d["enabled"] = list(d["enabled"])
    return d


def calibrate(cfg: Config, gen_dir, flights: list[Flight], hover_by_robot: dict, robot_type_of: dict,
              out_dir: str | Path, workers: int = 1, names: list[str] | None = None,
              rough: Roughness | None = None, command: str = "ns2 sim calibrate") -> dict:
    """Fit (unless ``rough`` is given), compare, write out_dir/calibration.json and
    calibration.md and, with a fit, the fitted parameter files rough.toml and
    read_law.toml beside them (the form of host/sim/params/ and paper/params/, made by
    ``command`` at this checkout's commit; copied over host/sim/params/rough.toml and
    paper/params/read_law.toml they become the ones flown);
    returns the JSON."""
    out_dir = Path(out_dir)
    fit_report, law = None, READ_LAW
    if rough is None:
        rough, fit_report = fit(cfg, gen_dir, flights, hover_by_robot, robot_type_of, workers)
        law, fit_report["read_law"] = fit_read_law(cfg, gen_dir, flights, rough, workers)
    cmp = compare(cfg, gen_dir, flights, rough, names, workers, fit_report["real"] if fit_report else None, law)
    l2s = paper_l2s(cfg, gen_dir, rough, law=law)
    res = {"roughness": roughness_dict(rough), "read_law": law, "effects": list(EFFECTS), "fit": fit_report,
           "compare": cmp, "paper_l2s": l2s}
    files = {"calibration.json": json.dumps(stamp(res, command), indent=1, sort_keys=True), "calibration.md": markdown(res)}
    if fit_report is not None:
        files.update(param_files(rough, law, command))
    atomic_write_files(out_dir, files)
    if fit_report is None:        # no fit: no parameter file of an earlier run beside this report
        for name in PARAM_FILES:
            (out_dir / name).unlink(missing_ok=True)
    return res


PARAM_FILES = ("rough.toml", "read_law.toml")


def param_files(rough: Roughness, law: dict, command: str) -> dict:
    """{name: text} of the parameter files of a fit (rough.toml, read_law.toml), their
    origin this checkout's commit, ``command`` and today (UTC)."""
    origin = {"commit": source_commit(), "command": command, "date": time.strftime("%Y-%m-%d", time.gmtime()),
              "report": "calibration.md and calibration.json beside this file"}
    return dict(zip(PARAM_FILES, (dump_roughness(rough, origin), dump_read_law(law, origin))))


def compare_in_order(res: dict) -> dict:
    """calibrate's comparison with its simulators in VARIANTS' order (the JSON's keys are sorted)."""
    sims = res["compare"]["simulators"]
    return {**res["compare"], "simulators": {k: sims[k] for k in VARIANTS if k in sims}}


# calibration.md's sections after the roughness table, in its order
SECTIONS = {"replays": "Replayed swaps", "paper-l2s": "The paper's L2S swap, the authors' controller, rough simulator",
            "read-law": "The z law read off the logs", "wake": "The wake at the real states",
            "lateral": "The wake's lateral push"}


def report_parts(res: dict) -> dict:
    """calibration.md's tables of calibrate's JSON: part -> a function making it (roughness
    first, then SECTIONS' order; wake and lateral only with a fit)."""
    from .calibrate_tables import (lateral_table, paper_l2s_table, read_law_table, roughness_table,
                                   sim_to_real_table, wake_profile_table)

    fit, cmp = res["fit"], compare_in_order(res)
    parts = {"roughness": lambda: roughness_table(cmp), "replays": lambda: sim_to_real_table(cmp),
             "paper-l2s": lambda: paper_l2s_table(res["paper_l2s"]),
             "read-law": lambda: read_law_table(res["read_law"], fit["read_law"] if fit else None)}
    if fit:
        parts.update({"wake": lambda: wake_profile_table(fit["wake"]), "lateral": lambda: lateral_table(fit["lateral"])})
    return parts


def markdown(res: dict) -> str:
    """calibration.md of calibrate's JSON (as written: its simulators in VARIANTS' order)."""
    parts = report_parts(res)
    return ("# The simulator against the real flights\n\n" + parts.pop("roughness")()
            + "".join(f"\n\n## {SECTIONS[k]}\n\n" + make() for k, make in parts.items()) + "\n")
