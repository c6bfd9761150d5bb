"""Cortex-M4F target builds of the firmware library and runs in QEMU.

``build_image`` cross-compiles the library (the same sources and flags as the
host build, plus ``firmware/flags.mk``'s ARM flags) with a test program from
``firmware/target/`` into an ELF for the STM32F405.  ``run_vectors`` runs the
query-vector image in ``qemu-system-arm -M netduinoplus2`` with semihosting:
queries go in through ``ns2_in.bin``, results come back in ``ns2_out.bin``.

ns2_in.bin:  "NS2V", u32 count, then per query
             u8 robot_type, u8 pad, u16 n, f32 p[3], f32 v[3],
             n x ns2_neighbor_t (u8 type, 3 pad bytes, f32 rel[NS2_INPUT_DIM]),
             with wake memory (NS2_HISTORY_LAGS > 0) then f32 own_past[6 lags]
ns2_out.bin: per query f32 float result, i16 fixed result, u16 pad,
             ns2_info_t of the float call, ns2_info_t of the fixed call
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ns2codegen.errors import Ns2Error

from .cbuild import REPO, BUILD_ROOT, GENERATED, cached, compile_error, content_hash, flags

ARM_CC = os.environ.get("ARM_CC", "arm-none-eabi-gcc")
TARGET_DIR = REPO / "firmware" / "target"
QEMU = "qemu-system-arm"

QUERY_DT = np.dtype([("robot_type", "u1"), ("pad", "u1"), ("n", "<u2"), ("p", "<f4", 3), ("v", "<f4", 3)])
def nbr_dtype(input_dim: int = 6) -> np.dtype:
    """ns2_neighbor_t of a model with ``input_dim`` phi inputs (6 without wake memory)."""
    return np.dtype({"names": ["type", "rel"], "formats": ["u1", ("<f4", input_dim)], "offsets": [0, 4],
                     "itemsize": 4 + 4 * input_dim})


NBR_DT = nbr_dtype()
INFO_DT = [("status", "<i4"), ("n_used", "<u2"), ("n_invalid", "<u2"), ("n_outside", "<u2"), ("n_truncated", "<u2")]
# f32/q15: ns2_predict_*; *_sliced: the same query through ns2_job_* in slices of
# 1 + (query index mod 5) phi evaluations
RESULT_DT = np.dtype([("f32", "<f4"), ("q15", "<i2"), ("pad", "<u2"), ("info_f32", INFO_DT), ("info_q15", INFO_DT),
                      ("f32_sliced", "<f4"), ("q15_sliced", "<i2"), ("pad2", "<u2")])


# Weight-table placement (firmware/src/ns2_internal.h): the defines that put
# tables in SRAM instead of flash.
RAM_ALL = ("NS2_RAM_Q15_PHI", "NS2_RAM_Q15_RHO", "NS2_RAM_F32_PHI", "NS2_RAM_F32_RHO")


def ram_placement(robot_type_name: str, path: str = "q15") -> tuple[str, ...]:
    """Defines that put the hot tables of one robot in SRAM: every phi net of the
    path (q15 / f32; streamed once per neighbour or pair) and the rho net of its
    own type (streamed once per prediction)."""
    from ns2codegen.config import c_identifier

    p = path.upper()
    return (f"NS2_RAM_{p}_PHI", f"NS2_TABLE_{p}_RHO_{c_identifier(robot_type_name).upper()}=NS2_RAM_TABLE")


def table_bytes(elf: Path) -> dict[str, dict]:
    """Bytes of the generated weight tables in an image, by path and net
    (q15_phi, q15_rho, f32_phi, f32_rho), and how many of them are in SRAM."""
    from elftools.elf.elffile import ELFFile

    out = {k: {"bytes": 0, "in_ram_bytes": 0} for k in ("q15_phi", "q15_rho", "f32_phi", "f32_rho")}
    with open(elf, "rb") as f:
        for sym in ELFFile(f).get_section_by_name(".symtab").iter_symbols():
            parts = sym.name.split("_")
            if sym["st_info"]["type"] != "STT_OBJECT" or len(parts) < 4 or parts[0] != "ns2" or \
                    parts[1] not in ("q15", "f32") or parts[2] not in ("phi", "rho") or not parts[-1].startswith("l") \
                    or not parts[-1][1:].isdigit():
                continue
            d = out[f"{parts[1]}_{parts[2]}"]
            d["bytes"] += sym["st_size"]
            if 0x20000000 <= sym["st_value"] < 0x20020000:
                d["in_ram_bytes"] += sym["st_size"]
    return out


def have_toolchain() -> bool:
    return shutil.which(ARM_CC) is not None


def have_qemu() -> bool:
    return shutil.which(QEMU) is not None


def build_image(gen_dir: Path, program: str = "qemu_vectors.c", opt: str | None = None,
                extra_sources: tuple[str, ...] = (), defines: tuple[str, ...] = (),
                semihosting: bool = True) -> Path:
    """Cross-compile ``firmware/target/<program>`` + the library into an ELF (cached)."""
    f = flags()
    gen_dir = Path(gen_dir).resolve()
    opt_flags = [opt] if opt else f["NS2_OPT_FLAGS"]
    sources = [REPO / s for s in f["NS2_SOURCES"]] + [REPO / s for s in extra_sources] + \
        [TARGET_DIR / "startup_cm4.c", TARGET_DIR / program]
    key = content_hash([*sources, *sorted((REPO / "firmware" / "include").glob("*.h")),
                        *sorted((REPO / "firmware" / "src").glob("*.h")), *sorted(TARGET_DIR.glob("*.h")),
                        *sorted((REPO / "firmware" / "hil").glob("*.h")), *[gen_dir / g for g in GENERATED],
                        TARGET_DIR / "stm32f405.ld", repr((sorted(f.items()), opt_flags, ARM_CC, defines, semihosting))],
                       16)
    out = BUILD_ROOT.parent / "arm" / f"{Path(program).stem}-{key}.elf"
    inc = [f"-I{REPO / i}" for i in f["NS2_INCLUDES"]] + [f"-I{gen_dir}", f"-I{TARGET_DIR}"]

    def build(tmp: Path) -> None:
        cmd = [ARM_CC, *f["NS2_ARM_FLAGS"], *f["NS2_STD_FLAGS"], *opt_flags, *f["NS2_WARN_FLAGS"], *inc,
               *[f"-D{d}" for d in defines], "-ffunction-sections", "-fdata-sections", "-g",
               *(["-DNS2_SEMIHOSTING", "--specs=rdimon.specs"] if semihosting else ["--specs=nosys.specs"]),
               "-nostartfiles", f"-T{TARGET_DIR / 'stm32f405.ld'}",
               "-Wl,--gc-sections", *map(str, sources), "-lm", "-o", str(tmp / out.name)]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise compile_error(f"the target image {out.name}", cmd, r)

    return cached(out, build, product=None)


def build_controller_image(gen_dir: Path, opt: str | None = None) -> Path:
    """The controller-step vector image (semihosting)."""
    return build_image(gen_dir, program="qemu_controller.c", opt=opt,
                       extra_sources=("firmware/target/ns2_ctrl_vectors.c",))


def run_controller_vectors(elf: Path, vehicle: bytes, gains: bytes, steps: bytes, step_size: int,
                           out_size: int, timeout: float = 300.0) -> bytes:
    """Run controller steps on the emulated STM32F405; returns the raw ns2_step_out_t records."""
    count = len(steps) // step_size
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "ns2_in.bin").write_bytes(b"NS2C" + np.uint32(count).tobytes() + vehicle + gains + steps)
        cmd = [QEMU, "-M", "netduinoplus2", "-nographic", "-monitor", "none", "-serial", "null",
               "-semihosting-config", "enable=on,target=native", "-kernel", str(elf)]
        r = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=timeout)
        if r.returncode != 0:
            raise TargetError(f"target exited with {r.returncode}: {r.stdout}{r.stderr}")
        data = (Path(tmp) / "ns2_out.bin").read_bytes()
    if len(data) != count * out_size:
        raise TargetError(f"expected {count} controller results, got {len(data) / out_size}")
    return data


def build_hil_image(gen_dir: Path, opt: str | None = None) -> Path:
    """The serial HIL image (no semihosting: it runs on a board as well)."""
    return build_image(gen_dir, program="hil_usart.c", opt=opt,
                       extra_sources=tuple(flags()["NS2_HIL_SOURCES"]), semihosting=False)


def encode_queries(q) -> bytes:
    """Queries (ns2codegen.queries) in the ns2_in.bin layout."""
    parts = [b"NS2V", np.uint32(len(q)).tobytes()]
    dt = nbr_dtype(q.nbr_rel.shape[-1])
    for i in range(len(q)):
        head = np.zeros(1, QUERY_DT)
        head["robot_type"], head["n"], head["p"], head["v"] = q.robot_type[i], q.n[i], q.p[i], q.v[i]
        nb = np.zeros(int(q.n[i]), dt)
        nb["type"] = q.nbr_type[i, :q.n[i]]
        nb["rel"] = q.nbr_rel[i, :q.n[i]]
        parts += [head.tobytes(), nb.tobytes(), np.ascontiguousarray(q.past[i], "<f4").tobytes()]
    return b"".join(parts)


class TargetError(Ns2Error, RuntimeError):
    """The emulated target failed or produced no complete result."""


def run_vectors(elf: Path, q, timeout: float = 300.0) -> np.ndarray:
    """Run queries on the emulated STM32F405; returns RESULT_DT records."""
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "ns2_in.bin").write_bytes(encode_queries(q))
        cmd = [QEMU, "-M", "netduinoplus2", "-nographic", "-monitor", "none", "-serial", "null",
               "-semihosting-config", "enable=on,target=native", "-kernel", str(elf)]
        try:
            r = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired as e:
            raise TargetError(f"qemu timed out after {timeout} s") from e
        if r.returncode != 0:
            raise TargetError(f"target exited with {r.returncode}: {r.stdout}{r.stderr}")
        data = (Path(tmp) / "ns2_out.bin").read_bytes()
    if len(data) != len(q) * RESULT_DT.itemsize:
        raise TargetError(f"expected {len(q)} results, got {len(data) / RESULT_DT.itemsize}")
    return np.frombuffer(data, RESULT_DT)
