"""Instruction counts of cross-compiled functions on an emulated Cortex-M4.

The ELF built for the STM32F405 is loaded into the unicorn engine (its
Cortex-M4 model, FPU enabled); a function is called with arguments in r0-r3
and on the stack and run until it returns.  Every executed instruction is
counted; capstone classifies them, and a documented Cortex-M4 cost model turns
the mix into estimated cycles (an estimate: the real core's bus wait states,
flash accelerator and load/store pipelining are not modelled).

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
"""
from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import capstone
import unicorn
from elftools.elf.elffile import ELFFile
from unicorn import arm_const as A

FLASH, FLASH_SIZE = 0x08000000, 1 << 20
RAM, RAM_SIZE = 0x20000000, 128 << 10
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
    nregs = op_str.count(",") + 1 if "{" in op_str else 1
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


@dataclass
class Run:
    instructions: int = 0
    cycles: int = 0
    mix: Counter = field(default_factory=Counter)
    by_function: Counter = field(default_factory=Counter)

    @property
    def microseconds(self) -> float:
        return self.cycles / CLOCK_HZ * 1e6


class Cm4:
    """An ELF loaded into unicorn's Cortex-M4, ready for function calls."""

    def __init__(self, elf: Path):
        self.elf = Path(elf)
        mu = unicorn.Uc(unicorn.UC_ARCH_ARM, unicorn.UC_MODE_THUMB | unicorn.UC_MODE_MCLASS)
        mu.ctl_set_cpu_model(unicorn.arm_const.UC_CPU_ARM_CORTEX_M4)
        mu.mem_map(FLASH, FLASH_SIZE)
        mu.mem_map(RAM, RAM_SIZE)
        mu.mem_map(SCS, SCS_SIZE)
        self.symbols = {}
        with open(self.elf, "rb") as f:
            elf = ELFFile(f)
            for seg in elf.iter_segments():
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
        self.heap = RAM + 0x8000  # argument scratch area (below the stack)

    def addr(self, name: str) -> int:
        return self.symbols[name][0] & ~1

    def write(self, data: bytes) -> int:
        """Copy ``data`` into the scratch area; returns its address."""
        a = self.heap
        self.mu.mem_write(a, data)
        self.heap = (self.heap + len(data) + 7) & ~7
        return a

    def reset_scratch(self) -> None:
        self.heap = RAM + 0x8000

    def read(self, addr: int, n: int) -> bytes:
        return bytes(self.mu.mem_read(addr, n))

    def _decode(self, addr: int, size: int):
        d = self._decoded.get(addr)
        if d is None:
            ins = next(self.cs.disasm(self.read(addr, size), addr))
            d = (ins.mnemonic, ins.op_str, ins.size)
            self._decoded[addr] = d
        return d

    def call(self, name: str, *args: int, float_args: tuple[float, ...] = ()) -> tuple[int, float, Run]:
        """Call ``name`` (integer/pointer args, then float args in s0..); returns (r0, s0, Run)."""
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
        trace: list[tuple[int, int]] = []

        def hook(uc, address, size, _):
            trace.append((address, size))

        h = mu.hook_add(unicorn.UC_HOOK_CODE, hook)
        try:
            mu.emu_start(self.addr(name) | 1, RETURN, timeout=0, count=50_000_000)
        finally:
            mu.hook_del(h)
        run = Run()
        funcs = sorted((a & ~1, a + sz, n) for n, (a, sz) in self.symbols.items() if sz)
        starts = [f[0] for f in funcs]
        import bisect

        for k, (address, size) in enumerate(trace):
            j = bisect.bisect_right(starts, address) - 1
            run.by_function[funcs[j][2] if j >= 0 and address < funcs[j][1] else "?"] += 1
            mn, ops, _ = self._decode(address, size)
            taken = False
            if _base(mn.lower()) in _BRANCHES:
                nxt = trace[k + 1][0] if k + 1 < len(trace) else RETURN
                taken = nxt != address + size
            run.instructions += 1
            run.cycles += instruction_cost(mn, ops, taken)
            run.mix[mn.split(".")[0]] += 1
        r0 = mu.reg_read(A.UC_ARM_REG_R0)
        s0 = struct.unpack("<f", struct.pack("<I", mu.reg_read(A.UC_ARM_REG_S0)))[0]
        return r0, s0, run
