"""The tables of calibration.md (``make calibrate``, ns2exp.calibrate): the real flights'
statistics (paper/flightstats.py) against each simulator's replays of them, the replayed
swaps, the paper's L2S swap flown by the authors' controller, the z law read off the logs,
the wake at the real states and its lateral push.  Moved out of the simulator's
host/sim/calibration.py (the ground truth against the paper's points): they report the
paper's reproduction, not the simulator."""
from __future__ import annotations

SIM_TO_REAL_TOL = 0.3   # the goal: the simulated median worst z error within 30 % of the real


def _cell(x, nd: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, list):
        return "/".join(_cell(v, 2) for v in x)
    return f"{x:.{nd}f}"


def _ratio(sim, real) -> str:
    if sim is None or real is None or isinstance(sim, list) or not real:
        return ""
    return f"{sim / real:.2f}"


def _within(sim: float, real: float) -> bool:
    return abs(sim / real - 1.0) <= SIM_TO_REAL_TOL


def roughness_table(cmp: dict, judged: str = "rough") -> str:
    """Every statistic of paper/flightstats.py: real against each simulator of
    ``cmp`` (experiments/calibrate.py compare: ``real`` and ``simulators``, in order),
    with ``judged`` / real."""
    sims = list(cmp["simulators"])
    lines = ["| statistic | real | " + " | ".join(sims) + f" | {judged} / real |",
             "|---|---|" + "---|" * (len(sims) + 1)]
    real = cmp["real"]

    def get(d: dict, path: tuple):
        for k in path:
            if not isinstance(d, dict) or k not in d:
                return None
            d = d[k]
        return d

    def row(label: str, path: tuple, nd: int = 3):
        r = get(real, path)
        cells = [get(cmp["simulators"][v], path) for v in sims]
        lines.append(f"| {label} | {_cell(r, nd)} | " + " | ".join(_cell(c, nd) for c in cells)
                     + f" | {_ratio(get(cmp['simulators'][judged], path), r)} |")

    for ty in sorted(real["free_air"]):
        for st in ("mean_g", "std_g", "fast_std_g", "band_fraction", "motor_noise"):
            extra = " (0-0.5, 0.5-2, 2-5, 5-20, 20-50 Hz)" if st == "band_fraction" else ""
            row(f"free air, {ty}: {st}{extra}", ("free_air", ty, st), 4 if st == "motor_noise" else 3)
        for st in ("z_error_mean_m", "z_error_std_m"):
            row(f"free air, {ty}: {st}", ("z_loop", "by_type", ty, st), 4)
    for st in ("kp_per_s2", "kd_per_s", "r2"):
        row(f"free air, z loop identified (all types): {st}", ("z_loop", "fit", st))
    for ty in sorted(real.get("z_law", {})):
        for st in ("kp_per_s2", "kd_per_s", "ki_per_s3", "k_fa", "r2", "z_error_mean_m"):
            row(f"swap flights, z law read off every robot, {ty}: {st}", ("z_law", ty, st), 4 if st.startswith("z") else 3)
    for pair in sorted(real["wake_scatter"]):
        for st in ("scatter_g", "fast_scatter_g", "mean_abs_g"):
            row(f"{pair}: {st}", ("wake_scatter", pair, st))
    for pair in sorted(real.get("wake_lateral", {})):
        for st in ("push_out_g", "fz_g"):
            row(f"{pair}, beside the wake's axis: {st}", ("wake_lateral", pair, st))
    k = real.get("lateral_k_xy")
    for key in ("all", "small", "large") if k else ():
        row(f"wake's lateral push per unit r / sigma read off the labels (aero.py K_XY, the truth's "
            f"{k['truth_k_xy']}), {key} robots", ("lateral_k_xy", key, "k_xy"))
    for ty in sorted(real["battery"]):
        for st in ("start_V", "slope_V_per_min"):
            row(f"battery, {ty}: {st}", ("battery", ty, st), 4 if st == "slope_V_per_min" else 3)
    for case in sorted(real.get("unpredicted", {})):
        for st in ("rms_g", "mean_g", "slow_rms_g", "label_rms_g"):
            row(f"swap {case}, bottom robot in a wake: label - prediction flown, {st}", ("unpredicted", case, st))
    for case in sorted(real.get("attitude", {})):
        row(f"swap {case}, bottom robot: median largest tilt (deg)", ("attitude", case, "median_max_tilt_deg"), 1)
        row(f"swap {case}, bottom robot: median largest xy error (m)", ("attitude", case, "median_max_xy_error_m"), 4)
        row(f"swap {case}, bottom robot: median largest motor departure from the motors' mean (PWM)",
            ("attitude", case, "median_max_motor_spread"), 4)
        row(f"swap {case}, bottom robot: median largest departure of its 0.2 s average (PWM)",
            ("attitude", case, "median_max_slow_motor_spread"), 4)
        row(f"swap {case}, bottom robot: median rise of the motors' mean PWM", ("attitude", case, "median_mean_pwm_rise"), 4)
        row(f"swap {case}, bottom robot: median largest single motor command (PWM, 1: saturated)",
            ("attitude", case, "median_max_motor_pwm"), 4)
    for case in sorted(real["swaps"]):
        row(f"swap {case}: median worst z error (m)", ("swaps", case, "median_worst_z_error_m"), 4)
    return "\n".join(lines) + "\n"


def sim_to_real_table(cmp: dict) -> str:
    """Per swap scenario of the replayed flights: median worst z error of the bottom
    robot (cm), real against each simulator with its ratio to the real, "*" where
    within SIM_TO_REAL_TOL; the last row counts the scenarios within it."""
    sims = list(cmp["simulators"])
    lines = ["| scenario | swaps | real (cm) | " + " | ".join(f"{v}: cm (/ real)" for v in sims) + " |",
             "|---|---|---|" + "---|" * len(sims)]
    within = dict.fromkeys(sims, 0)
    cases = sorted(cmp["real"]["swaps"].items())
    for case, r in cases:
        rv = r["median_worst_z_error_m"]
        cells = []
        for v in sims:
            x = cmp["simulators"][v]["swaps"].get(case, {}).get("median_worst_z_error_m")
            if x is None:
                cells.append("-")
                continue
            ok = _within(x, rv)
            within[v] += ok
            cells.append(f"{100 * x:.1f} ({_ratio(x, rv)}{'*' if ok else ''})")
        lines.append(f"| {case} | {r['swaps']} | {100 * rv:.1f} | " + " | ".join(cells) + " |")
    lines.append("| within 30 % (*) | | | " + " | ".join(f"{within[v]} of {len(cases)}" for v in sims) + " |")
    return "\n".join(lines) + "\n"


def read_law_table(law: dict, fit_rows: list | None = None) -> str:
    """The z law read off the logs (ns2paper.gains.READ_LAW's form) and, if given, its fit
    (experiments/calibrate.py fit_read_law): per iteration and type, what the replay
    read (Kp, Kd, Ki, k_fa, the z error's mean) against the real reading."""
    lines = ["| type | Kp (1/s^2) | Kd (1/s) | Ki (1/s^3) | k_fa | mass parameter (g) |", "|---|---|---|---|---|---|"]
    for ty, zl in sorted(law.items()):
        lines.append(f"| {ty} | {zl['kp']:.2f} | {zl['kd']:.2f} | {zl['ki']:.2f} | {zl['k_fa']:.2f} | "
                     f"{1000 * zl['mass_kg']:.1f} |")
    if fit_rows:
        head, rows = fit_rows[0], fit_rows[1:]
        lines += ["", f"Read off the real flights {', '.join(head['flights'])} and their replays "
                      "(Kp / Kd / Ki / k_fa / mean z error cm):", "",
                  "| iteration | type | real | replay | largest miss |", "|---|---|---|---|---|"]

        def cells(z):
            return (f"{z['kp_per_s2']:.2f} / {z['kd_per_s']:.2f} / {z['ki_per_s3']:.2f} / {_cell(z['k_fa'], 2)} / "
                    f"{100 * z['z_error_mean_m']:.2f}")
        for r in rows:
            for ty in sorted(r["read"]):
                lines.append(f"| {r['iteration']} | {ty} | {cells(head['real'][ty])} | {cells(r['read'][ty])} | "
                             f"{r['miss']:.3f} |")
    return "\n".join(lines) + "\n"


def wake_profile_table(wake: dict) -> str:
    """experiments/calibrate.py fit_wake: the real labels of robots under a neighbour
    against the truth at the same logged states, with the paper's wake and the fitted
    one, per pair and horizontal offset; the rms of the difference."""
    lines = [f"The wake's initial width x {wake['sigma0_scale']:.3f}, spreading rate x {wake['spread_scale']:.3f} "
             f"(rms of label - truth over {wake['samples']} samples: {wake['rms_paper_g']:.2f} g with the paper's "
             f"wake, {wake['rms_fitted_g']:.2f} g fitted).", "",
             "| pair | offset (cm) | samples | real f_a,z (g) | truth, the paper's wake | truth, fitted |",
             "|---|---|---|---|---|---|"]
    for pair, rows in wake["profile"].items():
        for r in rows:
            lo, hi = (100 * v for v in r["r_m"])
            lines.append(f"| {pair} | {lo:.0f}-{hi:.0f} | {r['samples']} | {r['real_g']:.1f} | {r['paper_g']:.1f} | "
                         f"{r['fitted_g']:.1f} |")
    return "\n".join(lines) + "\n"


def lateral_table(lateral: dict) -> str:
    """experiments/calibrate.py fit_lateral: the lateral push per unit r / sigma read off
    the labels (lateral_k_xy) of the real pair swaps and of their replays at each
    constant flown, per robot type, and the fit."""
    flown = {**{f"replay, K_XY {k}": v for k, v in lateral["flown"].items()},
             "replay at the fit": lateral["check"]}
    types = sorted(lateral["k_xy"])
    lines = ["| reading (K_XY of the labels) | " + " | ".join(types) + " |", "|---|" + "---|" * len(types)]
    for label, r in {"real": lateral["real"], **flown}.items():
        lines.append(f"| {label} | " + " | ".join(_cell(r.get(t, {}).get("k_xy")) for t in types) + " |")
    return ("\n".join(lines) + "\n\nFitted: " + ", ".join(f"{t} {lateral['k_xy'][t]}" for t in types)
            + " (the line through the two replays, solved for the real reading); replays of "
            + ", ".join(lateral["flights"]) + ", the authors' controller flying the logged prediction, the "
            "turbulence off.\n")


def paper_l2s_table(l2s: dict) -> str:
    """experiments/calibrate.py paper_l2s: simulated against the paper's median worst z error."""
    lines = ["| controller | swaps | simulated (cm) | paper (cm) | simulated / paper | within 30 % |",
             "|---|---|---|---|---|---|"]
    for c, r in l2s.items():
        sim, paper = r["median_worst_z_error_m"], r["paper_m"]
        lines.append(f"| {c} | {len(r['worst_z_error_m'])} | {100 * sim:.1f} | {100 * paper:.0f} | {_ratio(sim, paper)} | "
                     f"{'yes' if _within(sim, paper) else 'no'} |")
    return "\n".join(lines) + "\n"
