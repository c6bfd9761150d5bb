"""The 2 ms-tick budget on the emulated Cortex-M4 (ns2host.cm4_count's cost model):
one prediction for a robot with n neighbours plus the environment, and one
controller step (position + attitude), against 20 % of a 500 Hz tick at 168 MHz,
at zero wait states and on the modelled memory system (flash wait states, ART
accelerator; cm4_count.STM32F405_168MHZ), with the weight tables in flash or
(``defines``, target.ram_placement) in SRAM.  The firmware's stabilizer loop runs
at 1 kHz (1 ms iterations); the attitude controller every second iteration.

RAM for tables: the stock cf2 build leaves about 37.9 KB of SRAM and 648 B of CCM
free (../shared/crazyflie-firmware/README.md); APP_RESERVE_BYTES of it are kept
for the app itself (jobs, peers, its task), an assumption until the app's own RAM
is measured in the real firmware build.

A network with wake memory (model.history_ms, NS2_HISTORY_LAGS > 0 in its export) is
counted through the entry points the app calls (ns2_predict_*_hist, ns2_job_begin_hist),
with each neighbour's 6 (1 + lags) inputs and the robot's own past; a network without
it through the plain ones, as before.

Used by benchmarks/bench_target.py (the numbers) and by the tests (the on-board
network variant must stay within the budget; counts are deterministic)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ns2codegen.config import Config

from ns2codegen.vehicle import vehicle

from . import cm4_count, target
from .cbuild import CModel
from .target import nbr_dtype

TICK_US, BUDGET_FRACTION = 2000.0, 0.2
BUDGET_US = TICK_US * BUDGET_FRACTION
STABILIZER_ITERATION_US = 1000.0  # the firmware's 1 kHz stabilizer loop
SRAM_FREE_BYTES, CCM_FREE_BYTES = 37_900, 648  # stock cf2 build
APP_RESERVE_BYTES = 4096
TABLE_RAM_BUDGET_BYTES = SRAM_FREE_BYTES - APP_RESERVE_BYTES


P_SELF, V_SELF = np.float32([0.1, -0.2, 0.8]), np.float32([0.2, 0.0, -0.1])  # the counted robot


def neighbors(cfg: Config, n: int, rng: np.random.Generator) -> np.ndarray:
    """n neighbours of random types close above and around the robot (all inside
    the interaction volume, so all of them are evaluated), ns2_neighbor_t of the
    config's phi input (cfg.input_dim).  With wake memory each neighbour's past
    relative state at each lag of cfg.history_ms is that of constant relative
    velocity (the same random draws as without: the present states are the same)."""
    nb = np.zeros(max(n, 1), nbr_dtype(cfg.input_dim))
    nb["type"] = rng.integers(0, cfg.num_robot_types, len(nb))
    now = np.column_stack([rng.uniform(-0.2, 0.2, (len(nb), 2)), rng.uniform(0.1, 1.0, len(nb)),
                           rng.normal(0, 0.3, (len(nb), 3))])
    nb["rel"] = np.concatenate([now] + [np.column_stack([now[:, :3] - now[:, 3:] * (ms / 1000), now[:, 3:]])
                                        for ms in cfg.history_ms], 1)
    return nb


def own_past(cfg: Config) -> np.ndarray | None:
    """The counted robot's own [p; v] at each lag of cfg.history_ms (constant
    velocity: ns2_predict_*_hist's own_past); None without wake memory."""
    if not cfg.history_ms:
        return None
    return np.float32([[*(P_SELF - V_SELF * np.float32(ms / 1000)), *V_SELF] for ms in cfg.history_ms])


def prediction_run(cm: cm4_count.Cm4, fn: str, nb: np.ndarray, n: int,
                   past: np.ndarray | None = None) -> tuple[cm4_count.Run, dict]:
    """``fn`` (ns2_predict_f32 / _q15) for a small robot at 0.8 m with the first n of
    ``nb``; with ``past`` (own_past: a network with wake memory) ``fn``_hist with it.
    Returns the run and the addresses of its arguments (for further calls:
    job_begin)."""
    if (past is None) != (nb["rel"].shape[-1] == 6):
        raise ValueError(f"neighbours of {nb['rel'].shape[-1]} inputs with {'no' if past is None else 'an'} "
                         "own past: give own_past(cfg) exactly for a network with wake memory")
    cm.reset_scratch()
    args = {"p": cm.write(P_SELF.tobytes()), "v": cm.write(V_SELF.tobytes()),
            "info": cm.write(bytes(16)), "nbrs": cm.write(nb.tobytes())}
    if past is None:
        _, _, run = cm.call(fn, 0, args["p"], args["v"], args["nbrs"], n, args["info"])
    else:
        args["past"] = cm.write(np.ascontiguousarray(past, "<f4").tobytes())
        _, _, run = cm.call(f"{fn}_hist", 0, args["p"], args["v"], args["past"], args["nbrs"], n, args["info"])
    used = int.from_bytes(cm.read(args["info"] + 4, 2), "little")
    if used != n:
        raise AssertionError(f"{used} of {n} neighbours used")
    return run, args


def job_begin(cm: cm4_count.Cm4, args: dict, n: int) -> tuple[int, cm4_count.Run]:
    """ns2_job_begin_hist of the robot and the first n neighbours of ``args``
    (prediction_run's; own_past NULL without wake memory: that is ns2_job_begin, a
    wrapper the vector image does not keep) into a fresh job in the scratch area;
    returns the job's address and the run."""
    size = cm.symbols["job"][1] if "job" in cm.symbols else 0   # the image's static ns2_job_t
    job = cm.write(bytes(max(2048, size)))
    _, _, run = cm.call("ns2_job_begin_hist", job, 0, args["p"], args["v"], args.get("past", 0), args["nbrs"], n)
    return job, run


def controller_runs(gen: Path, cfg: Config) -> dict[str, cm4_count.Run]:
    """One position step (100 Hz) and one attitude step (500 Hz) of the firmware
    controller, in a hovering, slightly perturbed state (second call: the
    derivative filters are primed)."""
    host = CModel(gen)
    ffi = host.ffi
    c = host.controller([vehicle(cfg, "small")])
    cm = cm4_count.Cm4(target.build_controller_image(gen))
    ctrl = cm.write(bytes(ffi.sizeof("ns2_ctrl_t")))
    cm.call("ns2_ctrl_init", ctrl, cm.write(bytes(ffi.buffer(ffi.addressof(c[0], "veh")))),
            cm.write(bytes(ffi.buffer(ffi.addressof(c[0], "g")))))
    st = ffi.new("ns2_ctrl_state_t *", {"p": [0.01, -0.02, 1.0], "v": [0.1, 0, 0], "q": [0.999, 0.02, -0.03, 0.01],
                                         "w": [0.1, -0.2, 0.05]})
    sp = ffi.new("ns2_setpoint_t *", {"p": [0, 0, 1.0], "yaw": 0.3})
    s_addr, sp_addr = cm.write(bytes(ffi.buffer(st))), cm.write(bytes(ffi.buffer(sp)))
    fa = cm.write(np.float32([0.0, 0.0, -0.05]).tobytes())
    for _ in range(2):
        _, _, pos = cm.call("ns2_ctrl_position", ctrl, s_addr, sp_addr, fa, float_args=(0.01,))
        _, _, att = cm.call("ns2_ctrl_attitude", ctrl, s_addr, float_args=(0.002, 3.9))
    return {"position_step": pos, "attitude_step": att}


def one_tick(gen: Path, cfg: Config, n: int = 15, seed: int = 0) -> dict:
    """A whole prediction with n neighbours + the environment (with wake memory: their
    pasts and the robot's own) and one controller step in one tick, float and
    fixed point, against BUDGET_US: at zero wait
    states (prediction_us, total_us, meets_budget) and on the modelled memory
    system with the tables in flash and with each path's hot tables in SRAM
    (``memory_model``: {"flash": ..., "ram": ...})."""
    nb, past = neighbors(cfg, n, np.random.default_rng(seed)), own_past(cfg)
    ctrl = controller_runs(gen, cfg).values()
    ctrl_us = sum(r.microseconds for r in ctrl)
    ctrl_mem_us = sum(r.memory_microseconds for r in ctrl)
    out = {"neighbors": n, "history_ms": cfg.history_ms, "input_dim": cfg.input_dim, "budget_us": BUDGET_US,
           "controller_step_us": round(ctrl_us, 2), "controller_step_us_memory_model": round(ctrl_mem_us, 2)}
    flash = cm4_count.Cm4(target.build_image(gen))
    for name, fn, path in (("float", "ns2_predict_f32", "f32"), ("fixed", "ns2_predict_q15", "q15")):
        run, _ = prediction_run(flash, fn, nb, n, past)
        total = run.microseconds + ctrl_us
        out[name] = {"prediction_us": round(run.microseconds, 1), "total_us": round(total, 1),
                     "meets_budget": total <= BUDGET_US, "memory_model": {}}
        defines = target.ram_placement(cfg.robot_types[0], path)
        ram_elf = target.build_image(gen, defines=defines)
        for where, cm in (("flash", flash), ("ram", cm4_count.Cm4(ram_elf))):
            r = run if where == "flash" else prediction_run(cm, fn, nb, n, past)[0]
            t = r.memory_microseconds + ctrl_mem_us
            ram_bytes = sum(v["in_ram_bytes"] for v in target.table_bytes(cm.elf).values())
            out[name]["memory_model"][where] = {
                "prediction_us": round(r.memory_microseconds, 1), "total_us": round(t, 1),
                "meets_budget": t <= BUDGET_US, "stall_cycles": {"fetch": r.stalls.fetch, "data": r.stalls.data},
                "tables_in_ram_bytes": ram_bytes, "fits_ram_budget": ram_bytes <= TABLE_RAM_BUDGET_BYTES,
                **({"defines": list(defines)} if where == "ram" else {})}
    return out


def adapt_runs(gen: Path, cfg: Config) -> dict[str, cm4_count.Run]:
    """One position tick of the on-board label (ns2_label_step) and of the adaptation
    (ns2_adapt_step) of a small robot hovering, on the library's target image: the
    adaptation with a recursive least-squares update (its costliest path, tick 18) and
    in a wake (|NN| > wakeG: no update, tick 21), the label's history full."""
    from ns2codegen.onboard import AdaptCfg, LabelCfg

    from . import onboard

    host = CModel(gen)
    ffi = host.ffi
    lc, ac = ffi.new("ns2_label_cfg_t *"), ffi.new("ns2_adapt_cfg_t *")
    onboard._fill_label_cfg(lc, LabelCfg.of_vehicle(cfg.vehicle("small")))
    onboard.fill_adapt_cfg(ac, AdaptCfg())
    cm = cm4_count.Cm4(onboard.build_image(gen))
    lab, ad = cm.write(bytes(ffi.sizeof("ns2_label_t"))), cm.write(bytes(ffi.sizeof("ns2_adapt_t")))
    ac_addr = cm.write(bytes(ffi.buffer(ac)))
    cm.call("ns2_label_init", lab, cm.write(bytes(ffi.buffer(lc))))
    cm.call("ns2_adapt_reset", ad, ac_addr)
    q = cm.write(np.float32([0.999, 0.02, -0.03, 0.01]).tobytes())
    pwm = cm.write(np.float32([0.55, 0.56, 0.54, 0.55]).tobytes())
    runs = {}
    for k in range(22):
        _, _, lab_run = cm.call("ns2_label_step", lab, q, pwm, float_args=(0.01 * np.sin(k), 1.0, 3.9))
        wake = int(k >= 19)         # the labelled tick (two back) is in a wake from k = 21 on: |NN| > wakeG
        _, _, ad_run = cm.call("ns2_adapt_step", ad, ac_addr, wake, 0, float_args=(20.0 if wake else 0.5, -1.0))
        runs["label_step"] = lab_run
        if k in (18, 21):
            runs["adapt_step_wake" if k == 21 else "adapt_step_update"] = ad_run
    theta0_bits = int.from_bytes(cm.read(ad + ffi.offsetof("ns2_adapt_t", "theta"), 4), "little")
    if theta0_bits == 0:
        raise AssertionError("the adaptation did not update (theta still 0)")
    return runs
