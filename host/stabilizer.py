"""One 1 ms stabilizer iteration on the emulated Cortex-M4: the firmware's Kalman
estimator and stock PID controller next to the ns2 app.

The loop runs at RATE_MAIN_LOOP = 1 kHz.  ``build_image`` compiles, with the
firmware's own compiler flags (-Os, gnu11, -ffunction-sections, its ARCH_CFLAGS):
kalman_core.c + mm_position.c (the estimator task's iteration with a position
measurement), controller_pid.c and the PID code it uses, peer_localization.c
(those with ``UNIT_TEST_MODE`` as the firmware's Python bindings compile them), and
the app (firmware/app/src, NS2_INFER) with host/cf_stabilizer.c's entry points into
one ELF for the STM32F405 (cached by content).  ``iteration`` counts each part
with ns2host.cm4_count (the same emulator and cost model as the library) over the
ticks of a 100 Hz period and reports the worst tick of each.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from ns2codegen.export import export_config

from . import cfapp, cm4_count, crazyflie
from .cbuild import BUILD_ROOT, REPO, cached, compile_error, content_hash, flags
from .target import ARM_CC, TARGET_DIR

FIRMWARE_SOURCES = (
    "src/modules/src/kalman_core/kalman_core.c", "src/modules/src/kalman_core/mm_position.c",
    "src/modules/src/controller/controller_pid.c", "src/modules/src/controller/position_controller_pid.c",
    "src/modules/src/controller/attitude_pid_controller.c", "src/utils/src/pid.c", "src/utils/src/filter.c",
    "src/utils/src/num.c", "src/modules/src/peer_localization.c",
    # the CMSIS-DSP functions kalman_core uses (vendor/Kbuild compiles them for the firmware)
    "vendor/CMSIS/CMSIS/DSP/Source/MatrixFunctions/arm_mat_mult_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/MatrixFunctions/arm_mat_trans_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/FastMathFunctions/arm_cos_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/FastMathFunctions/arm_sin_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/CommonTables/arm_common_tables.c",
)
ARCH_CFLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-fno-math-errno",
               "-DARM_MATH_CM4", "-D__FPU_PRESENT=1", "-mfp16-format=ieee", *cfapp.FIRMWARE_DEFINES)
KBUILD_CFLAGS = ("-Os", "-std=gnu11", "-fno-strict-aliasing", "-ffunction-sections", "-fdata-sections",
                 "-DCRAZYFLIE_FW", "-Wall", "-Werror", "-Wno-array-bounds")
DRIVER = REPO / "host" / "cf_stabilizer.c"
ENTRY_POINTS = ("bench_init", "bench_radio", "bench_estimator", "bench_pid", "bench_app")
TICK_US, CLOCK_HZ = 1000.0, cm4_count.CLOCK_HZ
HIST_PERIOD_MS = 10  # NS2_PEERS_HIST_PERIOD_MS: the app records its wake memory at its 100 Hz position tick


def build_image(gen_dir: Path, infer: str = "fixed") -> Path:
    """The ELF with the estimator, the PID controller, the app and the entry points."""
    gen_dir = Path(gen_dir).resolve()
    app = cfapp.app_config()  # autoconf.h: the configuration the app flies with
    fw = crazyflie.firmware_dir()
    fixed, flt = {"fixed": (1, 0), "float": (0, 1), "both": (1, 1)}[infer]
    app_flags = ["-ffp-contract=off", f"-DNS2_APP_FIXED={fixed}", f"-DNS2_APP_FLOAT={flt}",
                 *[f"-I{REPO / i}" for i in flags()["NS2_INCLUDES"]], f"-I{gen_dir}"]
    inc = [a for d in cfapp.firmware_includes(app) for a in ("-I", str(d))] + \
        ["-include", str(app / "include/generated/autoconf.h")]
    units = [(fw / s, ["-DUNIT_TEST_MODE", "-Wno-unused-const-variable"]) for s in FIRMWARE_SOURCES] + \
        [(REPO / "firmware/app/src" / s, app_flags) for s in ("ns2_app.c", "ns2_lib.c")] + \
        [(DRIVER, []), (TARGET_DIR / "startup_cm4.c", [])]
    key = content_hash([repr((ARCH_CFLAGS, KBUILD_CFLAGS, app_flags, ARM_CC, ENTRY_POINTS)), *[u for u, _ in units],
                        *cfapp.app_inputs(gen_dir), TARGET_DIR / "stm32f405.ld", app / "include/generated/autoconf.h"], 16)
    out = BUILD_ROOT.parent / "arm" / f"cf_stabilizer-{key}.elf"

    def build(tmp: Path) -> None:
        objs = []
        for i, (src, extra) in enumerate(units):
            obj = tmp / f"{i}-{src.stem}.o"
            cmd = [ARM_CC, *ARCH_CFLAGS, *KBUILD_CFLAGS, *extra, *inc, "-g", "-c", str(src), "-o", str(obj)]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                raise compile_error(" ".join(cmd[-3:]), cmd, r)
            objs.append(str(obj))
        cmd = [ARM_CC, *ARCH_CFLAGS, "--specs=nosys.specs", "-nostartfiles", f"-T{TARGET_DIR / 'stm32f405.ld'}",
               "-Wl,--gc-sections", *[f"-Wl,--undefined={e}" for e in ENTRY_POINTS], *objs, "-lm", "-o", str(tmp / out.name)]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise compile_error(" ".join(cmd[-3:]), cmd, r)

    return cached(out, build, product=None)


MODELS = {"zero_wait": "cycles", "memory": "memory_cycles"}  # cm4_count.Run's two counts


def _worst(runs: list[cm4_count.Run]) -> dict:
    """The worst tick's counts (zero wait and memory model) and where its zero-wait
    cycles go (the eight costliest functions)."""
    w = max(runs, key=lambda r: r.cycles)
    out = {"instructions": w.instructions, "cycles": w.cycles, "us_at_168MHz": round(w.microseconds, 1),
           "cycles_by_function": dict(w.cycles_by_function.most_common(8))}
    m = max(runs, key=lambda r: r.memory_cycles)
    return {**out, "memory_cycles": m.memory_cycles, "memory_us_at_168MHz": round(m.memory_microseconds, 1)}


def _share(cycles: float) -> float:
    return round(cycles / CLOCK_HZ * 1e6 / TICK_US, 4)


def iteration(gen_dir: Path, n_peers: int = 15, infer: str = "fixed", adapt: bool = False) -> dict:
    """Each part's worst 1 ms tick, the worst iteration of the estimator with each
    controller, and the mean CPU load, over 20 ticks (two 100 Hz periods) after a
    warm-up period (Kalman filter and app running, prediction jobs under way), at zero
    wait states and on the memory-system model (cm4_count.STM32F405_168MHZ).

    The estimator's costly tick (its 100 Hz prediction and a mocap position
    measurement, counted together: the worst case) is not tied to the controllers'
    ticks in the firmware: estimator_kalman.c predicts when its own clock passes
    nextPredictionMs, and mocap arrives when the radio brings it.  So each part is
    counted tick by tick and the worst iteration is taken over all 10 phases of that
    tick against the controllers' 100 Hz period (the stock PID's worst tick, the app's
    position tick, lands on it in one of them).  The estimator runs in its own, lower
    priority task, so its worst tick may spill into the next millisecond; the mean
    load says whether the CPU keeps up.  ``adapt``: with the on-board adaptation on
    (PARAM ns2adapt.enable = 1 written into the app's adaptCfg after boot; the label is
    computed either way).  With wake memory (the export's model.history_ms) the warm-up
    lasts until the app's history ring holds the longest lag (a 200 ms lag: 21 periods),
    so that every past state comes from the ring."""
    lag_ticks = max(((ms + HIST_PERIOD_MS // 2) // HIST_PERIOD_MS for ms in export_config(gen_dir).history_ms),
                    default=0)  # the app's rounding (ns2_peers.c), in history ticks = 100 Hz periods
    cm = cm4_count.Cm4(build_image(gen_dir, infer))
    a = 2.0 * np.pi * np.arange(n_peers) / n_peers  # a ring 0.3 m around and 0.3 m above (inside V)
    ring = np.stack([0.3 * np.cos(a), 0.3 * np.sin(a), np.full(n_peers, 1.3)], 1).astype("<f4")
    cm.call("bench_init", n_peers, cm.write(ring.tobytes()))
    if adapt:
        cm.mu.mem_write(cm.addr("adaptCfg"), b"\x01")   # ns2_adapt_cfg_t.enable, its first byte
    runs: dict[str, list] = {"estimator": [], "estimator_other": [], "pid": [], "app": []}
    period = 10  # PREDICT_RATE = 100 Hz, mocap at 100 Hz; the controllers' 100 Hz period
    warm = period * (1 + lag_ticks)  # ticks before counting (one period without wake memory)
    for tick in range(1, warm + 2 * period + 1):
        heavy, counted = int(tick % period == 0), tick > warm  # the warm-up runs untraced
        cm.call("bench_radio", tick, count=False)  # mocap broadcasts (the radio task's time, not counted)
        _, _, e = cm.call("bench_estimator", tick, heavy, heavy, count=counted)
        _, _, p = cm.call("bench_pid", tick, count=counted)
        _, _, a = cm.call("bench_app", tick, count=counted)
        if counted:
            runs["estimator" if heavy else "estimator_other"].append(e)
            runs["pid"].append(p)
            runs["app"].append(a)
    w = {k: _worst(v) for k, v in runs.items()}
    n_used = int.from_bytes(cm.read(cm.addr("nUsed"), 1), "little")
    ticks = len(runs["pid"])

    def worst_tick(ctrl: str) -> dict:
        """max over the ticks of estimator + ctrl, for each phase f (the estimator's
        costly tick at the ticks with tick % 10 == f; share_by_phase[f])"""
        out = {}
        for model, attr in MODELS.items():
            c = {t: getattr(r, attr) for t, r in zip(range(warm + 1, warm + 2 * period + 1), runs[ctrl])}
            est = [w["estimator_other"][attr], w["estimator"][attr]]
            by_phase = [max(est[int(t % period == f)] + c[t] for t in c) for f in range(period)]
            out[model] = {"cycles": max(by_phase), "share_of_1ms": _share(max(by_phase)),
                          "share_by_phase": [_share(x) for x in by_phase]}
        return out

    def load(ctrl: str) -> dict:
        return {model: _share(sum(getattr(r, attr) for r in runs["estimator"] + runs["estimator_other"] + runs[ctrl])
                              / ticks) for model, attr in MODELS.items()}

    stock, app = worst_tick("pid"), worst_tick("app")
    return {"tick_us": TICK_US, "clock_hz": CLOCK_HZ, "peers_broadcast": n_peers, "app_neighbors_used": n_used,
            "warm_up_ticks": warm,
            "infer": infer, "adaptation": adapt, "estimator_kalman_predict_and_position": w["estimator"],
            "estimator_kalman_other_ticks": w["estimator_other"],
            "stock_controller_pid": w["pid"], "app_controller_oot": w["app"],
            # the app's cycles in each tick of a period, tick % 10 = 0..9
            "app_by_tick": {model: [getattr(r, attr) for r in runs["app"][period - 1:2 * period - 1]]
                            for model, attr in MODELS.items()},
            "stock_worst_tick": stock, "app_worst_tick": app,
            "app_adds_to_worst_tick": {m: round(app[m]["share_of_1ms"] - stock[m]["share_of_1ms"], 4) for m in MODELS},
            "stock_mean_load": load("pid"), "app_mean_load": load("app")}


ADAPT_BUDGET_SHARE = 0.10   # of 1 ms, added to the stock worst tick (issue 53)


def with_adaptation(gen_dir: Path, n_peers: int = 15, infer: str = "fixed") -> dict:
    """The app with the adaptation on (``iteration(adapt=True)``: in the bench's ring every
    tick is a wake, so no update) against the stock worst tick, and the bound with a whole
    label-and-update step (budget.adapt_runs) added to the position tick (k = 0 of the app's
    period, where ns2_pilot_position runs them) with the estimator's costly tick on it: the
    worst of that and the app's worst iteration as counted (the label is computed in every
    position tick already, so it is counted twice: an upper bound)."""
    from .budget import adapt_runs

    it = iteration(gen_dir, n_peers, infer, adapt=True)
    runs = adapt_runs(gen_dir, export_config(gen_dir))
    out = {"app_worst_tick": it["app_worst_tick"], "app_adds_to_worst_tick": it["app_adds_to_worst_tick"]}
    for model, attr in MODELS.items():
        step = getattr(runs["label_step"], attr) + getattr(runs["adapt_step_update"], attr)
        est = it["estimator_kalman_predict_and_position"][attr]
        worst = max(it["app_worst_tick"][model]["cycles"], est + it["app_by_tick"][model][0] + step)
        bound = it["app_adds_to_worst_tick"][model] + (worst - it["app_worst_tick"][model]["cycles"]) / CLOCK_HZ * 1e3
        out[f"update_step_cycles_{model}"] = step
        out[f"adds_to_worst_tick_bound_{model}"] = round(bound, 4)
        out[f"within_budget_{model}"] = bound <= ADAPT_BUDGET_SHARE
    return out
