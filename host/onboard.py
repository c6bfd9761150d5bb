"""The on-board label and adaptation (firmware/src/ns2_label.c, ns2_adapt.c) run over
sequences of position ticks, in the host build (cffi) and on the emulated
STM32F405 (QEMU), through the one loop of firmware/target/ns2_adapt_vectors.c;
the float32 references are ns2codegen.onboard."""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ns2codegen.onboard import ADAPT_FIELDS, ADAPT_U8_FIELDS, AdaptCfg, LabelCfg, u8

from . import cbuild, target

STEP_RESET, STEP_WAKE = 1, 2   # NS2_ADAPT_STEP_RESET, NS2_ADAPT_STEP_WAKE


@dataclass
class Ticks:
    """Inputs of n position ticks: vz, z [n], q [n, 4], pwm [n, 4], battery_V, nn_g [n],
    the adaptation's parameters per tick, the ticks that reset it and those in a wake,
    the composite tracking error times the period s_h [n] (m; zeros by default)."""
    vz: np.ndarray
    z: np.ndarray
    q: np.ndarray
    pwm: np.ndarray
    battery_V: np.ndarray
    nn_g: np.ndarray
    cfgs: list
    reset: np.ndarray
    wake: np.ndarray
    s_h: np.ndarray

    def __len__(self) -> int:
        return len(self.vz)


def ticks(vz, z, q, pwm, battery_V, nn_g, cfgs=None, reset=None, wake=None, s_h=None) -> Ticks:
    n = len(vz)
    cfgs = [AdaptCfg()] * n if cfgs is None else ([cfgs] * n if isinstance(cfgs, AdaptCfg) else list(cfgs))
    return Ticks(*(np.asarray(a, np.float32) for a in (vz, z, q, pwm, battery_V, nn_g)), cfgs,
                 *(np.zeros(n, bool) if a is None else np.asarray(a, bool) for a in (reset, wake)),
                 np.zeros(n, np.float32) if s_h is None else np.asarray(s_h, np.float32))


def _fill_label_cfg(c, cfg: LabelCfg) -> None:
    c.mass_kg, c.psi1, c.h_s, c.min_z_m, c.min_r33 = cfg.mass_kg, list(cfg.psi1), cfg.h_s, cfg.min_z_m, cfg.min_r33
    setattr(c, "lambda", cfg.lam)


def fill_adapt_cfg(c, cfg: AdaptCfg) -> None:
    for k in ADAPT_FIELDS:
        setattr(c, k, u8(getattr(cfg, k)) if k in ADAPT_U8_FIELDS else getattr(cfg, k))


def _inputs(ffi, t: Ticks):
    """The ticks as an ns2_adapt_in_t array (filled through numpy: the same float32
    roundings as cffi's field stores, many ticks fast)."""
    off = {k: ffi.offsetof("ns2_adapt_in_t", k) for k in ("vz", "z", "q", "pwm", "battery_V", "nn_g", "s_h", "cfg",
                                                            "flags")}
    coff = {k: off["cfg"] + ffi.offsetof("ns2_adapt_cfg_t", k) for k in ADAPT_FIELDS}
    names = ["vz", "z", "q", "pwm", "battery_V", "nn_g", "s_h", "flags"] + ADAPT_FIELDS
    fmts = ["<f4", "<f4", ("<f4", 4), ("<f4", 4), "<f4", "<f4", "<f4", "<u4"] + \
        ["u1" if k in ADAPT_U8_FIELDS else "<f4" for k in ADAPT_FIELDS]
    dt = np.dtype({"names": names, "formats": fmts, "offsets": [off[k] for k in names[:8]] +
                   [coff[k] for k in ADAPT_FIELDS], "itemsize": ffi.sizeof("ns2_adapt_in_t")})
    n = len(t)
    rec = np.zeros(max(n, 1), dt)
    for k in ("vz", "z", "q", "pwm", "battery_V", "nn_g", "s_h"):
        rec[k][:n] = getattr(t, k)
    rec["flags"][:n] = np.where(t.reset, STEP_RESET, 0) | np.where(t.wake, STEP_WAKE, 0)
    uniq: dict = {}
    which = np.array([uniq.setdefault(id(c), len(uniq)) for c in t.cfgs], np.int64)
    cfgs = {i: c for c in t.cfgs for i in [uniq[id(c)]]}
    for k in ADAPT_FIELDS:
        col = np.array([getattr(cfgs[i], k) for i in range(len(cfgs))], np.float64)
        if k in ADAPT_U8_FIELDS:    # uint8_t: the C conversion keeps the low byte of an integer
            col = np.array([u8(getattr(cfgs[i], k)) for i in range(len(cfgs))], np.uint8)
        rec[k][:n] = col[which] if n else rec[k][:0]
    buf = ffi.new("ns2_adapt_in_t[]", max(n, 1))
    ffi.buffer(buf)[:] = rec.tobytes()
    return buf


def _results(ffi, out, n: int) -> dict:
    dt = np.dtype([("label_N", "<f4"), ("label_g", "<f4"), ("out_g", "<f4"), ("term_g", "<f4"),
                   ("theta", "<f4", 2), ("P", "<f4", 3), ("label_status", "<u4"), ("adapt_status", "<u4"),
                   ("updates", "<u4")])
    assert dt.itemsize == ffi.sizeof("ns2_adapt_out_t")
    return _split(np.frombuffer(out, dt, count=n))


def _split(rec: np.ndarray) -> dict:
    return {k: rec[k].copy() for k in rec.dtype.names}


def run_host(gen_dir, label_cfg: LabelCfg, t: Ticks) -> dict:
    """The ticks through the host build: arrays label_N, label_g, out_g, term_g, theta
    [n, 2], P [n, 3], label_status, adapt_status, updates."""
    ffi, lib = cbuild.load(gen_dir)
    lc, ac = ffi.new("ns2_label_cfg_t *"), ffi.new("ns2_adapt_cfg_t *")
    _fill_label_cfg(lc, label_cfg)
    fill_adapt_cfg(ac, t.cfgs[0] if len(t) else AdaptCfg())
    lab, ad = ffi.new("ns2_label_t *"), ffi.new("ns2_adapt_t *")
    lib.ns2_label_init(lab, lc)
    lib.ns2_adapt_reset(ad, ac)
    steps = _inputs(ffi, t)
    out = ffi.new("ns2_adapt_out_t[]", max(len(t), 1))
    lib.ns2_adapt_run_steps(lab, ad, steps, out, len(t))
    return _results(ffi, ffi.buffer(out), len(t))


def build_image(gen_dir, opt: str | None = None) -> Path:
    """The label-and-adaptation vector image (semihosting)."""
    return target.build_image(gen_dir, program="qemu_adapt.c", opt=opt,
                              extra_sources=("firmware/target/ns2_adapt_vectors.c",))


def run_qemu(gen_dir, elf: Path, label_cfg: LabelCfg, t: Ticks, timeout: float = 300.0) -> dict:
    """The same ticks on the emulated STM32F405 (the structs' layout is the same on
    both little-endian 32-bit-float ABIs, checked by the sizes)."""
    import subprocess

    ffi, _ = cbuild.load(gen_dir)
    lc, ac = ffi.new("ns2_label_cfg_t *"), ffi.new("ns2_adapt_cfg_t *")
    _fill_label_cfg(lc, label_cfg)
    fill_adapt_cfg(ac, t.cfgs[0] if len(t) else AdaptCfg())
    data = b"NS2A" + np.uint32(len(t)).tobytes() + bytes(ffi.buffer(lc)) + bytes(ffi.buffer(ac)) \
        + bytes(ffi.buffer(_inputs(ffi, t)))[:len(t) * ffi.sizeof("ns2_adapt_in_t")]
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "ns2_in.bin").write_bytes(data)
        cmd = [target.QEMU, "-M", "netduinoplus2", "-nographic", "-monitor", "none", "-serial", "null",
               "-semihosting-config", "enable=on,target=native", "-kernel", str(elf)]
        r = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=timeout)
        if r.returncode != 0:
            raise target.TargetError(f"target exited with {r.returncode}: {r.stdout}{r.stderr}")
        out = (Path(tmp) / "ns2_out.bin").read_bytes()
    if len(out) != len(t) * ffi.sizeof("ns2_adapt_out_t"):
        raise target.TargetError(f"expected {len(t)} adaptation results, got {len(out)} bytes")
    return _results(ffi, out, len(t))
