"""Instruction counts of cross-compiled functions on an emulated Cortex-M4.

The ELF built for the STM32F405 is loaded into the unicorn engine (its
Cortex-M4 model, FPU enabled); a function is called with arguments in r0-r3
and on the stack and run until it returns.  Every executed instruction is
counted; capstone classifies them, and a documented Cortex-M4 cost model turns
the mix into estimated cycles at zero wait states; the flash wait states and the
ART accelerator of the STM32F405 are added by a model of the memory system
(below).  Estimates: load/store pipelining is not modelled.

Cortex-M4 cost model (cycles; Cortex-M4 TRM r0p1 table 3-1, FPU TRM table 3-1;
P = 2 for a pipeline refill after a taken branch):
  data processing, MOV, CMP, IT, shifts, MUL, SMLAD/SMUAD/SMLABB, SMULL/SMLAL .. 1
  MLA, MLS ...................................................................... 2
  SDIV, UDIV (upper bound) ..................................................... 12
  LDR*/STR* single ................. 2     LDRD/STRD ...................... 3
  LDM/STM/PUSH/POP of N registers .. 1+N   POP or LDM including PC ........ 1+N+P
  B/BL/BX/CBZ/CBNZ taken ........... 1+P   not taken ...................... 1
  VADD/VSUB/VMUL/VNEG/VABS/VCMP/VMOV/VMRS/VCVT  1
  VMLA/VMLS/VFMA ................... 3     VDIV/VSQRT ..................... 14
  VLDR/VSTR ........................ 2     VLDM/VSTM/VPUSH/VPOP of N ...... 1+N

These counts are the zero-wait-state figures (``Run.cycles``).  The memory
system of the STM32F405 at 168 MHz is modelled on top (``Run.memory_cycles``,
``MemorySystem``, ``memory_stalls``; docs/target.md has the derivation):
  - flash: 5 wait states at 168 MHz and 2.7-3.6 V (RM0090 rev 19, section 3.5.1,
    table 10), i.e. one 128-bit flash read takes 1 + 5 = 6 HCLK cycles; the flash
    interface serves one read at a time;
  - ART accelerator (RM0090 section 3.5.2): instruction cache of 64 lines of 128 bits
    (a line read on a miss is copied into it, and in this model a line used from the
    prefetch buffer too: see ``cache_prefetched``), LRU replacement; data cache of 8
    lines of 128 bits (literal pools and constant tables read through the D-code
    bus); prefetch of the next sequential 128-bit line while the current one
    executes; both caches modelled fully associative (the manual does not give the
    organisation);
  - contention: I-code and D-code share the flash interface; the D-code bus has
    priority (RM0090 section 3.5.2, "Data management"), modelled as: a read that has
    started (a prefetch included) completes, a data read goes before a prefetch that
    has not started yet;
  - SRAM1/SRAM2 (0x2000_0000) and CCM (0x1000_0000, data only) at zero wait states
    (RM0090 section 2.3.1 and 2.3.2; the S-bus and D-bus reach them without wait
    states); data reads there add nothing to the TRM counts;
  - not modelled: the core's own 3-word fetch buffer (fetches run a little ahead of
    execution, so the modelled instruction stalls are slightly pessimistic), code
    executing from SRAM (S-bus instruction fetches are registered, Cortex-M4 TRM
    section 2.3.1 "System interface": the library always runs from flash), DMA.
"""
from __future__ import annotations

import bisect
import struct
from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import capstone
import unicorn
from elftools.elf.elffile import ELFFile
from unicorn import arm_const as A

FLASH, FLASH_SIZE = 0x08000000, 1 << 20
RAM, RAM_SIZE = 0x20000000, 128 << 10
CCM, CCM_SIZE = 0x10000000, 64 << 10
SCS, SCS_SIZE = 0xE000E000, 0x1000
RETURN = 0x080FFF00  # returning here stops the emulation
CLOCK_HZ = 168e6
P = 2

_BRANCHES = {"b", "bl", "blx", "bx", "cbz", "cbnz"}


def _base(mn: str) -> str:
    mn = mn.split(".")[0]
    for cond in ("eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt", "le"):
        if len(mn) > len(cond) and mn.endswith(cond) and mn[:-len(cond)] in _BRANCHES | {"b"}:
            return mn[:-len(cond)]
    return mn


def instruction_cost(mnemonic: str, op_str: str, taken: bool) -> int:
    mn = mnemonic.lower()
    base = _base(mn)
    if base in _BRANCHES:
        return 1 + P if taken else 1
    if mn.startswith(("vmla", "vmls", "vfma", "vfms", "vfnm")):
        return 3
    if mn.startswith(("vdiv", "vsqrt")):
        return 14
    if mn.startswith(("vldm", "vstm", "vpush", "vpop")):
        regs = op_str[op_str.find("{") + 1:op_str.find("}")]
        n = sum(_reg_range(r) for r in regs.split(","))
        return 1 + n
    if mn.startswith(("vldr", "vstr")):
        return 2
    if mn.startswith("v"):
        return 1
    if base.startswith(("ldm", "stm", "push", "pop")):
        regs = op_str[op_str.find("{") + 1:op_str.find("}")]
        n = sum(_reg_range(r) for r in regs.split(","))
        return 1 + n + (P if "pc" in regs else 0)
    if base.startswith(("ldrd", "strd")):
        return 3
    if base.startswith(("ldr", "str")):
        return 2
    if base in ("mla", "mls"):
        return 2
    if base in ("sdiv", "udiv"):
        return 12
    return 1


def _reg_range(r: str) -> int:
    r = r.strip()
    if "-" in r:
        a, b = r.split("-")
        return int(b.strip()[1:]) - int(a.strip()[1:]) + 1
    return 1


@dataclass(frozen=True)
class MemorySystem:
    """Flash wait states and the ART accelerator (see the module docstring)."""
    name: str
    flash_wait_states: int = 5
    line_bytes: int = 16
    icache_lines: int = 64
    dcache_lines: int = 8
    prefetch: bool = True
    contention: bool = True  # False: instruction and data reads never wait for each other (optimistic)
    # a prefetched line that the core uses goes into the I-cache as well (RM0090 names
    # only missed lines; CoreMark, docs/target.md, matches ST's figures only with this)
    cache_prefetched: bool = True

    @property
    def read_cycles(self) -> int:
        """HCLK cycles of one 128-bit flash read."""
        return 1 + self.flash_wait_states


STM32F405_168MHZ = MemorySystem("STM32F405 at 168 MHz: flash 5 wait states, ART I-cache 64 x 128 bit, "
                                "D-cache 8 x 128 bit, prefetch on; SRAM/CCM zero wait")
ZERO_WAIT = MemorySystem("zero wait states", flash_wait_states=0)
# RM0090's wording taken literally: lines served from the prefetch buffer stay out of the I-cache
STM32F405_PREFETCH_UNCACHED = MemorySystem("STM32F405 at 168 MHz as above, prefetched lines not cached",
                                           cache_prefetched=False)
# the same without contention between instruction and data reads (a lower bound)
STM32F405_NO_CONTENTION = MemorySystem("STM32F405 at 168 MHz as above, instruction and data reads never "
                                       "waiting for each other (optimistic)", contention=False)


@dataclass
class Stalls:
    """Cycles that the memory system adds to the zero-wait count, and flash line reads."""
    fetch: int = 0
    data: int = 0
    fetch_misses: int = 0
    data_misses: int = 0
    prefetches: int = 0

    @property
    def total(self) -> int:
        return self.fetch + self.data


def _in_flash(addr: int) -> bool:
    return FLASH <= addr < FLASH + FLASH_SIZE


class _Lru:
    def __init__(self, n: int):
        self.n, self.lines = n, OrderedDict()

    def hit(self, line: int) -> bool:
        if line in self.lines:
            self.lines.move_to_end(line)
            return True
        return False

    def insert(self, line: int) -> None:
        if self.n <= 0:
            return
        self.lines[line] = True
        self.lines.move_to_end(line)
        if len(self.lines) > self.n:
            self.lines.popitem(last=False)


def memory_stalls(events, mem: MemorySystem = STM32F405_168MHZ) -> Stalls:
    """Stall cycles of an instruction stream on ``mem``.

    ``events``: per executed instruction (pc, size in bytes, zero-wait cycles,
    data reads as ((address, bytes), ...)), in program order.  Time advances by
    each instruction's zero-wait cycles plus its stalls.  An instruction that
    enters a new 128-bit line of flash code gets it from the I-cache (no stall),
    from the prefetch buffer (stall until the prefetched read is done) or from a
    flash read (miss: stall until the read is done; the line goes into the
    I-cache); then the next sequential line is prefetched unless cached.  Each
    flash data line a load touches comes from the D-cache or from a flash read
    (stall; into the D-cache).  A flash read starts when the flash interface is
    free and takes ``mem.read_cycles``; the zero-wait count already has one cycle
    per access, so a read started at once stalls ``flash_wait_states`` cycles.
    Reads outside flash (SRAM, CCM) and code outside flash add nothing.
    """
    st = Stalls()
    if mem.flash_wait_states == 0:
        return st
    lb, rc = mem.line_bytes, mem.read_cycles
    icache, dcache = _Lru(mem.icache_lines), _Lru(mem.dcache_lines)
    t = 0
    port_free = [0, 0]  # when the flash interface is free for instruction (0) and data (1) reads
    cur = pf_line = None
    pf_start = pf_ready = 0

    def read(at: int, side: int) -> int:  # a flash line read requested at `at`; returns its completion
        nonlocal pf_start, pf_ready
        if side == 1 and mem.contention and pf_line is not None and pf_start > at:
            # the D-code bus goes before the queued prefetch, which moves behind it
            done = pf_start + rc  # the interface is busy until pf_start (else the prefetch had started)
            pf_start, pf_ready = done, done + rc
            port_free[0] = port_free[1] = pf_ready
            return done
        start = max(at, port_free[side])
        done = start + rc
        if mem.contention:
            port_free[0] = port_free[1] = done
        else:
            port_free[side] = done
        return done

    for pc, size, cycles, reads in events:
        if _in_flash(pc):
            for line in range(pc // lb, (pc + size - 1) // lb + 1):
                if line == cur:
                    continue
                cur = line
                if icache.hit(line):
                    stall = 0
                elif mem.prefetch and line == pf_line:
                    stall = max(0, pf_ready - 1 - t)
                    if mem.cache_prefetched:
                        icache.insert(line)
                else:
                    stall = read(t, 0) - 1 - t
                    icache.insert(line)
                    st.fetch_misses += 1
                t += stall
                st.fetch += stall
                pf_line = None
                if mem.prefetch and (line + 1) not in icache.lines:
                    pf_ready = read(t, 0)
                    pf_line, pf_start = line + 1, pf_ready - rc
                    st.prefetches += 1
        else:
            cur = None
        for addr, n in reads:
            if not _in_flash(addr):
                continue
            for line in range(addr // lb, (addr + n - 1) // lb + 1):
                if dcache.hit(line):
                    continue
                stall = read(t, 1) - 1 - t
                dcache.insert(line)
                st.data_misses += 1
                t += stall
                st.data += stall
        t += cycles
    return st


@dataclass
class Run:
    instructions: int = 0
    cycles: int = 0  # zero wait states (Cortex-M4 TRM counts)
    mix: Counter = field(default_factory=Counter)
    by_function: Counter = field(default_factory=Counter)  # instructions
    cycles_by_function: Counter = field(default_factory=Counter)  # zero-wait cycles
    stalls: Stalls = field(default_factory=Stalls)  # added by the memory system
    memory: str = ZERO_WAIT.name

    @property
    def microseconds(self) -> float:
        """At zero wait states."""
        return self.cycles / CLOCK_HZ * 1e6

    @property
    def memory_cycles(self) -> int:
        """With the modelled memory system (``memory``)."""
        return self.cycles + self.stalls.total

    @property
    def memory_microseconds(self) -> float:
        return self.memory_cycles / CLOCK_HZ * 1e6


class Cm4:
    """An ELF loaded into unicorn's Cortex-M4, ready for function calls."""

    def __init__(self, elf: Path, memory: MemorySystem = STM32F405_168MHZ):
        self.elf = Path(elf)
        self.memory = memory
        mu = unicorn.Uc(unicorn.UC_ARCH_ARM, unicorn.UC_MODE_THUMB | unicorn.UC_MODE_MCLASS)
        mu.ctl_set_cpu_model(unicorn.arm_const.UC_CPU_ARM_CORTEX_M4)
        mu.mem_map(FLASH, FLASH_SIZE)
        mu.mem_map(RAM, RAM_SIZE)
        mu.mem_map(CCM, CCM_SIZE)
        mu.mem_map(SCS, SCS_SIZE)
        self.symbols = {}
        ram_end = RAM
        with open(self.elf, "rb") as f:
            elf = ELFFile(f)
            for seg in elf.iter_segments():
                if seg["p_type"] == "PT_LOAD" and RAM <= seg["p_vaddr"] < RAM + RAM_SIZE:
                    ram_end = max(ram_end, seg["p_vaddr"] + seg["p_memsz"])
                if seg["p_type"] == "PT_LOAD" and seg["p_filesz"]:
                    data = seg.data()
                    mu.mem_write(seg["p_paddr"], data)
                    if seg["p_vaddr"] != seg["p_paddr"]:
                        mu.mem_write(seg["p_vaddr"], data)  # .data as start-up would copy it
            for sym in elf.get_section_by_name(".symtab").iter_symbols():
                if sym["st_info"]["type"] in ("STT_FUNC", "STT_OBJECT"):
                    self.symbols[sym.name] = (sym["st_value"], sym["st_size"])
        # enable the FPU: CPACR CP10/CP11 full access
        mu.mem_write(0xE000ED88, struct.pack("<I", 0xF << 20))
        mu.reg_write(A.UC_ARM_REG_CPACR if hasattr(A, "UC_ARM_REG_CPACR") else A.UC_ARM_REG_C1_C0_2, 0xF << 20)
        self.mu = mu
        self.cs = capstone.Cs(capstone.CS_ARCH_ARM, capstone.CS_MODE_THUMB | capstone.CS_MODE_MCLASS)
        self._decoded: dict[int, tuple[str, str, int]] = {}
        # argument scratch area: above the image's .data/.bss (tables placed in SRAM
        # included), below the stack
        self.scratch = max(RAM + 0x8000, (ram_end + 0xFF) & ~0xFF)
        self.heap = self.scratch

    def addr(self, name: str) -> int:
        return self.symbols[name][0] & ~1

    def write(self, data: bytes) -> int:
        """Copy ``data`` into the scratch area; returns its address."""
        a = self.heap
        self.mu.mem_write(a, data)
        self.heap = (self.heap + len(data) + 7) & ~7
        return a

    def reset_scratch(self) -> None:
        self.heap = self.scratch

    def read(self, addr: int, n: int) -> bytes:
        return bytes(self.mu.mem_read(addr, n))

    def _decode(self, addr: int, size: int):
        d = self._decoded.get(addr)
        if d is None:
            ins = next(self.cs.disasm(self.read(addr, size), addr))
            d = (ins.mnemonic, ins.op_str, ins.size)
            self._decoded[addr] = d
        return d

    def call(self, name: str, *args: int, float_args: tuple[float, ...] = (), count: bool = True
             ) -> tuple[int, float, Run]:
        """Call ``name`` (integer/pointer args, then float args in s0..); returns (r0, s0, Run).
        ``count=False`` runs it without tracing (the same machine state after it, an empty
        Run): a warm-up at the emulator's own speed."""
        mu = self.mu
        sp = RAM + RAM_SIZE - 64
        stack_args = list(args[4:])
        sp -= 4 * len(stack_args)
        sp &= ~7
        for i, a in enumerate(stack_args):
            mu.mem_write(sp + 4 * i, struct.pack("<I", a & 0xFFFFFFFF))
        for i, a in enumerate(args[:4]):
            mu.reg_write(A.UC_ARM_REG_R0 + i, a & 0xFFFFFFFF)
        for i, v in enumerate(float_args):
            mu.reg_write(A.UC_ARM_REG_S0 + i, struct.unpack("<I", struct.pack("<f", v))[0])
        mu.reg_write(A.UC_ARM_REG_SP, sp)
        mu.reg_write(A.UC_ARM_REG_LR, RETURN | 1)
        if not count:
            mu.emu_start(self.addr(name) | 1, RETURN, timeout=0, count=50_000_000)
            mu.ctl_flush_tb()  # blocks translated without the hooks would run untraced later
            return (mu.reg_read(A.UC_ARM_REG_R0), struct.unpack("<f", struct.pack("<I", mu.reg_read(A.UC_ARM_REG_S0)))[0],
                    Run(memory=self.memory.name))
        trace: list[tuple[int, int]] = []
        flash_reads: dict[int, list[tuple[int, int]]] = {}

        def hook(uc, address, size, _):
            trace.append((address, size))

        def on_read(uc, access, address, size, value, _):
            flash_reads.setdefault(len(trace) - 1, []).append((address, size))

        h = mu.hook_add(unicorn.UC_HOOK_CODE, hook)
        hr = mu.hook_add(unicorn.UC_HOOK_MEM_READ, on_read, begin=FLASH, end=FLASH + FLASH_SIZE - 1)
        try:
            mu.emu_start(self.addr(name) | 1, RETURN, timeout=0, count=50_000_000)
        finally:
            mu.hook_del(h)
            mu.hook_del(hr)
        run = Run(memory=self.memory.name)
        funcs = sorted((a & ~1, a + sz, n) for n, (a, sz) in self.symbols.items() if sz)
        starts = [f[0] for f in funcs]
        events = []
        for k, (address, size) in enumerate(trace):
            j = bisect.bisect_right(starts, address) - 1
            fname = funcs[j][2] if j >= 0 and address < funcs[j][1] else "?"
            run.by_function[fname] += 1
            mn, ops, _ = self._decode(address, size)
            taken = False
            if _base(mn.lower()) in _BRANCHES:
                nxt = trace[k + 1][0] if k + 1 < len(trace) else RETURN
                taken = nxt != address + size
            cost = instruction_cost(mn, ops, taken)
            run.instructions += 1
            run.cycles += cost
            run.cycles_by_function[fname] += cost
            run.mix[mn.split(".")[0]] += 1
            events.append((address, size, cost, flash_reads.get(k, ())))
        run.stalls = memory_stalls(events, self.memory)
        r0 = mu.reg_read(A.UC_ARM_REG_R0)
        s0 = struct.unpack("<f", struct.pack("<I", mu.reg_read(A.UC_ARM_REG_S0)))[0]
        return r0, s0, run
