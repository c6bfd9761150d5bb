"""The roughness of a flight, measured the same way on real logs and on simulated ones
(issue: a simulator as rough as a real Crazyflie, step 1).  Every function takes
``Flight``s on a uniform time base (ns2codegen.data.from_logs: the real collection
through ns2codegen.logs, the simulator's logs through host/sim/collect.py) and
labels them as the data set does (``labelled_steps``: eq. (residual) from the
estimated state, PWM and battery voltage).

free_air      the residual force of a robot with no neighbour near (no robot within
              FREE_AIR horizontally, above FREE_AIR's height): mean, standard
              deviation, its fast part (minus its HP_WINDOW moving average: what
              no controller follows), its spectrum in bands; the motor-command
              noise (motor_noise) there
wake_scatter  how the residual under one neighbour scatters around its mean for the
              same relative state (bins of vertical gap, horizontal distance and
              relative horizontal speed): the pooled within-bin standard deviation,
              against the bins' mean |f_a,z|
wake_lateral  the horizontal residual of a robot beside the axis of the wake above it:
              pushed out or drawn in, on average
battery       the battery voltage over a flight: at take-off and its slope
z_loop        the z tracking of a robot with no neighbour near: the error's mean and
              standard deviation per type, and the closed loop's stiffness identified
              from it (the commanded vertical force against the z and v_z errors)
z_law         the position law that flew, read off every robot of a flight (the
              commanded vertical force against the z error, its rate, its integral
              and the prediction flown): the same flights real and replayed
swap_errors   the worst z error of the bottom robot of each swap (the paper's metric,
              Fig. swap): per scenario, the median over swaps
swap_attitude the bottom robot's largest tilt and horizontal error in each swap: per
              scenario, the medians over swaps (what the wakes do beside the z force)
swap_geometry the swaps' setpoints: the bottom robot's horizontal travel and peak
              setpoint speed per swap, medians over every swap (the paper's swap
              experiments are "similar" to these, its section on swaps)
unpredicted   what the prediction flown in the loop left of the bottom robot's residual
              in the swaps (label minus the logged on-board f_a,z-hat where |label|
              > UNPREDICTED_MIN_G): the force its controller had to absorb
"""
from __future__ import annotations

import numpy as np

from ns2codegen.config import Config
from ns2codegen.data.from_logs import Flight, labelled_steps
from ns2codegen.data.labels import psi1_newtons, quat_to_R

from ns2codegen.vehicle import G

FREE_AIR = {"min_z_m": 0.4, "min_horizontal_m": 0.6}
HP_WINDOW = 21            # samples (0.2 s at 100 Hz): the fast part of a signal is what is left around this mean
NOISE_WINDOW = 11         # samples (0.1 s at 100 Hz): motor commands minus their moving average
BANDS_HZ = ((0.0, 0.5), (0.5, 2.0), (2.0, 5.0), (5.0, 20.0), (20.0, 50.1))
WELCH_N = 256             # samples per spectrum segment (2.56 s)
WAKE = {"max_horizontal_m": 0.3, "gap_m": (0.1, 1.2), "bin_gap_m": 0.05, "bin_horizontal_m": 0.025,
        "bin_speed_mps": 0.25, "min_bin": 10}
SWAP_MIN_S = 0.5          # s: a shorter movement is no swap (the setpoint's noise around a start)
SWAP_MIN_SPEED = 0.02     # m/s: the bottom robot's setpoint moves horizontally (a swap under way;
                          # its speed from the 0.1 s moving average: the real setpoint is logged in mm)


def moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average of n samples along axis 0 (edges: the partial window; a
    series shorter than the window too)."""
    k = np.ones(n)
    x = np.asarray(x, float)
    flat = x.reshape(len(x), -1)
    s = (n - 1) // 2                   # np.convolve's "same" centring, for any length

    def conv(c):
        return np.convolve(c, k, mode="full")[s:s + len(x)]
    num = np.stack([conv(c) for c in flat.T], axis=1)
    den = conv(np.ones(len(x)))[:, None]
    return (num / den).reshape(x.shape)


def motor_noise(pwm: np.ndarray) -> float:
    """rms of the motor commands (PWM in [0, 1]) minus their 0.1 s moving average, over
    time, motors and the robots given ([T, ..., 4]); the window's edges left out."""
    d = fast_part(np.asarray(pwm, float).reshape(len(pwm), -1), NOISE_WINDOW)
    return float(np.sqrt((d ** 2).mean()))


def fast_part(x: np.ndarray, n: int) -> np.ndarray:
    """x minus its centred n-sample moving average, the window's edges (n // 2 samples
    at each end) left out."""
    h = n // 2
    return (x - moving_average(x, n))[h:len(x) - h]


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of every run of True."""
    e = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(mask, np.int8), [0]])))
    return list(zip(e[::2].tolist(), e[1::2].tolist()))


def _labels_g(cfg: Config, flights: list[Flight]):
    """(flight, robot, f_a,z [T] in g with NaN where unlabelled) per labelled robot."""
    for fl, i, steps, fa in labelled_steps(cfg, flights):
        fz = np.full(len(fl.t), np.nan)
        fz[steps] = fa[steps, 2] * 1e3 / G
        yield fl, i, fz


def alone(fl: Flight, i: int, min_z_m: float = FREE_AIR["min_z_m"],
          min_horizontal_m: float = FREE_AIR["min_horizontal_m"]) -> np.ndarray:
    """Where robot i is above min_z_m with every other robot farther than
    min_horizontal_m horizontally (free air by default)."""
    ok = fl.p[:, i, 2] > min_z_m
    for j in range(len(fl.types)):
        if j != i:
            ok &= np.hypot(*(fl.p[:, j, :2] - fl.p[:, i, :2]).T) > min_horizontal_m
    return ok


def bottom_order(fl: Flight) -> list[int]:
    """The robots from the lowest setpoint up (median over the flight); the first is the
    bottom robot of a swap."""
    return [int(k) for k in np.argsort(np.nanmedian(fl.p_d[:, :, 2], axis=0), kind="stable")]


def free_air(cfg: Config, flights: list[Flight]) -> dict:
    """Per robot type: samples, mean_g, std_g, fast_std_g (the label minus its 0.2 s
    moving average), band_fraction (Welch spectrum of runs >= 2.56 s, share of the
    variance per band of BANDS_HZ, or None without such a run), motor_noise."""
    from scipy.signal import welch

    acc: dict = {}
    for fl, i, fz in _labels_g(cfg, flights):
        ok = alone(fl, i) & np.isfinite(fz)
        a = acc.setdefault(fl.types[i], {"x": [], "fast": [], "psd": [], "pwm": []})
        for s, e in runs(ok):
            x = fz[s:e]
            a["x"].append(x)
            if e - s > HP_WINDOW:
                a["fast"].append(fast_part(x, HP_WINDOW))
            if e - s > NOISE_WINDOW:
                a["pwm"].append(fast_part(fl.pwm[s:e, i], NOISE_WINDOW))
            if e - s >= WELCH_N:
                f, p = welch(x - x.mean(), fs=1.0 / float(np.median(np.diff(fl.t))), nperseg=WELCH_N)
                a["psd"].append(p * (e - s))
    out = {}
    for ty, a in sorted(acc.items()):
        x = np.concatenate(a["x"]) if a["x"] else np.zeros(0)
        fast = np.concatenate(a["fast"]) if a["fast"] else np.zeros(0)
        pwm = np.concatenate(a["pwm"]) if a["pwm"] else np.zeros((0, 4))
        bands = None
        if a["psd"]:
            p = np.sum(a["psd"], axis=0)
            bands = [round(float(p[(f >= lo) & (f < hi)].sum() / p.sum()), 3) for lo, hi in BANDS_HZ]
        out[ty] = {"samples": int(x.size), "mean_g": _r(x.mean() if x.size else None),
                   "std_g": _r(x.std() if x.size else None),
                   "fast_std_g": _r(np.sqrt((fast ** 2).mean()) if fast.size else None),
                   "band_fraction": bands, "bands_hz": [list(b) for b in BANDS_HZ],
                   "motor_noise": _r(np.sqrt((pwm ** 2).mean()) if pwm.size else None, 5)}
    return out


def _r(x, nd: int = 3):
    return None if x is None else round(float(x), nd)


LATERAL_R_M = (0.06, 0.22)   # m: beside a wake's axis, where its profile's gradient is steep


def wake_lateral(cfg: Config, flights: list[Flight]) -> dict:
    """Per (robot type, neighbour type) of two-robot flights, the robot under its
    neighbour (vertical gap in WAKE's range) and LATERAL_R_M beside its axis: the mean
    horizontal residual force along the direction away from the neighbour (g;
    positive: pushed out of the wake, negative: drawn in), and the mean f_a,z there."""
    acc: dict = {}
    for fl, i, steps, fa in labelled_steps(cfg, flights):
        if len(fl.types) != 2:
            continue
        d = fl.p[steps, i] - fl.p[steps, 1 - i]
        r = np.hypot(d[:, 0], d[:, 1])
        ok = ((-d[:, 2] >= WAKE["gap_m"][0]) & (-d[:, 2] <= WAKE["gap_m"][1]) & (r >= LATERAL_R_M[0])
              & (r <= LATERAL_R_M[1]) & np.isfinite(fa[steps]).all(1))
        out_dir = d[ok, :2] / r[ok, None]
        a = acc.setdefault(f"{fl.types[i]} under {fl.types[1 - i]}", {"push": [], "z": []})
        a["push"].append((fa[steps][ok, :2] * out_dir).sum(1) * 1e3 / G)
        a["z"].append(fa[steps][ok, 2] * 1e3 / G)
    out = {}
    for key, a in sorted(acc.items()):
        push, z = np.concatenate(a["push"]), np.concatenate(a["z"])
        if push.size:
            out[key] = {"samples": int(push.size), "push_out_g": _r(push.mean()), "fz_g": _r(z.mean())}
    return out


def wake_scatter(cfg: Config, flights: list[Flight]) -> dict:
    """Per (robot type, neighbour type) of two-robot flights, the robot under its
    neighbour (vertical gap in WAKE's range, horizontal distance below its maximum):
    the labels binned by gap, horizontal distance and relative horizontal speed; the
    pooled within-bin standard deviation (scatter_g: what no model of the relative
    state predicts, measurement noise included), the rms of the bins' means
    (mean_abs_g), and the same scatter of its fast part (fast_scatter_g)."""
    w = WAKE
    acc: dict = {}
    for fl, i, fz in _labels_g(cfg, flights):
        if len(fl.types) != 2:
            continue
        j = 1 - i
        d = fl.p[:, j] - fl.p[:, i]
        r = np.hypot(d[:, 0], d[:, 1])
        dv = np.hypot(*(fl.v[:, j, :2] - fl.v[:, i, :2]).T)
        ok = (np.isfinite(fz) & (d[:, 2] >= w["gap_m"][0]) & (d[:, 2] <= w["gap_m"][1])
              & (r <= w["max_horizontal_m"]))
        fast = np.full(len(fz), np.nan)
        h = HP_WINDOW // 2
        for s, e in runs(np.isfinite(fz)):
            if e - s > HP_WINDOW:
                fast[s + h:e - h] = fast_part(fz[s:e], HP_WINDOW)
        key = f"{fl.types[i]} under {fl.types[j]}"
        a = acc.setdefault(key, {"bin": [], "x": [], "fast": []})
        b = np.stack([np.floor(d[ok, 2] / w["bin_gap_m"]), np.floor(r[ok] / w["bin_horizontal_m"]),
                      np.floor(dv[ok] / w["bin_speed_mps"])], 1).astype(np.int64)
        a["bin"].append(b)
        a["x"].append(fz[ok])
        a["fast"].append(fast[ok])
    out = {}
    for key, a in sorted(acc.items()):
        if not a["x"] or not sum(len(x) for x in a["x"]):
            continue
        b, x, fast = np.concatenate(a["bin"]), np.concatenate(a["x"]), np.concatenate(a["fast"])
        _, inv, cnt = np.unique(b, axis=0, return_inverse=True, return_counts=True)
        inv = inv.ravel()
        keep = cnt[inv] >= w["min_bin"]
        if not keep.any():
            continue
        _, inv = np.unique(inv[keep], return_inverse=True)
        x, fast = x[keep], fast[keep]
        m = np.bincount(inv, x) / np.bincount(inv)
        dof = x.size - len(m)
        res = x - m[inv]
        okf = np.isfinite(fast)
        mf = np.bincount(inv[okf], fast[okf], minlength=len(m)) / np.maximum(np.bincount(inv[okf], minlength=len(m)), 1)
        out[key] = {"samples": int(x.size), "bins": int(len(m)),
                    "scatter_g": _r(np.sqrt((res ** 2).sum() / max(dof, 1))),
                    "mean_abs_g": _r(np.sqrt((m[inv] ** 2).mean())),
                    "fast_scatter_g": _r(np.sqrt(((fast[okf] - mf[inv[okf]]) ** 2).mean())) if okf.any() else None}
    return out


def battery(flights: list[Flight], min_s: float = 10.0) -> dict:
    """Per robot type, over flight pieces of at least ``min_s``: the voltage in the
    first second (median over pieces) and the slope of a straight-line fit (V/min,
    median), with their 10th-90th percentiles."""
    acc: dict = {}
    for fl in flights:
        if fl.t[-1] - fl.t[0] < min_s:
            continue
        first = fl.t - fl.t[0] < 1.0
        for i, ty in enumerate(fl.types):
            a = acc.setdefault(ty, {"v0": [], "slope": []})
            a["v0"].append(float(np.median(fl.battery_V[first, i])))
            a["slope"].append(float(np.polyfit(fl.t, fl.battery_V[:, i], 1)[0]) * 60.0)
    return {ty: {"pieces": len(a["v0"]), "start_V": _r(np.median(a["v0"])),
                 "start_V_p10_p90": [_r(v) for v in np.percentile(a["v0"], [10, 90])],
                 "slope_V_per_min": _r(np.median(a["slope"]), 4),
                 "slope_p10_p90": [_r(v, 4) for v in np.percentile(a["slope"], [10, 90])]}
            for ty, a in sorted(acc.items())}


def setpoint_derivatives(t: np.ndarray, p_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """v_d, a_d [T, ...] of a logged position setpoint p_d [T, ...] at times t (each after
    a 0.1 s moving average: the real setpoint is logged in millimetres)."""
    v = np.gradient(moving_average(p_d, NOISE_WINDOW), t, axis=0)
    return v, np.gradient(moving_average(v, NOISE_WINDOW), t, axis=0)


def commanded_acc_z(cfg: Config, fl: Flight, i: int, w: slice, a_d_z: np.ndarray) -> np.ndarray:
    """Robot i's commanded vertical acceleration over ``w`` (m/s^2): psi_1 of the logged
    PWM (before the motors' delay) along the body z axis per unit of the type's mass,
    minus g and the setpoint's a_z (``a_d_z``, over ``w``)."""
    veh = cfg.vehicle(fl.types[i])
    f = psi1_newtons(veh["psi1"], fl.pwm[w, i], fl.battery_V[w, i]).sum(axis=1) * quat_to_R(fl.q[w, i])[:, 2, 2]
    return f / (veh["mass_g"] / 1000.0) - G - a_d_z


def least_squares(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Coefficients of y ~ X and the fit's R^2."""
    c = np.linalg.lstsq(X, y, rcond=None)[0]
    return c, float(1.0 - ((y - X @ c) ** 2).mean() / y.var())


def z_loop(cfg: Config, flights: list[Flight]) -> dict:
    """Free-air z tracking (robots alone as in free_air; flights with setpoints): per
    type the z error's mean and standard deviation (m); pooled over the types, the
    least-squares fit of the commanded vertical acceleration (psi_1 of the logged PWM,
    before the motors' delay, along the body z axis, per unit of the type's mass,
    minus g and the setpoint's a_z) = -kp e_z - kd e_vz + bias of the type, with its R^2: the
    stiffness of the controller that flew (a PD law; an integral would show as a
    drifting bias)."""
    per: dict = {}
    X, Y = [], []
    for fl in flights:
        if fl.p_d is None or len(fl.t) < 2 * NOISE_WINDOW or not np.isfinite(fl.p_d).all():
            continue
        v_d, a_d = setpoint_derivatives(fl.t, fl.p_d)
        for i, ty in enumerate(fl.types):
            if fl.labelled is not None and not fl.labelled[i]:
                continue
            ok = alone(fl, i)
            if not ok.any():
                continue
            az = commanded_acc_z(cfg, fl, i, slice(None), a_d[:, i, 2])
            ez = fl.p[:, i, 2] - fl.p_d[:, i, 2]
            ev = fl.v[:, i, 2] - v_d[:, i, 2]
            per.setdefault(ty, []).append(ez[ok])
            onehot = np.zeros((len(ez), len(cfg.robot_types)))
            onehot[:, cfg.robot_types.index(ty)] = 1.0
            X.append(np.column_stack([ez, ev, onehot])[ok])
            Y.append(az[ok])
    out: dict = {"by_type": {ty: {"samples": int(sum(len(e) for e in es)),
                                  "z_error_mean_m": _r(np.concatenate(es).mean(), 4),
                                  "z_error_std_m": _r(np.concatenate(es).std(), 4)} for ty, es in sorted(per.items())}}
    if X:
        X, Y = np.concatenate(X), np.concatenate(Y)
        c, r2 = least_squares(X, Y)
        out["fit"] = {"kp_per_s2": _r(-c[0]), "kd_per_s": _r(-c[1]),
                      "bias_mps2": {ty: _r(b) for ty, b in zip(cfg.robot_types, c[2:])},
                      "r2": _r(r2), "samples": int(len(Y))}
    return out


Z_LAW_MIN_Z_M = 0.3      # m: z_law reads robots in flight (above the ground's take-off and landing)


def z_law(cfg: Config, flights: list[Flight]) -> dict:
    """The z position law that flew, per type, read off every robot above Z_LAW_MIN_Z_M
    while its setpoint is logged, neighbours or not (the same flights real and
    replayed): least squares of psi_1(PWM) b3_z / m - g - a_d,z (the commanded vertical
    acceleration; m the type's mass) = -(Kp e + Kd e_v + Ki int e) - k_fa f_a,z-hat / m
    + c, e = z - z_d, e_v = v_z - v_d,z, int e from the start of each stretch of logged
    setpoint (c takes the integral's start), f_a,z-hat the logged ``fa_onboard_g``
    (0 where not logged).  The controller that flew is f_d = m (a_d + g e3 - Kp e - Kd
    e_v - Ki int e) - k_fa f_a-hat (paper/c/ctrl_authors.c; k_fa = 1: the prediction
    taken off whole); a stiffer or softer law, an integral or none, a prediction taken
    off in part read as such (k_fa None where a type never logged a prediction).  Also
    the z error's mean (m) over those samples."""
    rows: dict = {}
    for fl in flights:
        if fl.p_d is None or len(fl.t) < 2 * NOISE_WINDOW:
            continue
        for i, ty in enumerate(fl.types):
            if fl.labelled is not None and not fl.labelled[i]:
                continue
            have = np.isfinite(fl.p_d[:, i]).all(axis=1)
            for a, b in runs(have):
                if b - a < 2 * NOISE_WINDOW:
                    continue
                w = slice(a, b)
                v_d, a_d = setpoint_derivatives(fl.t[w], fl.p_d[w, i])
                fa = (np.zeros(b - a) if fl.fa_onboard_g is None else np.nan_to_num(fl.fa_onboard_g[w, i])
                      * (1e-3 * G / (cfg.vehicle(ty)["mass_g"] / 1000.0)))       # m/s^2
                y = commanded_acc_z(cfg, fl, i, w, a_d[:, 2])
                e = fl.p[w, i, 2] - fl.p_d[w, i, 2]
                ie = np.concatenate([[0.0], np.cumsum(0.5 * (e[1:] + e[:-1]) * np.diff(fl.t[w]))])
                X = np.column_stack([e, fl.v[w, i, 2] - v_d[:, 2], ie, fa, np.ones(b - a)])
                ok = (fl.p[w, i, 2] > Z_LAW_MIN_Z_M) & np.isfinite(X).all(axis=1) & np.isfinite(y)
                r = rows.setdefault(ty, {"X": [], "y": []})
                r["X"].append(X[ok])
                r["y"].append(y[ok])
    out = {}
    for ty, r in sorted(rows.items()):
        X, y = np.concatenate(r["X"]), np.concatenate(r["y"])
        if len(y) < 10:
            continue
        flown = bool(np.any(X[:, 3] != 0.0))
        c, r2 = least_squares(X if flown else np.delete(X, 3, axis=1), y)
        out[ty] = {"kp_per_s2": _r(-c[0]), "kd_per_s": _r(-c[1]), "ki_per_s3": _r(-c[2]),
                   "k_fa": _r(-c[3]) if flown else None,
                   "r2": _r(r2), "z_error_mean_m": _r(X[:, 0].mean(), 4),
                   "samples": int(len(y))}
    return out


UNPREDICTED_MIN_G = 3.0   # g: the bottom robot is in a wake (or the ground effect)


def unpredicted(cfg: Config, flights: list[Flight]) -> dict:
    """Per swap scenario: rms and mean (g) of label - fa_onboard_g of the bottom robot
    where |label| > UNPREDICTED_MIN_G, the rms of its slow part there (its HP_WINDOW
    moving average over the labelled samples: what the z loop has time to follow), the
    rms of those labels, and the samples."""
    acc: dict = {}
    for fl, i, fz in _labels_g(cfg, flights):
        if fl.p_d is None or fl.fa_onboard_g is None or len(fl.types) < 2:
            continue
        order = bottom_order(fl)
        if i != order[0]:
            continue
        ok = np.isfinite(fz) & np.isfinite(fl.fa_onboard_g[:, i]) & (np.abs(fz) > UNPREDICTED_MIN_G)
        d = fz - fl.fa_onboard_g[:, i]
        have = np.isfinite(d)
        slow = moving_average(np.where(have, d, 0.0), HP_WINDOW) / np.maximum(
            moving_average(have.astype(float), HP_WINDOW), 1e-9)
        a = acc.setdefault(swap_case(fl.types, i, order), {"d": [], "x": [], "s": []})
        a["d"].append(d[ok])
        a["x"].append(fz[ok])
        a["s"].append(slow[ok])
    out = {}
    for case, a in sorted(acc.items()):
        d, x, sl = (np.concatenate(a[k]) for k in ("d", "x", "s"))
        if d.size:
            out[case] = {"samples": int(d.size), "rms_g": _r(np.sqrt((d ** 2).mean())), "mean_g": _r(d.mean()),
                         "slow_rms_g": _r(np.sqrt((sl ** 2).mean())), "label_rms_g": _r(np.sqrt((x ** 2).mean()))}
    return out


def swap_case(types: list[str], bottom: int, order: list[int]) -> str:
    """The paper's name of a swap: the robots above the bottom one, from the bottom up,
    then "2" and the bottom robot (L2S: a large robot above a small one)."""
    letter = lambda t: t[0].upper()  # noqa: E731
    return "".join(letter(types[k]) for k in order if k != bottom) + "2" + letter(types[bottom])


def swap_errors(flights: list[Flight]) -> dict:
    """Per swap scenario: the worst |z - z_d| (m) of the bottom robot in each swap (the
    robot with the lowest setpoint; one swap = from the start of a horizontal movement
    of its setpoint to the start of the next, whole swaps inside one flight piece only;
    z from the robot's own estimate, as logged), and their median.  Flights need the
    setpoint ``p_d``."""
    per: dict = {}
    for fl, bottom, case, a, b in swaps(flights):
        err = np.abs(fl.p[a:b, bottom, 2] - fl.p_d[a:b, bottom, 2])
        per.setdefault(case, []).append(float(np.nanmax(err)))
    return {case: {"swaps": len(w), "median_worst_z_error_m": _r(np.median(w), 4),
                   "p25_p75_m": [_r(v, 4) for v in np.percentile(w, [25, 75])], "worst_m": _r(max(w), 4)}
            for case, w in sorted(per.items())}


def swaps(flights: list[Flight]):
    """(flight, bottom robot, swap case, start, end) of every whole swap (swap_errors)."""
    for fl in flights:
        if fl.p_d is None or np.isnan(fl.p_d).all() or len(fl.types) < 2:
            continue
        order = bottom_order(fl)
        bottom = order[0]
        case = swap_case(fl.types, bottom, order)
        vd = setpoint_derivatives(fl.t, fl.p_d)[0][:, bottom, :2]
        moving = np.hypot(vd[:, 0], vd[:, 1]) > SWAP_MIN_SPEED
        starts = [s for s, e in runs(moving) if s > 0 and fl.t[e - 1] - fl.t[s] >= SWAP_MIN_S]
        for a, b in zip(starts[:-1], starts[1:]):
            yield fl, bottom, case, a, b


def swap_geometry(flights: list[Flight]) -> dict:
    """Over every swap (swaps()): the medians of the bottom robot's horizontal setpoint
    travel (m, start of the movement to the next one's) and peak setpoint speed (m/s)."""
    travel, peak, last, v_d = [], [], None, None
    for fl, bottom, _, a, b in swaps(flights):
        if fl is not last:                    # swaps() yields a flight's swaps one after another
            last, v_d = fl, setpoint_derivatives(fl.t, fl.p_d)[0]
        pd = fl.p_d[a:b, bottom, :2]
        travel.append(float(np.hypot(*(pd[-1] - pd[0]))))
        peak.append(float(np.nanmax(np.hypot(*v_d[a:b, bottom, :2].T))))
    return {"swaps": len(travel), "median_travel_m": float(np.median(travel)) if travel else None,
            "median_peak_speed_mps": float(np.median(peak)) if peak else None}


def tilt_deg(q: np.ndarray) -> np.ndarray:
    """Angle (deg) between the body z axis and the vertical, q [..., 4] (w, x, y, z)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    bz = 1.0 - 2.0 * (q[..., 1] ** 2 + q[..., 2] ** 2)
    return np.degrees(np.arccos(np.clip(bz, -1.0, 1.0)))


def swap_attitude(flights: list[Flight]) -> dict:
    """Per swap scenario, the bottom robot (swap_errors' swaps): the medians over the
    swaps of its largest tilt (deg), its largest horizontal error |p_xy - p_d,xy| (m),
    from its own estimate as logged, its largest motor command's departure from the
    four motors' mean (PWM in [0, 1]: what its attitude loop asked), how far the
    four motors' mean rose above its median over the swap (what its z loop got), its
    largest single motor command (PWM; 1 is saturation: no thrust left to fight a
    wake with), and the largest departure of the departure's HP_WINDOW moving average
    (its slow part: what a moment steadier than 0.2 s asks; the rest is fast)."""
    per: dict = {}
    for fl, bottom, case, a, b in swaps(flights):
        eh = np.hypot(*(fl.p[a:b, bottom, :2] - fl.p_d[a:b, bottom, :2]).T)
        pwm = fl.pwm[a:b, bottom]
        mean = pwm.mean(1)
        dep = pwm - mean[:, None]
        per.setdefault(case, []).append((float(np.nanmax(tilt_deg(fl.q[a:b, bottom]))), float(np.nanmax(eh)),
                                         float(np.nanmax(np.abs(dep))),
                                         float(np.nanmax(mean) - np.nanmedian(mean)), float(np.nanmax(pwm)),
                                         float(np.nanmax(np.abs(moving_average(dep, HP_WINDOW))))))
    keys = ("median_max_tilt_deg", "median_max_xy_error_m", "median_max_motor_spread", "median_mean_pwm_rise",
            "median_max_motor_pwm", "median_max_slow_motor_spread")
    return {case: {"swaps": len(w), **{k: _r(np.median([x[n] for x in w]), 2 if n == 0 else 4)
                                       for n, k in enumerate(keys)}} for case, w in sorted(per.items())}
