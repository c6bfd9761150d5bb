"""Instruction counting on the emulated Cortex-M4 (unicorn) and the cross-build
memory report: the harness computes what the host computes, and the generated
kernels stay within their instruction budgets (deterministic counts); a network
with wake memory (24 inputs per neighbour) is counted through the same helpers."""
import numpy as np
import pytest

from ns2codegen.queries import random_queries
from conftest import ARM, needs
from ns2host import budget, cm4_count, firmware_report, target
from ns2host.target import nbr_dtype

pytestmark = needs(ARM)


@pytest.fixture(scope="module")
def cm(exported):
    return cm4_count.Cm4(target.build_image(exported.gen_dir))


def _call(cm, fn, q, i):
    """fn on query i; with wake memory (q.lags > 0) fn_hist with the query's own past."""
    cm.reset_scratch()
    p = cm.write(q.p[i].tobytes())
    v = cm.write(q.v[i].tobytes())
    info = cm.write(bytes(16))
    nb = np.zeros(max(int(q.n[i]), 1), nbr_dtype(q.nbr_rel.shape[-1]))
    nb["type"][:q.n[i]] = q.nbr_type[i, :q.n[i]]
    nb["rel"][:q.n[i]] = q.nbr_rel[i, :q.n[i]]
    if q.lags:
        past = cm.write(np.ascontiguousarray(q.past[i], "<f4").tobytes())
        return cm.call(f"{fn}_hist", int(q.robot_type[i]), p, v, past, cm.write(nb.tobytes()), int(q.n[i]), info)
    return cm.call(fn, int(q.robot_type[i]), p, v, cm.write(nb.tobytes()), int(q.n[i]), info)


def _match_host(ex, cm, count):
    """count random queries of the export ``ex`` on the emulator: the host's bits."""
    c = ex.cmodel()
    q = random_queries(ex.cfg, count, seed=4, max_given=6)
    f_host, _ = c.predict(q, False)
    q_host, _ = c.predict(q, True)
    for i in range(len(q)):
        _, s0, run_f = _call(cm, "ns2_predict_f32", q, i)
        r0, _, run_q = _call(cm, "ns2_predict_q15", q, i)
        assert np.float32(s0).view(np.uint32) == f_host[i:i + 1].view(np.uint32)[0]
        assert np.int16(np.uint16(r0 & 0xFFFF).view(np.int16)) == q_host[i]
        assert run_f.instructions > 1000 and run_f.cycles >= run_f.instructions
    return q


def test_emulated_calls_match_the_host(exported, cm):
    _match_host(exported, cm, 12)


def test_tables_in_ram_same_results_fewer_stalls(exported, cm):
    """The image with the fixed-point tables in SRAM computes the same bits in the
    emulator; its flash data stalls nearly vanish (the rho tables of other robot
    types, the layer descriptors and literal pools stay in flash)."""
    ram = cm4_count.Cm4(target.build_image(exported.gen_dir,
                                           defines=target.ram_placement(exported.cfg.robot_types[0])))
    q = random_queries(exported.cfg, 6, seed=7, max_given=16)
    q.robot_type[:] = 0
    for i in range(len(q)):
        r_flash, _, in_flash = _call(cm, "ns2_predict_q15", q, i)
        r_ram, _, in_ram = _call(ram, "ns2_predict_q15", q, i)
        assert r_ram & 0xFFFF == r_flash & 0xFFFF
        assert abs(in_ram.cycles - in_flash.cycles) <= 8  # the same code, other table addresses
        if q.n[i] >= 2:
            assert in_ram.stalls.data_misses < 0.1 * in_flash.stalls.data_misses
            assert in_ram.memory_cycles < in_flash.memory_cycles


def test_instruction_budgets_per_multiply_accumulate(exported, cm):
    cfg = exported.cfg
    phi = sum(a * b for a, b in zip(cfg.phi_dims()[:-1], cfg.phi_dims()[1:]))
    q = random_queries(cfg, 1, seed=5, max_given=16, inside=1.0, edge=0.0)
    q.n[:] = 16
    q.p[:] = np.float32([0.0, 0.0, 0.8])
    q.nbr_rel[0, :, :3] = np.float32([0.0, 0.0, 0.3])
    per_phi = {}
    for fn in ("ns2_predict_f32", "ns2_predict_q15"):
        q.n[:] = 1
        _, _, one = _call(cm, fn, q, 0)
        q.n[:] = 16
        _, _, sixteen = _call(cm, fn, q, 0)
        per_phi[fn] = (sixteen.instructions - one.instructions) / 15 / phi
        kernels = sum(n for f, n in sixteen.by_function.items() if f.startswith("dense"))
        if fn.endswith("q15"):
            assert sixteen.mix["smlad"] > 0
            assert kernels / (17 * phi) < 1.0  # dense kernels: < 1 instruction per MAC
    assert per_phi["ns2_predict_f32"] < 3.0, per_phi  # whole phi evaluation, float
    assert per_phi["ns2_predict_q15"] <= 1.0, per_phi  # neighbours two at a time through phi


def test_one_tick_budget(exported, onboard):
    """A whole fixed-point prediction with 15 neighbours + the environment and a
    controller step within 20 % of a 2 ms tick: met by the on-board variant (the
    paper-sized network is sliced over five ticks by the app, see bench_target)."""
    small = budget.one_tick(onboard.gen_dir, onboard.cfg)
    assert small["fixed"]["meets_budget"] and small["fixed"]["total_us"] <= budget.BUDGET_US
    assert small["controller_step_us"] > 5.0
    # on the modelled memory system (flash wait states, ART) it needs its hot tables in SRAM,
    # within the RAM the stock firmware leaves
    ram, flash = small["fixed"]["memory_model"]["ram"], small["fixed"]["memory_model"]["flash"]
    assert ram["meets_budget"] and ram["fits_ram_budget"] and ram["tables_in_ram_bytes"] > 0
    assert flash["total_us"] > ram["total_us"] >= small["fixed"]["total_us"]
    paper = budget.one_tick(exported.gen_dir, exported.cfg)
    assert paper["fixed"]["prediction_us"] > 1.5 * small["fixed"]["prediction_us"]  # 3550 vs 1536 MACs per phi


@pytest.fixture(scope="module")
def cm_hist(history):
    return cm4_count.Cm4(target.build_image(history.gen_dir))


def test_history_emulated_calls_match_the_host(history, cm_hist):
    """The network with wake memory (24 inputs per neighbour, the robot's own past)
    through ns2_predict_*_hist on the emulated Cortex-M4: the host's bits."""
    q = _match_host(history, cm_hist, 4)
    assert q.lags == 3 and q.nbr_rel.shape[-1] == 24


def test_history_budget_path(exported, history, cm, cm_hist):
    """budget's helpers take the input width from the export: the wake-memory network's
    phi evaluation costs more than the present-state one's (18 more inputs to clamp,
    quantize and multiply) and stays within the instruction budgets per multiply-
    accumulate (its dense kernels under 1, fixed point; its input handling costs about
    0.14 per MAC more), the sliced job (ns2_job_begin_hist) gives the one-shot bits, and
    the one-tick budget counts 24 inputs per neighbour (3 neighbours here: the counts
    of bench_target's 15 take long on the emulator)."""
    per_phi, kernels, three = {}, {}, {}
    for name, ex, image in (("now", exported, cm), ("hist", history, cm_hist)):
        nb, past = budget.neighbors(ex.cfg, 3, np.random.default_rng(0)), budget.own_past(ex.cfg)
        assert nb["rel"].shape[-1] == ex.cfg.input_dim and (past is None) == (name == "now")
        for fn in ("ns2_predict_f32", "ns2_predict_q15"):
            one, _ = budget.prediction_run(image, fn, nb, 1, past)
            three[name, fn], args = budget.prediction_run(image, fn, nb, 3, past)
            per_phi[name, fn] = (three[name, fn].instructions - one.instructions) / 2   # one pair of phi
            kernels[name, fn] = sum(n for f, n in three[name, fn].by_function.items() if f.startswith("dense"))
        with pytest.raises(ValueError, match="own past"):
            budget.prediction_run(image, "ns2_predict_q15", nb, 1, None if name == "hist" else np.zeros((1, 6)))
    dims, rho_dims = history.cfg.phi_dims(), history.cfg.rho_dims()
    assert dims[0] == 24 and exported.cfg.phi_dims()[0] == 6
    phi = sum(a * b for a, b in zip(dims[:-1], dims[1:]))
    rho = sum(a * b for a, b in zip(rho_dims[:-1], rho_dims[1:]))
    for fn, bound in (("ns2_predict_f32", 3.0), ("ns2_predict_q15", 1.25)):
        assert per_phi["now", fn] < per_phi["hist", fn] < bound * phi, (fn, per_phi)
        assert kernels["now", fn] < kernels["hist", fn]
    assert kernels["hist", "ns2_predict_q15"] / (4 * phi + rho) < 1.0
    # the sliced job of the wake-memory network (args: its last q15 call): the one-shot bits
    r0 = cm_hist.call("ns2_predict_q15_hist", 0, args["p"], args["v"], args["past"], args["nbrs"], 3, args["info"])[0]
    job, begin = budget.job_begin(cm_hist, args, 3)
    assert begin.instructions > 100
    while cm_hist.call("ns2_job_step_q15", job, 1)[0] > 0:
        pass
    r_job = cm_hist.call("ns2_job_finish_q15", job, args["info"])[0]
    assert r_job & 0xFFFF == r0 & 0xFFFF and int.from_bytes(cm_hist.read(args["info"], 4), "little") == 0  # NS2_OK
    tick = budget.one_tick(history.gen_dir, history.cfg, n=3)
    assert tick["input_dim"] == 24 and tick["history_ms"] == [50, 100, 200]
    assert tick["fixed"]["prediction_us"] == round(three["hist", "ns2_predict_q15"].microseconds, 1)
    assert tick["fixed"]["prediction_us"] > round(three["now", "ns2_predict_q15"].microseconds, 1)
    ram, flash = tick["fixed"]["memory_model"]["ram"], tick["fixed"]["memory_model"]["flash"]
    assert flash["total_us"] > ram["total_us"] >= tick["fixed"]["total_us"] and ram["tables_in_ram_bytes"] > 0


def test_memory_report(exported):
    rep = firmware_report.report(exported.gen_dir)
    for entry in ("ns2_predict_f32", "ns2_predict_q15"):
        r = rep[entry]
        assert r["without_stack_data"] == []
        assert 200 < r["worst_case_stack_bytes"] < 2048
        assert r["static_ram_bytes"] == 0 and r["flash_bytes"] > 20_000
    # int16 tables take about half the flash of the float ones
    assert rep["ns2_predict_q15"]["flash_bytes"] < 0.7 * rep["ns2_predict_f32"]["flash_bytes"]


APP_TASK_STACK_BYTES = 1400  # firmware/app/src/ns2_app.c's task (docs/app.md)


def test_memory_report_of_the_apps_step(exported):
    """The app's per-millisecond step within its task's stack, with the default app's
    fixed-point path alone (NS2_PILOT_F32=0) less than with both paths; its chain and the
    simulator's ns2_pilot_tick end in library functions (libm's leaves have no stack data)."""
    both = firmware_report.report(exported.gen_dir, "-Os")
    fixed = firmware_report.report(exported.gen_dir, "-Os", ("NS2_PILOT_F32=0",))
    for rep in (both, fixed):
        for entry in ("ns2_pilot_step", "ns2_pilot_tick"):
            r = rep[entry]
            assert r["deepest_chain"][0] == entry and len(r["deepest_chain"]) > 2
            assert all(not u.startswith("ns2_") for u in r["without_stack_data"]), r["without_stack_data"]
            assert 300 < r["worst_case_stack_bytes"] < APP_TASK_STACK_BYTES
    assert fixed["ns2_pilot_step"]["worst_case_stack_bytes"] < both["ns2_pilot_step"]["worst_case_stack_bytes"]


# --- the memory system (flash wait states, ART caches, prefetch): hand-computed stalls

F = cm4_count.FLASH  # flash code/data; one 128-bit line = 16 bytes
S = cm4_count.RAM    # SRAM: zero wait states
ART = cm4_count.STM32F405_168MHZ  # 5 wait states: a flash line read takes 6 cycles


def _seq(base, n, cycles=1, size=4):
    """n straight-line instructions of `size` bytes and `cycles` cycles, no data reads."""
    return [(base + size * i, size, cycles, ()) for i in range(n)]


def test_memory_model_zero_wait_and_sram_add_nothing():
    ev = _seq(F, 40) + [(F + 160, 4, 2, ((F + 0x1000, 4),)), (S, 4, 2, ((S + 64, 4),))]
    assert cm4_count.memory_stalls(ev, cm4_count.ZERO_WAIT).total == 0
    ram = [(S + 4 * i, 4, 2, ((S + 0x400 + 16 * i, 4),)) for i in range(50)]  # code and data in SRAM
    assert cm4_count.memory_stalls(ram, ART).total == 0


def test_memory_model_sequential_code_with_and_without_prefetch():
    # 8 single-cycle 32-bit instructions = 2 lines.  Line 0: miss at t=0, read 0..6, the
    # instruction issues at t=5 (stall 5).  Prefetch of line 1 starts when the interface is
    # free (t=6), done at 12; line 0 executes t=5..9; line 1 wanted at t=9, ready for
    # issue at 11: stall 2.
    st = cm4_count.memory_stalls(_seq(F, 8), ART)
    assert (st.fetch, st.fetch_misses, st.prefetches, st.data) == (7, 1, 2, 0)
    # without prefetch: two misses of 5
    st = cm4_count.memory_stalls(_seq(F, 8), cm4_count.MemorySystem("np", prefetch=False))
    assert (st.fetch, st.fetch_misses) == (10, 2)
    # 16-bit instructions: 8 per line, 8 cycles per line >= 6: prefetch hides line 1 fully
    st = cm4_count.memory_stalls(_seq(F, 16, size=2), ART)
    assert st.fetch == 5


def test_memory_model_instruction_cache_keeps_missed_lines_only():
    # A loop of 2 lines run 3 times; each instruction 3 cycles (12 per line > 6).
    body = _seq(F, 8, cycles=3)
    st = cm4_count.memory_stalls(body * 3, cm4_count.MemorySystem("np", prefetch=False))
    assert (st.fetch, st.fetch_misses) == (10, 2)  # both lines missed once, then cached
    # with prefetch: line 0 misses (5), line 1 is prefetched in time (12 cycles of line 0)
    # and cached when used; the prefetch of line 2 is issued from line 1 on every pass,
    # that of line 1 only on the first: 4 prefetches, no further stall
    st = cm4_count.memory_stalls(body * 3, ART)
    assert (st.fetch, st.fetch_misses, st.prefetches) == (5, 1, 4)
    # RM0090 taken literally (only missed lines are cached): line 1 is prefetched
    # again on every pass (in time: still no stall), 6 prefetches
    st = cm4_count.memory_stalls(body * 3, cm4_count.STM32F405_PREFETCH_UNCACHED)
    assert (st.fetch, st.fetch_misses, st.prefetches) == (5, 1, 6)
    # ... which costs where lines execute in fewer than 6 cycles: 4 single-cycle
    # instructions per line, a 2-line loop run 3 times
    fast = _seq(F, 8)
    assert cm4_count.memory_stalls(fast * 3, ART).fetch == 7
    assert cm4_count.memory_stalls(fast * 3, cm4_count.STM32F405_PREFETCH_UNCACHED).fetch > 7
    # more lines than the cache holds (LRU): 65 lines in a loop miss every time
    big = _seq(F, 4 * 65, cycles=3)
    st = cm4_count.memory_stalls(big * 2, cm4_count.MemorySystem("np", prefetch=False))
    assert st.fetch_misses == 130 and st.fetch == 650


def test_memory_model_data_cache_eight_lines():
    code = S  # code in SRAM: only the data side counts
    def loads(lines, passes):
        return [(code, 4, 2, ((F + 0x1000 + 16 * k, 4),)) for _ in range(passes) for k in range(lines)]
    st = cm4_count.memory_stalls(loads(8, 2), ART)
    assert (st.data_misses, st.data) == (8, 40)  # 8 lines fit the data cache
    st = cm4_count.memory_stalls(loads(9, 2), ART)
    assert (st.data_misses, st.data) == (18, 90)  # 9 do not (LRU): every load misses
    # an LDM of 4 words across a line boundary reads two lines, one after the other:
    # 0..6 (stall 5, t=5), then 6..12 (stall 12 - 1 - 5 = 6)
    st = cm4_count.memory_stalls([(code, 4, 5, ((F + 8, 4), (F + 12, 4), (F + 16, 4), (F + 20, 4)))], ART)
    assert (st.data_misses, st.data) == (2, 11)


def test_memory_model_contention_between_prefetch_and_data():
    # line 0 (code) misses: read 0..6, stall 5, issue at t=5; the prefetch of line 1 is
    # queued behind it (would start at 6).  A load in that first instruction asks at t=5:
    # the D-code bus goes first (RM0090 3.5.2): its read runs 6..12, stall 12 - 1 - 5 = 6,
    # and the prefetch moves to 12..18
    ev = [(F, 4, 2, ((F + 0x1000, 4),))] + _seq(F + 4, 3, cycles=3)
    st = cm4_count.memory_stalls(ev, ART)
    assert (st.fetch, st.data) == (5, 6)
    # a load one instruction later (t=6) finds the prefetch started (6..12): it waits
    # for it and reads 12..18, stall 18 - 1 - 6 = 11
    ev = [(F, 2, 1, ())] + [(F + 2, 4, 2, ((F + 0x1000, 4),))] + _seq(F + 6, 2, cycles=3)
    st = cm4_count.memory_stalls(ev, ART)
    assert (st.fetch, st.data) == (5, 11)
    # without contention each load waits only for its own read: 5
    assert cm4_count.memory_stalls(ev, cm4_count.STM32F405_NO_CONTENTION).data == 5


_SUM_S = """
    .syntax unified
    .thumb
    .text
    .global ns2_reset_handler
    .type ns2_reset_handler, %function
ns2_reset_handler:
    b ns2_reset_handler
    .size ns2_reset_handler, .-ns2_reset_handler
    .balign 16
    .global sum_words
    .type sum_words, %function
sum_words:                  @ r0 = table, r1 = words: 16 bytes of code, one flash line
    movs r2, #0
1:  ldr.w r3, [r0], #4
    add r2, r3
    subs r1, #1
    bne 1b
    mov r0, r2
    bx lr
    .size sum_words, .-sum_words
    .section .rodata
    .balign 16
    .global table
    .type table, %object
table:
    .rept 64
    .word 3
    .endr
    .size table, .-table
"""


@pytest.fixture(scope="module")
def sum_elf(tmp_path_factory):
    d = tmp_path_factory.mktemp("sum")
    (d / "sum.S").write_text(_SUM_S)
    elf = d / "sum.elf"
    import subprocess

    subprocess.run([target.ARM_CC, "-mcpu=cortex-m4", "-mthumb", "-nostdlib", "-nostartfiles",
                    f"-T{target.TARGET_DIR / 'stm32f405.ld'}", str(d / "sum.S"), "-o", str(elf)], check=True)
    return elf


def test_memory_model_on_an_emulated_loop(sum_elf):
    """A word-summing loop (one 16-byte line of code) over a flash table: without
    prefetch every flash line read is a 5-cycle stall: one for the code line, one per
    16-byte table line (64 words = 16 lines, more than the 8-line data cache); the
    same words copied to SRAM leave the code line's miss only."""
    no_pf = cm4_count.MemorySystem("no prefetch", prefetch=False)
    cm = cm4_count.Cm4(sum_elf, memory=no_pf)
    table = cm.addr("table")
    assert cm4_count.FLASH <= table < cm4_count.FLASH + cm4_count.FLASH_SIZE and table % 16 == 0
    r0, _, run = cm.call("sum_words", table, 64)
    assert r0 == 3 * 64
    # zero-wait count (TRM): movs 1, 64 x (ldr 2 + add 1 + subs 1), bne 63 x 3 + 1, mov 1, bx 3
    assert run.cycles == 1 + 64 * 4 + 63 * 3 + 1 + 1 + 3
    assert (run.stalls.fetch_misses, run.stalls.data_misses) == (1, 16)
    assert run.stalls.total == 5 * 17 and run.memory_cycles == run.cycles + 85
    _, _, run = cm.call("sum_words", table, 32)  # 8 lines (each call starts with cold caches)
    assert run.stalls.data_misses == 8
    in_ram = cm.write(cm.read(table, 256))
    r0, _, run = cm.call("sum_words", in_ram, 64)
    assert r0 == 3 * 64 and run.stalls.total == 5 and run.stalls.data_misses == 0
    cm.memory = cm4_count.ZERO_WAIT
    assert cm.call("sum_words", table, 64)[2].memory_cycles == run.cycles
