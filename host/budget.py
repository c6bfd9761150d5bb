"""The 2 ms-tick budget on the emulated Cortex-M4 (ns2host.cm4_count's cost model):
one prediction for a robot with n neighbours plus the environment, and one
controller step (position + attitude), against 20 % of a 500 Hz tick at 168 MHz.

Used by benchmarks/bench_target.py (the numbers) and by the tests (the on-board
network variant must stay within the budget; counts are deterministic)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ns2codegen.config import Config

from ns2codegen.vehicle import vehicle

from . import cm4_count, target
from .cbuild import CModel
from .target import NBR_DT

TICK_US, BUDGET_FRACTION = 2000.0, 0.2
BUDGET_US = TICK_US * BUDGET_FRACTION


def neighbors(cfg: Config, n: int, rng: np.random.Generator) -> np.ndarray:
    """n neighbours of random types close above and around the robot (all inside
    the interaction volume, so all of them are evaluated)."""
    nb = np.zeros(max(n, 1), NBR_DT)
    nb["type"] = rng.integers(0, cfg.num_robot_types, len(nb))
    nb["rel"] = np.column_stack([rng.uniform(-0.2, 0.2, (len(nb), 2)), rng.uniform(0.1, 1.0, len(nb)),
                                 rng.normal(0, 0.3, (len(nb), 3))])
    return nb


def prediction_run(cm: cm4_count.Cm4, fn: str, nb: np.ndarray, n: int) -> tuple[cm4_count.Run, dict]:
    """``fn`` (ns2_predict_f32 / _q15) for a small robot at 0.8 m with the first n of
    ``nb``; returns the run and the addresses of its arguments (for further calls)."""
    cm.reset_scratch()
    args = {"p": cm.write(np.float32([0.1, -0.2, 0.8]).tobytes()),
            "v": cm.write(np.float32([0.2, 0.0, -0.1]).tobytes()),
            "info": cm.write(bytes(16)), "nbrs": cm.write(nb.tobytes())}
    _, _, run = cm.call(fn, 0, args["p"], args["v"], args["nbrs"], n, args["info"])
    used = int.from_bytes(cm.read(args["info"] + 4, 2), "little")
    if used != n:
        raise AssertionError(f"{used} of {n} neighbours used")
    return run, args


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
    """A whole prediction with n neighbours + the environment and one controller
    step in one tick, float and fixed point, against BUDGET_US."""
    cm = cm4_count.Cm4(target.build_image(gen))
    nb = neighbors(cfg, n, np.random.default_rng(seed))
    ctrl_us = sum(r.microseconds for r in controller_runs(gen, cfg).values())
    out = {"neighbors": n, "budget_us": BUDGET_US, "controller_step_us": round(ctrl_us, 2)}
    for name, fn in (("float", "ns2_predict_f32"), ("fixed", "ns2_predict_q15")):
        run, _ = prediction_run(cm, fn, nb, n)
        total = run.microseconds + ctrl_us
        out[name] = {"prediction_us": round(run.microseconds, 1), "total_us": round(total, 1),
                     "meets_budget": total <= BUDGET_US}
    return out
