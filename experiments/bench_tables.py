"""The tables made of the Cortex-M4 benchmarks' JSON (benchmarks/bench_target.py,
benchmarks/bench_stabilizer.py, benchmarks/bench_plan.py), the firmware's size reports
(``python -m ns2host.cfapp``) and the ground truth's calibration
(``python -m ns2host.sim.calibration --json``), as committed under docs/results/runs/:
docs/benchmarks.md's and docs/memory.md's cycle tables, docs/app.md's flash and RAM,
docs/planning.md's SCP benchmark, docs/ground-truth.md's calibration tables and README's
"what make bench measures" (experiments/tables.py's DOC_TABLES).  Every number is read
from the files; nothing here measures."""
from __future__ import annotations

import re

NEIGHBORS = "15_neighbors"        # bench_target's prediction of robot type 0 with 15 neighbours + environment
PLACES = ("zero_wait", "flash", "ram")    # zero wait states; the memory model with the tables in flash / in SRAM


def _us(x: float, digits: int = 0) -> str:
    return f"{x:.{digits}f}"


def _kb(n_bytes: float) -> str:
    return f"{n_bytes / 1000:.1f} KB"


def _within(us: float, budget: float) -> str:
    return "within budget" if us <= budget else "over budget"


def _verdict(values, budget: float, places=("zero wait", "flash", "SRAM")) -> str:
    """"within budget" / "over budget" when every value agrees, else where it is within."""
    ok = [p for v, p in zip(values, places) if v <= budget]
    if len(ok) in (0, len(places)):
        return _within(max(values), budget)
    return "within budget at " + " and ".join(ok) + " only"


def _one_tick(t: dict, kind: str, place: str) -> dict:
    """bench_target's one-iteration prediction (15 neighbours + environment) of ``kind``
    (fixed / float) with its tables in ``place`` (flash / ram)."""
    return t["stabilizer_1kHz"][kind][place]["one_iteration"]


def _sliced(t: dict, kind: str, place: str, rate: str) -> dict:
    key = {"1kHz": "sliced_1kHz_2_phi_per_iteration", "500Hz": "sliced_500Hz_4_phi_per_tick"}[rate]
    return t["stabilizer_1kHz"][kind][place][key]


def _each(f, t: dict, kind: str, *args) -> list:
    """``f(t, kind, place, *args)`` at zero wait, on the memory model with flash tables, with SRAM tables."""
    return [f(t, kind, w, *args) for w in PLACES]


def _cycles_per_mac_cells(t: dict, kind: str, sep: str) -> str:
    return sep.join(f"{c:.3f}" for c in _each(_cycles_per_mac, t, kind))


def _tick_us(t: dict, kind: str, which: str) -> float:
    o = _one_tick(t, kind, "flash" if which != "ram" else "ram")
    return o["with_controller_us_zero_wait"] if which == "zero_wait" else o["with_controller_us"]


def _sliced_us(t: dict, kind: str, which: str, rate: str) -> float:
    s = _sliced(t, kind, "flash" if which != "ram" else "ram", rate)
    return (s["worst_iteration_with_controller_us_zero_wait"] if which == "zero_wait"
            else s["worst_iteration_with_controller_us"])


def _prediction_us(t: dict, kind: str, which: str) -> float:
    p = t[kind]["prediction"][NEIGHBORS]
    if which == "zero_wait":
        return p["us_at_168MHz"]
    if which == "flash":
        return p["memory_model_us"]
    return _one_tick(t, kind, "ram")["prediction"]["memory_model_us"]


def _cycles_per_mac(t: dict, kind: str, which: str) -> float:
    p = t[kind]["prediction"][NEIGHBORS]
    cycles = {"zero_wait": p["cycles"], "flash": p["memory_model_cycles"],
              "ram": _one_tick(t, kind, "ram")["prediction"]["memory_model_cycles"]}[which]
    return cycles / t["moonshot_one_tick"]["macs_per_prediction"]


def _layers(net: dict) -> str:
    return "-".join(map(str, net["phi"])) + " / " + "-".join(map(str, net["rho"]))


def _onboard_us(t: dict, kind: str, which: str) -> float:
    o = t["onboard_variant_one_tick"][kind]
    return o["total_us"] if which == "zero_wait" else o["memory_model"][which]["total_us"]


def benchmarks_host_table(core: dict, sim: dict, plan: dict) -> str:
    """bench_core.py, bench_sim.py and bench_plan.py's rows of docs/benchmarks.md: training,
    the host C, data generation and C-in-the-loop speed, the SCP programs side by side."""
    tr, c = core["training"], core["host_c_inference"]
    dg, rtf = sim["data_generation"], sim["c_in_the_loop_real_time_factor"]
    sp = plan["planning"]["scp_programs"]
    reb, par = sp["rebuilt"], sp["parametrized"]

    def per_call(kind: str) -> str:
        return " / ".join(f"{c[f'{kind}_{n}_neighbors_us']:.1f}" for n in (1, 4, 16))

    return "\n".join([
        f"| what (host, {core['machine']['cpu_count']} cores) | result |", "|---|---|",
        f"| training, {tr['samples'] / 1e6:.1f} M generated samples ({tr['train_samples']:,} train), {tr['epochs']} "
        f"epochs, batch {tr['batch_size']}, {tr['torch_threads']} torch threads | {tr['train_time_s']:.0f} s, "
        f"{tr['samples_per_second']:,} samples/s, validation MSE {tr['validation_mse_g2']:.3f} g^2 (label variance "
        f"{tr['label_variance_g2']:.0f} g^2) |",
        f"| host C inference per call, 1 / 4 / 16 neighbours (portable C on x86) | fixed {per_call('fixed')} us; "
        f"float {per_call('float')} us |",
        f"| simulated data generation ({dg['teams']} teams, {dg['flight_seconds_per_team']:g} s of flight each, labels "
        f"from the drones' logs) | {dg['samples_per_second']:,} samples/s: about "
        f"{dg['paper_size_1.4M_estimate_s'] / 60:.0f} min for the paper's 1.4 M samples |",
        f"| planning, SSL and SLL in 2-D and 3-D, NN and BL, {len(plan['planning']['seeds'])} trials each "
        f"(`scp_programs`) | Stage 2 per trial: rebuilt program {reb['stage2_s_per_trial']:.2f} s, parametrized "
        f"{par['stage2_s_per_trial']:.2f} s, **{sp['stage2_speedup']:.1f}x**; Stage 1 + 2 per trial "
        f"{reb['stage1_plus_2_s_per_trial']:.2f} -> {par['stage1_plus_2_s_per_trial']:.2f} s, "
        f"**{sp['stage1_plus_2_speedup']:.1f}x**; the two programs' plans within {sp['plans_max_dp_m']:.1e} m |",
        f"| C-in-the-loop real-time factor (1 kHz: IMU, the firmware's EKF, `ns2_pilot` with the fixed-point NN; "
        f"100 Hz mocap; flow-based truth) | {rtf['1_robots']:.1f} (1 robot), {rtf['16_robots']:.1f} (16 robots): a "
        f"60 s 16-robot flight in {sim['c_in_the_loop_60s_16_robots_wall_s_estimate']:.0f} s |"])


# ------------------------------------------------------------------ docs/memory.md
def memory_table(t: dict) -> str:
    """Each case at zero wait, on the memory model with the tables in flash and with the
    hot tables in SRAM (bench_target.py of the paper-sized network)."""
    def row(label: str, f, kind: str, *args, ram_note: str = "") -> str:
        zero, flash, ram = _each(f, t, kind, *args)
        return f"| {label} | {zero:.1f} us | {flash:.1f} us | {ram:.1f} us{ram_note} |"

    def ram_note(kind: str) -> str:
        r = t["stabilizer_1kHz"][kind]["ram"]
        return f" ({_kb(r['tables_in_ram_bytes'])}" + ("" if r["fits_ram_budget"] else ": over the budget") + ")"

    budget = t["budget_2ms_tick"]["budget_us"]
    onb = t["onboard_variant_one_tick"]
    n1k, n500 = (_sliced(t, "fixed", "flash", r)["iterations_with_phi"] for r in ("1kHz", "500Hz"))
    macs = t["moonshot_one_tick"]["macs_per_prediction"]

    def onboard(kind: str) -> str:
        f = _each(_onboard_us, t, kind)
        over = lambda us: f" (over {budget:g})" if us > budget else ""          # noqa: E731
        kb = _kb(onb[kind]["memory_model"]["ram"]["tables_in_ram_bytes"])
        return (f"| on-board variant, {kind}, one iteration + controller | {f[0]:.1f} us{over(f[0])} | "
                f"{f[1]:.1f} us{over(f[1])} | {f[2]:.1f} us ({kb}{'; over ' + f'{budget:g}' if f[2] > budget else ''}) |")

    return "\n".join([
        "| case | zero wait | memory model, tables in flash | memory model, hot tables in SRAM |",
        "|---|---|---|---|",
        row("fixed, whole prediction, 15 neighbours", _prediction_us, "fixed", ram_note=ram_note("fixed")),
        row("fixed, + controller step, one iteration", _tick_us, "fixed"),
        row(f"fixed, sliced, worst 1 ms iteration (2 phi per iteration, {n1k} iterations) + controller",
            _sliced_us, "fixed", "1kHz"),
        row(f"fixed, sliced, worst 500 Hz tick (4 phi per tick, {n500} ticks) + controller", _sliced_us, "fixed", "500Hz"),
        row("float, whole prediction, 15 neighbours", _prediction_us, "float", ram_note=ram_note("float")),
        row("float, sliced, worst 1 ms iteration + controller", _sliced_us, "float", "1kHz"),
        row("float, sliced, worst 500 Hz tick + controller", _sliced_us, "float", "500Hz"),
        onboard("fixed"), onboard("float"),
        f"| cycles per MAC, fixed, whole prediction ({macs:,} MACs) | {_cycles_per_mac_cells(t, 'fixed', ' | ')} |",
        f"| cycles per MAC, float, whole prediction | {_cycles_per_mac_cells(t, 'float', ' | ')} |"])


# ------------------------------------------------------------------ docs/benchmarks.md
def benchmarks_target_table(t: dict) -> str:
    """bench_target.py's rows of docs/benchmarks.md: the Cortex-M4's instructions and
    cycles, the 400 us budget of a 2 ms tick, the on-board variant, memory."""
    fx, fl, m1 = t["fixed"], t["float"], t["moonshot_one_tick"]
    budget = t["budget_2ms_tick"]["budget_us"]
    em, emr = t["emlearn"], t["emlearn_vs_ns2"]
    onb = t["onboard_variant_one_tick"]
    mem = t["memory"]
    one = _each(_tick_us, t, "fixed")
    s500 = _each(_sliced_us, t, "fixed", "500Hz")
    onb_fx = _each(_onboard_us, t, "fixed")
    bound = m1["float"]["bound_instructions_per_mac"]

    def three(values, digits=0) -> str:
        return " / ".join(_us(v, digits) for v in values)

    def sizes(name: str) -> str:
        r = mem[name]
        return f"{_kb(r['flash_bytes'])} / {r['static_ram_bytes']} / {r['worst_case_stack_bytes']:,} B"

    onb_verdict = _verdict(onb_fx, budget)
    return "\n".join([
        "| what (Cortex-M4 at 168 MHz, emulated) | result |", "|---|---|",
        f"| network | paper-sized, {_layers(t['network'])}: {t['macs']['phi']:,} MACs per phi evaluation, "
        f"{t['macs']['rho']:,} per rho |",
        f"| instructions per multiply-accumulate per phi evaluation | float {fl['instructions_per_mac_phi']:.2f} "
        f"(pair kernels alone {fl['kernel_instructions_per_mac']:.2f}; bound {bound['pair']:.4g}-{bound['single']:.4g}), "
        f"fixed {fx['instructions_per_mac_phi']:.3f} (dense kernels alone {fx['kernel_instructions_per_mac']:.2f}) |",
        f"| emlearn {em['emlearn_version']}'s C for the same layer sizes | {em['phi']['instructions_per_mac']:.2f} "
        f"instructions per MAC: {emr['phi_instructions_ratio_float']:.1f}x ours (float), "
        f"{emr['phi_instructions_ratio_fixed']:.1f}x (fixed); cycles {emr['phi_cycles_ratio_float']:.1f}x and "
        f"{emr['phi_cycles_ratio_fixed']:.1f}x |",
        f"| per phi evaluation, zero wait | fixed {fx['per_phi']['us_at_168MHz']:.0f} us, "
        f"float {fl['per_phi']['us_at_168MHz']:.0f} us |",
        "| full prediction with 1 / 4 / 16 neighbours (+ environment), zero wait | fixed "
        + " / ".join(_us(fx["prediction"][f"{n}_neighbors"]["us_at_168MHz"]) for n in (1, 4, 16)) + " us, float "
        + " / ".join(_us(fl["prediction"][f"{n}_neighbors"]["us_at_168MHz"]) for n in (1, 4, 16)) + " us |",
        "| cycles per MAC, whole prediction: zero wait / modelled, tables in flash / hot tables in SRAM | fixed "
        f"{_cycles_per_mac_cells(t, 'fixed', ' / ')}, float {_cycles_per_mac_cells(t, 'float', ' / ')} |",
        f"| controller step (position + attitude), zero wait / memory model | "
        f"{t['budget_2ms_tick']['controller_step_us']:.1f} / {t['stabilizer_1kHz']['controller_step_us_memory_model']:.1f} us |",
        f"| 15 neighbours + environment + controller step vs {budget:g} us (20 % of a 2 ms tick), in one tick: "
        f"zero wait / modelled flash / modelled SRAM tables | fixed {three(one)} us: **{_verdict(one, budget)}** "
        f"(the machine's bound is {m1['bound_us_with_controller']:.0f} us, [memory.md](memory.md)); float prediction "
        f"alone {three(_each(_prediction_us, t, 'float'))} us |",
        f"| the same prediction sliced over the 500 Hz ticks of a 100 Hz period (the app), worst tick + controller "
        f"step: zero wait / flash / SRAM | fixed {three(s500)} us (4 phi per tick): **{_verdict(s500, budget)}** |",
        "| the same against the firmware's 1 ms stabilizer iteration (2 phi per ms), worst iteration + controller "
        "step | fixed " + three(_each(_sliced_us, t, "fixed", "1kHz"))
        + " us, float " + three(_each(_sliced_us, t, "float", "1kHz")) + " us |",
        f"| the on-board variant (`make export-onboard`, {_layers(onb)}), 15 neighbours + environment + controller "
        f"step in one tick: zero wait / flash / SRAM | fixed {three(onb_fx)} us: **{onb_verdict}** "
        f"({_kb(onb['fixed']['memory_model']['ram']['tables_in_ram_bytes'])} in SRAM); float "
        f"{three(_each(_onboard_us, t, 'float'))} us; flash "
        f"{_kb(onb['memory']['flash_bytes'])}, stack {onb['memory']['worst_case_stack_bytes']:,} B |",
        f"| RAM per robot for the sliced prediction (`ns2_job_t`) | {fx['sliced_15_neighbors']['job_ram_bytes']:,} B |",
        f"| flash (code + tables) / static RAM / worst-case stack | float {sizes('ns2_predict_f32')}, fixed "
        f"{sizes('ns2_predict_q15')}, controller {sizes('ns2_ctrl_position')} |"])


def wake_memory_cycles_table(present: dict, memory: dict) -> str:
    """bench_target.py on the present-state network and on the wake-memory one side by side:
    a phi evaluation, the whole prediction, the app's slicing, the 2 ms-tick budget, RAM."""
    nets = (present, memory)

    def cells(f) -> str:
        return " | ".join(f(d) for d in nets)

    def sliced(d: dict) -> str:
        s = d["fixed"]["sliced_15_neighbors"]
        return (f"{s['begin_cycles']:,}; {s['worst_tick_cycles']:,} / {s['memory_model_worst_tick_cycles']:,} cycles "
                f"({s['worst_tick_us_at_168MHz']:.0f} / {s['memory_model_worst_tick_us']:.0f} µs)")

    def whole(d: dict) -> str:
        p = d["fixed"]["prediction"][NEIGHBORS]
        return (f"{p['cycles']:,} / {p['memory_model_cycles']:,} cycles ({p['us_at_168MHz']:.0f} / "
                f"{p['memory_model_us']:.0f} µs)")

    def sram(d: dict) -> str:
        r = d["stabilizer_1kHz"]["fixed"]["ram"]
        return f"{r['tables_in_ram_bytes']:,} B, " + ("fits" if r["fits_ram_budget"] else "does not fit")

    budget = present["budget_2ms_tick"]["budget_us"]
    table_budget = present["stabilizer_1kHz"]["table_ram_budget_bytes"]
    return "\n".join([
        f"| | present state ({present['network']['input_dim']} inputs) | wake memory "
        f"({memory['network']['input_dim']} inputs) |", "|---|---|---|",
        "| one phi evaluation, zero wait | " + cells(lambda d: f"{d['fixed']['per_phi']['cycles']:,} cycles "
                                                            f"({d['fixed']['per_phi']['us_at_168MHz']:.1f} µs)") + " |",
        "| instructions per multiply-accumulate, whole phi | "
        + cells(lambda d: f"{d['fixed']['instructions_per_mac_phi']:.3f}") + " |",
        "| whole prediction, zero wait / memory model, tables in flash | " + cells(whole) + " |",
        "| the app's slicing (4 phi per 500 Hz tick): `ns2_job_begin*`; worst tick, zero wait / memory model | "
        + cells(sliced) + " |",
        f"| 2 ms-tick budget ({budget:g} µs): that worst tick + controller step, zero wait | "
        + cells(lambda d: f"{d['budget_2ms_tick']['fixed_sliced_worst_tick_plus_controller_us']:.0f} µs, "
                          + ("within" if d["budget_2ms_tick"]["fixed_sliced_meets_budget"] else "over")) + " |",
        "| `ns2_job_t` | " + cells(lambda d: f"{d['fixed']['sliced_15_neighbors']['job_ram_bytes']:,} B") + " |",
        f"| hot fixed-point tables in SRAM (`target.ram_placement`), against the {table_budget:,} B table budget | "
        + cells(sram) + " |"])


# ------------------------------------------------------------------ docs/app.md
def _b(n: int, sign: bool = False) -> str:
    return f"{n:+,} B" if sign else f"{n:,} B"


def app_sizes_table(fixed: dict, flt: dict, both: dict) -> str:
    """`make app`'s size report (python -m ns2host.cfapp) of the stock cf2 and of the app with
    each inference path: flash, RAM and CCM, and what the app adds."""
    st = fixed["stock"]
    if flt["stock"] != st or both["stock"] != st:
        raise ValueError("the reports were not made against the same stock firmware")
    lines = ["| build | flash | RAM (bss + data) | CCM |", "|---|---|---|---|",
             f"| stock cf2 | {_b(st['flash'])} | {_b(st['ram'])} ({st['ram_free']:,} free) | "
             f"{_b(st['ccm'])} ({st['ccm_free']:,} free) |"]
    for doc in (fixed, flt, both):
        d = doc["delta"]
        default = " (default)" if doc["infer"] == "fixed" else ""
        lines.append(f"| with the app, `NS2_INFER={doc['infer']}`{default} | {_b(d['flash'], True)} "
                     f"({_kb(d['flash'])}) | {_b(d['ram'], True)} | {_b(d['ccm'], True)} |")
    return "\n".join(lines)


def app_memory_sizes_table(default: dict, memory: dict) -> str:
    """The app's flash and RAM with the present-state network and with the wake-memory one."""
    def row(label: str, doc: dict) -> str:
        return (f"| {label} | {_b(doc['delta']['flash'], True)} | {_b(doc['delta']['ram'], True)} | "
                f"{_b(doc['ram_added']['app_bss'])} | {_b(doc['app']['ram_free'])} |")

    lags = memory["network"]["history_ms"]
    if default["network"]["history_ms"] or not lags:
        raise ValueError("the first report is not of a present-state network or the second not of a wake-memory one")
    df, dr, db = (memory[a][k] - default[a][k] for a, k in (("delta", "flash"), ("delta", "ram"),
                                                          ("ram_added", "app_bss")))
    return "\n".join([
        "| build | flash over stock | RAM over stock | app bss | RAM left free |", "|---|---|---|---|---|",
        row("default network", default),
        row(f"with wake memory ({memory['network']['input_dim']} inputs, {len(lags)} lags)", memory),
        f"| difference | {_b(df, True)} | **{_b(dr, True)}** | {_b(db, True)} | |"])


def app_sram_table(flash: dict, ram: dict) -> str:
    """The default app with every table in flash and with the fixed-point phi tables in SRAM
    (`make app NS2_TABLES=ram`): the firmware's flash and RAM."""
    if (flash["tables"], ram["tables"]) != ("flash", "ram") or flash["stock"] != ram["stock"]:
        raise ValueError("not a flash-tables and a ram-tables report of the same stock firmware")

    def row(label: str, doc: dict) -> str:
        a = doc["app"]
        return f"| {label} | {_b(a['flash'])} | {_b(a['ram'])} ({a['ram_free']:,} free) | {_b(doc['delta']['data'], True)} |"

    return "\n".join(["| cf2 with the app (fixed point) | flash | RAM (bss + data) | data over stock |", "|---|---|---|---|",
                      row("tables in flash (default)", flash), row("phi tables in SRAM (`NS2_TABLES=ram`)", ram)])


# ------------------------------------------------------------------ docs/planning.md
def scp_programs_table(doc: dict) -> str:
    """bench_plan.py's ``scp_programs``: per case and over all trials, Stage 2 and Stage 1 + 2
    seconds per trial with the program rebuilt at every solve and with the parametrized one."""
    plan = doc["planning"]

    def row(label: str, s: dict, bold: bool = False) -> str:
        reb, par = s["rebuilt"], s["parametrized"]
        b = "**" if bold else ""
        return (f"| {label} | {reb['stage2_s_per_trial']:.2f} / {par['stage2_s_per_trial']:.2f} | "
                f"{b}{s['stage2_speedup']:.2f}{b} | {reb['stage1_plus_2_s_per_trial']:.2f} / "
                f"{par['stage1_plus_2_s_per_trial']:.2f} | {b}{s['stage1_plus_2_speedup']:.2f}{b} |")

    lines = ["| case | Stage 2 rebuilt / parametrized | Stage 2 ratio | Stage 1 + 2 rebuilt / parametrized | "
             "Stage 1 + 2 ratio |", "|---|---|---|---|---|"]
    lines += [row(re.sub(r"^(\d)D ", r"\1-D ", case), c["scp_programs"]) for case, c in plan["cases"].items()]
    lines.append(row(f"all {plan['scp_programs']['trials']} trials", plan["scp_programs"], bold=True))
    return "\n".join(lines)


# ------------------------------------------------------------------ docs/ground-truth.md
def calibration_points_table(doc: dict) -> str:
    from ns2host.sim.calibration import markdown

    return markdown(doc["points"]).rstrip("\n")


def calibration_gaps_table(doc: dict) -> str:
    from ns2host.sim.calibration import gap_markdown

    return gap_markdown(doc["gap_table"]).rstrip("\n")


def _source(point: str) -> str:
    """The paper's place a calibration point comes from (its "[...]")."""
    m = re.search(r"\[([^\]]*)\]", point)
    return m.group(1).split(":")[0].split(", ")[0] if m else point


# ------------------------------------------------------------------ README
def readme_measures_table(target: dict, stabilizer: dict, calibration: dict) -> str:
    """README's rows of what the benchmarks and the ground truth's calibration measured."""
    budget = target["budget_2ms_tick"]["budget_us"]
    one = [_tick_us(target, "fixed", w) for w in ("flash", "ram")]
    bound = target["moonshot_one_tick"]["bound_us_with_controller"]
    s500 = _sliced_us(target, "fixed", "flash", "500Hz")
    onb = target["onboard_variant_one_tick"]
    fx = stabilizer["fixed"]
    adds = fx["app_adds_to_worst_tick"]
    cm4 = (f"paper-sized network ({_layers(target['network'])}): fixed point {one[0]:.0f} us for 15 neighbours + "
           f"controller in one tick ({one[1]:.0f} us with its hot tables in SRAM; the machine's bound is {bound:.0f} us: "
           f"{'over' if bound > budget else 'within'} the {budget:g} us budget), {s500:.0f} us in the "
           "worst 500 Hz tick when sliced over the 100 Hz period; on-board variant: "
           f"{onb['fixed']['memory_model']['ram']['total_us']:.0f} us in one tick with its tables in SRAM; the app "
           f"({stabilizer['network']['phi'][0]} inputs per neighbour), its 100 Hz work spread over the milliseconds, "
           f"adds {100 * adds['zero_wait']:.1f} % of 1 ms to the firmware's worst stabilizer iteration with its Kalman "
           f"filter ({100 * adds['memory']:.1f} % on the memory model, "
           f"{100 * fx['stock_worst_tick']['memory']['share_of_1ms']:.0f} % to "
           f"{100 * fx['app_worst_tick']['memory']['share_of_1ms']:.0f} % of the millisecond)")
    pts = calibration["points"]
    ok = sum(bool(p["ok"]) for p in pts)
    fitted = [p for p in pts if p["fitted"]]
    numeric = [p for p in pts if not p["fitted"] and p["paper"] is not None]
    out = [p for p in pts if not p["ok"]]
    truth = (f"flow-based, non-additive wakes: {ok} of the paper's {len(pts)} points within their tolerance; "
             f"fitted: " + ", ".join(f"{p['sim']:.2f} vs {p['paper']:g} ({_source(p['point'])})" for p in fitted)
             + "; predicted: " + ", ".join(f"{p['sim']:.2f} vs {p['paper']:g} ({_source(p['point'])})" for p in numeric))
    if out:
        truth += "; out of tolerance: " + ", ".join(f"{p['sim']:.2f}, criterion {p['tolerance']} ({_source(p['point'])})"
                                                   for p in out)
    return "\n".join([
        "| | result | details |", "|---|---|---|",
        "| on the Cortex-M4 (emulated, with the STM32F405's flash wait states and ART accelerator) | "
        f"{cm4} | [docs/benchmarks.md](docs/benchmarks.md), [docs/memory.md](docs/memory.md), [docs/app.md](docs/app.md) |",
        f"| ground truth of the simulator against the paper's points | {truth} | "
        "[docs/ground-truth.md](docs/ground-truth.md) |"])
