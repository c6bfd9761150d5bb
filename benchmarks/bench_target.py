"""Target benchmarks (JSON on stdout): the cross-compiled library on an emulated
Cortex-M4 (unicorn), executed instructions and estimated cycles (cost model in
ns2host/cm4_count.py) per phi and rho evaluation and per full prediction with
1, 4, 15 and 16 neighbours, float and fixed point; microseconds at 168 MHz; the
2 ms-tick budget (host/budget.py), for the paper's network and for the
one-tick on-board variant (ns2codegen.config.ONBOARD_WIDTHS); emlearn's
generated C for the same layer sizes side by side; flash, RAM and worst-case
stack from the cross build; everything at zero wait states and on the modelled
memory system of the STM32F405 (flash wait states, ART accelerator), with the
weight tables in flash and the hot ones in SRAM, against the firmware's 1 kHz
stabilizer loop; the machine's bound for the paper-sized network in one tick.
The network is the export's (--gen; its ns2_config.toml): with wake memory
(model.history_ms) each neighbour has 6 (1 + lags) inputs and the counts run the
*_hist entry points with the robot's own past, as the app does.

    python benchmarks/bench_target.py [--gen firmware/generated]
"""
from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ns2codegen.checkpoint import load_checkpoint, save_checkpoint
from ns2codegen.config import ONBOARD_WIDTHS, Config
from ns2codegen.data.analytic import downwash_dataset
from ns2codegen.export import export, export_config
from ns2codegen.results import stamp
from ns2codegen.train import train
from ns2host import budget, cm4_count, firmware_report, target
from ns2host.cbuild import REPO, flags

PHI_PER_TICK = 4  # sliced prediction: phi evaluations per 500 Hz tick (the app's ns2.phiPerTick)


def macs(dims):
    return sum(a * b for a, b in zip(dims[:-1], dims[1:]))


def _run(r: cm4_count.Run) -> dict:
    """Counts of one run: zero wait states and the modelled memory system."""
    return {"instructions": r.instructions, "cycles": r.cycles, "us_at_168MHz": round(r.microseconds, 1),
            "memory_model_cycles": r.memory_cycles, "memory_model_us": round(r.memory_microseconds, 1),
            "stall_cycles": {"fetch": r.stalls.fetch, "data": r.stalls.data},
            "flash_line_reads": {"fetch_misses": r.stalls.fetch_misses, "prefetches": r.stalls.prefetches,
                                 "data_misses": r.stalls.data_misses}}


def measure_library(elf: Path, cfg: Config) -> dict:
    cm = cm4_count.Cm4(elf)
    nb, past = budget.neighbors(cfg, 16, np.random.default_rng(0)), budget.own_past(cfg)
    out = {}
    phi_macs, rho_macs = macs(cfg.phi_dims()), macs(cfg.rho_dims())
    for name, fn in (("float", "ns2_predict_f32"), ("fixed", "ns2_predict_q15")):
        runs = {}
        for n in (0, 1, 4, 15, 16):
            runs[n], args = budget.prediction_run(cm, fn, nb, n, past)
        sliced = measure_sliced(cm, name, args)
        per_phi = (runs[16].instructions - runs[1].instructions) / 15
        per_phi_cyc = (runs[16].cycles - runs[1].cycles) / 15
        kernel = sum(c for f, c in runs[16].by_function.items() if f.startswith("dense"))
        out[name] = {
            "prediction": {f"{n}_neighbors": _run(r) for n, r in runs.items()},
            "per_phi": {"instructions": round(per_phi), "cycles": round(per_phi_cyc),
                        "us_at_168MHz": round(per_phi_cyc / 168, 2)},
            "per_rho_and_call_overhead": {"instructions": round(runs[0].instructions - per_phi),
                                          "cycles": round(runs[0].cycles - per_phi_cyc)},
            "instructions_per_mac_phi": round(per_phi / phi_macs, 3),
            "kernel_instructions_per_mac": round(kernel / (17 * phi_macs + rho_macs), 3),
            "instruction_mix_16_neighbors": dict(runs[16].mix.most_common(10)),
            "sliced_15_neighbors": dict(sliced, job_ram_bytes=cm.symbols["job"][1]),  # static ns2_job_t of the image
        }
    return out


def measure_sliced(cm: cm4_count.Cm4, name: str, args: dict,
                   n: int = 15, per_step: int = PHI_PER_TICK, ticks: int = 5) -> dict:
    """The app's schedule (firmware/app): the prediction with n neighbours is
    spread over the five 500 Hz ticks of a 100 Hz position period, per_step phi
    evaluations per tick (ns2_job_step_*); at the position tick the previous job
    is finished (rho only, its phi all done) and the next one begun, and that
    tick also steps.  Its cost is the worst tick.  (At 1 kHz: ten 1 ms iterations
    per position period, ``ticks=10``.)  ``args``: budget.prediction_run's."""
    path = "q15" if name == "fixed" else "f32"
    job, begin = budget.job_begin(cm, args, n)
    steps, left = [], n + 1
    while left > 0:
        left, _, step = cm.call(f"ns2_job_step_{path}", job, per_step)
        steps.append(step)
    _, _, fin = cm.call(f"ns2_job_finish_{path}", job, args["info"])
    worst = fin.cycles + begin.cycles + max(s.cycles for s in steps)
    worst_mem = fin.memory_cycles + begin.memory_cycles + max(s.memory_cycles for s in steps)
    return {"neighbors": n, "phi_per_tick": per_step, "ticks_with_phi": len(steps),
            "fits_in_position_period": len(steps) <= ticks, "begin_cycles": begin.cycles,
            "step_cycles": [s.cycles for s in steps], "finish_rho_cycles": fin.cycles, "worst_tick_cycles": worst,
            "worst_tick_us_at_168MHz": round(worst / cm4_count.CLOCK_HZ * 1e6, 1),
            "memory_model_step_cycles": [s.memory_cycles for s in steps],
            "memory_model_worst_tick_cycles": worst_mem,
            "memory_model_worst_tick_us": round(worst_mem / cm4_count.CLOCK_HZ * 1e6, 1)}


def measure_controller(gen: Path, cfg: Config) -> dict:
    return {name: _run(run) for name, run in budget.controller_runs(gen, cfg).items()}


def measure_adaptation(gen: Path, cfg: Config) -> dict:
    """The on-board label and adaptation per 100 Hz position tick (issue 53): the label,
    the adaptation with its RLS update and in a wake; their sum per update."""
    runs = budget.adapt_runs(gen, cfg)
    out = {name: _run(run) for name, run in runs.items()}
    total = runs["label_step"].memory_cycles + runs["adapt_step_update"].memory_cycles
    out["per_update_memory_model_cycles"] = total
    out["per_update_memory_model_us"] = round(total / cm4_count.CLOCK_HZ * 1e6, 2)
    out["share_of_cpu_at_100Hz"] = round(total * 100 / cm4_count.CLOCK_HZ, 6)
    return out


def measure_stabilizer(gen: Path, cfg: Config, ctrl: dict, sliced: bool = True, n: int = 15) -> dict:
    """The prediction against the firmware's 1 kHz stabilizer loop on the modelled
    memory system, float and fixed point, weight tables in flash and the hot ones in
    SRAM (target.ram_placement): the whole prediction with n neighbours + the
    environment in one 1 ms iteration, and (``sliced``) the worst iteration of the
    prediction spread over the ten 1 ms iterations of the 100 Hz position period
    (2 phi per iteration) and over the five 500 Hz attitude ticks (4 phi per tick),
    each with the controller step (position + attitude: the worst iteration)."""
    nb, past = budget.neighbors(cfg, 16, np.random.default_rng(0)), budget.own_past(cfg)
    step = {k: sum(ctrl[s][k] for s in ("position_step", "attitude_step")) for k in ("cycles", "memory_model_cycles")}
    us = 1e6 / cm4_count.CLOCK_HZ
    out = {"iteration_us": budget.STABILIZER_ITERATION_US, "controller_step_us": round(step["cycles"] * us, 1),
           "controller_step_us_memory_model": round(step["memory_model_cycles"] * us, 1),
           "table_ram_budget_bytes": budget.TABLE_RAM_BUDGET_BYTES}
    for name, fn, path in (("float", "ns2_predict_f32", "f32"), ("fixed", "ns2_predict_q15", "q15")):
        out[name] = {}
        for where, defines in (("flash", ()), ("ram", target.ram_placement(cfg.robot_types[0], path))):
            cm = cm4_count.Cm4(target.build_image(gen, defines=defines))
            run, args = budget.prediction_run(cm, fn, nb, n, past)
            ram = sum(v["in_ram_bytes"] for v in target.table_bytes(cm.elf).values())
            one = (run.memory_cycles + step["memory_model_cycles"]) * us
            r = {"tables_in_ram_bytes": ram, "fits_ram_budget": ram <= budget.TABLE_RAM_BUDGET_BYTES,
                 "one_iteration": {"prediction": _run(run), "with_controller_us": round(one, 1),
                                   "with_controller_us_zero_wait": round((run.cycles + step["cycles"]) * us, 1),
                                   "share_of_1ms_iteration": round(one / budget.STABILIZER_ITERATION_US, 3),
                                   "within_400us_of_a_2ms_tick": one <= budget.BUDGET_US}}
            if sliced:
                for key, per, ticks in (("sliced_1kHz_2_phi_per_iteration", 2, 10),
                                        ("sliced_500Hz_4_phi_per_tick", PHI_PER_TICK, 5)):
                    sl = measure_sliced(cm, name, args, n, per, ticks)
                    worst = (sl["memory_model_worst_tick_cycles"] + step["memory_model_cycles"]) * us
                    r[key] = {"worst_iteration_with_controller_us": round(worst, 1),
                              "worst_iteration_with_controller_us_zero_wait":
                                  round((sl["worst_tick_cycles"] + step["cycles"]) * us, 1),
                              "share_of_1ms_iteration": round(worst / budget.STABILIZER_ITERATION_US, 3),
                              "iterations_with_phi": sl["ticks_with_phi"],
                              "fits_in_position_period": sl["fits_in_position_period"]}
            out[name][where] = r
    return out


# Machine bounds of the inner loops (Cortex-M4 TRM cycle counts, zero wait; docs/target.md):
# int16 SMLAD with a register tile of R rows x K neighbours costs per input pair R K SMLAD
# + (R + K) loaded words + one cycle per load instruction; 14 usable core registers hold
# R K accumulators, the live loaded words and two pointers, so R = 4, K = 2 is the best
# tile: 8 SMLAD + 6 words in 3 loads (LDRD: 3 cycles) = 17 cycles per 16 MACs.  One vector
# alone (rho, the environment's phi): 5 accumulators, an LDM of 5 weight words (6 cycles)
# and half an LDRD of two input words: 5 + 6 + 1.5 = 12.5 cycles per 10 MACs.
PAIR_CYCLES_PER_MAC = 17 / 16
SINGLE_CYCLES_PER_MAC = 12.5 / 10
# float: per MAC a VMUL and a VADD (two roundings as in C), 1 cycle each, and the
# weight (VLDM of 8: 9 cycles per 8 words), shared by K neighbours: (2 K + 9/8) / K
FLOAT_SINGLE_CYCLES_PER_MAC, FLOAT_PAIR_CYCLES_PER_MAC = 2 + 9 / 8, (4 + 9 / 8) / 2
FLOAT_SINGLE_INSTR_PER_MAC, FLOAT_PAIR_INSTR_PER_MAC = 2 + 1 / 8, (4 + 1 / 8) / 2


def moonshot(cfg: Config, stab: dict, lib: dict, n: int = 15) -> dict:
    """The paper-sized network, n neighbours + environment + controller step in one
    500 Hz tick within 400 us: the machine's lower bound (only the multiply-
    accumulates, at the best register tile, unpadded, every neighbour paired, zero
    wait) against what the code reaches on the modelled memory system."""
    phi, rho = macs(cfg.phi_dims()), macs(cfg.rho_dims())
    total_macs = (n + 1) * phi + rho
    us = 1e6 / cm4_count.CLOCK_HZ
    bound = n * phi * PAIR_CYCLES_PER_MAC + (phi + rho) * SINGLE_CYCLES_PER_MAC
    ctrl = stab["controller_step_us"] / us
    best = stab["fixed"]["ram"]["one_iteration"]["prediction"]
    fbound = n * phi * FLOAT_PAIR_CYCLES_PER_MAC + (phi + rho) * FLOAT_SINGLE_CYCLES_PER_MAC
    return {
        "macs_per_prediction": total_macs,
        "target_us": budget.BUDGET_US, "target_cycles_per_mac": round((budget.BUDGET_US / us - ctrl) / total_macs, 3),
        "bound_cycles": round(bound), "bound_us_with_controller": round((bound + ctrl) * us, 1),
        "bound_cycles_per_mac": round(bound / total_macs, 3),
        "possible": (bound + ctrl) * us <= budget.BUDGET_US,
        "fixed_ram_memory_model": {"prediction_cycles": best["memory_model_cycles"],
                                   "cycles_per_mac": round(best["memory_model_cycles"] / total_macs, 3),
                                   "with_controller_us": stab["fixed"]["ram"]["one_iteration"]["with_controller_us"],
                                   "zero_wait_cycles_per_mac": round(best["cycles"] / total_macs, 3)},
        "float": {"instructions_per_mac_phi": lib["float"]["instructions_per_mac_phi"],
                  "kernel_instructions_per_mac": lib["float"]["kernel_instructions_per_mac"],
                  "bound_instructions_per_mac": {"single": FLOAT_SINGLE_INSTR_PER_MAC,
                                                 "pair": FLOAT_PAIR_INSTR_PER_MAC},
                  "bound_cycles": round(fbound), "bound_us_with_controller": round((fbound + ctrl) * us, 1),
                  "prediction_cycles_per_mac_zero_wait":
                      round(lib["float"]["prediction"][f"{n}_neighbors"]["cycles"] / total_macs, 3)},
    }


def measure_emlearn(cfg: Config, work: Path) -> dict | None:
    try:
        import emlearn
        from sklearn.neural_network import MLPRegressor
    except ImportError:
        return None
    import warnings

    rng = np.random.default_rng(0)
    headers = {}
    for name, dims in (("eml_phi", cfg.phi_dims()), ("eml_rho", cfg.rho_dims())):
        m = MLPRegressor(hidden_layer_sizes=tuple(dims[1:-1]), max_iter=2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m.fit(rng.normal(size=(64, dims[0])), rng.normal(size=(64, dims[-1])) if dims[-1] > 1
                  else rng.normal(size=64))
        with contextlib.chdir(work):  # emlearn compiles helpers in ./tmp
            emlearn.convert(m).save(file=str(work / f"{name}.h"), name=name)
        headers[name] = dims
    f = flags()
    elf = work / "emlearn.elf"
    eml_inc = Path(emlearn.__file__).parent
    subprocess.run([target.ARM_CC, *f["NS2_ARM_FLAGS"], "-std=c99", *f["NS2_OPT_FLAGS"], "-ffp-contract=off",
                    f"-I{work}", f"-I{eml_inc}", "-ffunction-sections", "-fdata-sections",
                    "-DNS2_SEMIHOSTING", "--specs=rdimon.specs", "-nostartfiles", f"-T{REPO / 'firmware/target/stm32f405.ld'}",
                    "-Wl,--gc-sections", str(REPO / "benchmarks/emlearn_main.c"),
                    str(REPO / "firmware/target/startup_cm4.c"), "-lm", "-o", str(elf)],
                   check=True, capture_output=True)
    cm = cm4_count.Cm4(elf)
    res = {}
    for name, dims in headers.items():
        cm.reset_scratch()
        x = cm.write(np.float32(rng.normal(size=dims[0])).tobytes())
        y = cm.write(bytes(4 * dims[-1]))
        _, _, run = cm.call(f"{name}_regress", x, dims[0], y, dims[-1])
        res[name[4:]] = {"instructions": run.instructions, "cycles": run.cycles,
                         "instructions_per_mac": round(run.instructions / macs(dims), 3)}
    res["emlearn_version"] = emlearn.__version__ if hasattr(emlearn, "__version__") else "?"
    return res


def default_export(work: Path, cfg: Config | None = None) -> Path:
    """A briefly trained model of ``cfg`` (default: the configured, paper-sized one) exported into work."""
    cfg = cfg or Config.load()
    ds = downwash_dataset(cfg, 500, seed=0)
    model, rep = train(cfg, ds, epochs=1, seed=0)
    ck = work / "model.pt"
    save_checkpoint(ck, model, cfg, {"seed": 0, "data_hash": ds.content_hash(), "report": rep})
    export(ck, work / "gen")
    return work / "gen"


def measure_onboard_variant(work: Path) -> dict:
    """The one-tick on-board variant of the network (ONBOARD_WIDTHS: narrower
    intermediate layers, H and L as in the paper): the whole
    prediction with 15 neighbours and a controller step in one 2 ms tick."""
    cfg = Config.load().with_overrides(**ONBOARD_WIDTHS)
    (work / "onboard").mkdir()
    gen = default_export(work / "onboard", cfg)
    ctrl = measure_controller(gen, cfg)
    return {"phi": cfg.phi_dims(), "rho": cfg.rho_dims(), "macs": {"phi": macs(cfg.phi_dims()),
                                                                    "rho": macs(cfg.rho_dims())},
            **budget.one_tick(gen, cfg), "stabilizer_1kHz": measure_stabilizer(gen, cfg, ctrl, sliced=False),
            "memory": firmware_report.report(gen)["ns2_predict_q15"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gen", default=None, help="export folder (default: a freshly trained default model)")
    args = ap.parse_args()
    if not target.have_toolchain():
        sys.exit("arm-none-eabi-gcc missing: run scripts/install-deps.sh")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        gen = Path(args.gen) if args.gen else default_export(work)
        cfg = load_checkpoint(work / "model.pt").cfg if not args.gen else export_config(gen)
        elf = target.build_image(gen)
        lib = measure_library(elf, cfg)
        ctrl = measure_controller(gen, cfg)
        adapt = measure_adaptation(gen, cfg)
        stab = measure_stabilizer(gen, cfg, ctrl)
        eml = measure_emlearn(cfg, work)
        mem = firmware_report.report(gen)
        onboard = measure_onboard_variant(work)
    result = {"cost_model": "ns2host/cm4_count.py: Cortex-M4 TRM cycle counts at zero wait states (cycles, "
                            "us_at_168MHz) and on the modelled memory system (memory_model_*): "
                            + cm4_count.STM32F405_168MHZ.name + "; docs/target.md",
              "network": {"phi": cfg.phi_dims(), "rho": cfg.rho_dims(), "history_ms": cfg.history_ms,
                          "input_dim": cfg.input_dim},
              "macs": {"phi": macs(cfg.phi_dims()), "rho": macs(cfg.rho_dims())}, **lib,
              "adaptation_per_position_tick": adapt}
    if eml:
        result["emlearn"] = eml
        result["emlearn_vs_ns2"] = {
            "phi_instructions_ratio_float": round(eml["phi"]["instructions"] / lib["float"]["per_phi"]["instructions"], 2),
            "phi_instructions_ratio_fixed": round(eml["phi"]["instructions"] / lib["fixed"]["per_phi"]["instructions"], 2),
            "phi_cycles_ratio_float": round(eml["phi"]["cycles"] / lib["float"]["per_phi"]["cycles"], 2),
            "phi_cycles_ratio_fixed": round(eml["phi"]["cycles"] / lib["fixed"]["per_phi"]["cycles"], 2)}
    limit = budget.BUDGET_US
    step = ctrl["position_step"]["us_at_168MHz"] + ctrl["attitude_step"]["us_at_168MHz"]
    result["controller"] = ctrl
    fixed = lib["fixed"]
    free = (limit - step) * cm4_count.CLOCK_HZ / 1e6 - fixed["prediction"]["0_neighbors"]["cycles"]
    per_phi = fixed["per_phi"]["cycles"]
    result["budget_2ms_tick"] = {
        "budget_us": limit,
        "controller_step_us": round(step, 2),
        **{f"{k}_prediction_15_neighbors_plus_controller_us":
           round(lib[k]["prediction"]["15_neighbors"]["us_at_168MHz"] + step, 1) for k in ("float", "fixed")},
        **{f"{k}_meets_budget": lib[k]["prediction"]["15_neighbors"]["us_at_168MHz"] + step <= limit
           for k in ("float", "fixed")},
        "fixed_max_neighbors_in_one_tick": int(free // per_phi),
        # the prediction sliced over the five ticks of one 100 Hz position period
        **{f"{k}_sliced_worst_tick_plus_controller_us":
           round(lib[k]["sliced_15_neighbors"]["worst_tick_us_at_168MHz"] + step, 1) for k in ("float", "fixed")},
        **{f"{k}_sliced_meets_budget":
           lib[k]["sliced_15_neighbors"]["worst_tick_us_at_168MHz"] + step <= limit
           and lib[k]["sliced_15_neighbors"]["fits_in_position_period"] for k in ("float", "fixed")},
    }
    result["stabilizer_1kHz"] = stab
    result["moonshot_one_tick"] = moonshot(cfg, stab, lib)
    result["onboard_variant_one_tick"] = onboard
    result["memory"] = {k: mem[k] for k in firmware_report.ENTRY_POINTS}
    print(json.dumps(stamp(result), indent=2))


if __name__ == "__main__":
    main()
