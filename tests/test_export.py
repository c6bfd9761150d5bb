"""Export: determinism, stand-alone headers, the overflow proof, the cross build,
bad input, and a third robot type added by configuration only."""
import copy
import filecmp
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from ns2codegen import export as export_mod
from ns2codegen import reference as ref
from ns2codegen.config import Config
from ns2codegen.queries import random_queries
from ns2host.cbuild import REPO, flags

from conftest import ARM, needs, train_and_export

HEADERS = ("ns2_model_config.h", "ns2_model_float.h", "ns2_model_fixed.h", "ns2_vehicles.h")
ARM_CC = shutil.which("arm-none-eabi-gcc")


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "ns2cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd)


@pytest.fixture(params=["exported", "history"])
def model(request):
    """The default network, then the one with wake memory (conftest.history)."""
    return request.getfixturevalue(request.param)


def test_export_is_byte_identical(model, tmp_path):
    exported = model
    r = _cli("export", exported.checkpoint, "--out", tmp_path / "again")
    assert r.returncode == 0, r.stderr
    for name in HEADERS + ("ns2_model_manifest.json",):
        assert filecmp.cmp(exported.gen_dir / name, tmp_path / "again" / name, shallow=False), name


def test_history_lags_in_the_headers_and_the_proof(exported, history):
    """Wake memory: NS2_INPUT_DIM 6 (1 + lags) and the lags (ms) in the generated
    config, the proof over phi's 24 inputs (each within its component's box), the
    manifest's dims; a network without history has none of it (its headers are
    those of before, byte for byte: test_export_is_byte_identical keeps them)."""
    text = (history.gen_dir / "ns2_model_config.h").read_text()
    assert "#define NS2_INPUT_DIM 24\n" in text and "#define NS2_HISTORY_LAGS 3\n" in text
    assert "#define NS2_HISTORY_MAX_MS 200\n" in text and "{50, 100, 200};" in text
    plain = (exported.gen_dir / "ns2_model_config.h").read_text()
    assert "#define NS2_INPUT_DIM 6\n" in plain and "HISTORY" not in plain and "history" not in plain
    assert history.manifest["dims"]["history_ms"] == [50, 100, 200] and history.manifest["dims"]["phi"][0] == 24
    assert "history_ms" not in exported.manifest["dims"]
    first = history.manifest["overflow_proof"]["layers"][0]
    assert first["layer"] == "phi[small].layer0" and len(first["max_abs_inputs"]) == 24
    assert first["max_abs_inputs"][6:12] == first["max_abs_inputs"][:6] == first["max_abs_inputs"][18:]


def test_float_weights_round_trip_exactly(exported):
    text = (exported.gen_dir / "ns2_model_float.h").read_text()
    w, b = exported.em.phi[0][1]  # phi[small] layer 1: 25 -> 40
    start = text.index("ns2_f32_phi_small_l1[")
    body = text[text.index("{", start) + 1:text.index("};", start)]
    vals = np.array([float.fromhex(t.strip().rstrip("f")) for t in body.split(",") if t.strip()], np.float64)
    stream = vals.reshape(-1, 1 + w.shape[1], 4)  # [block][bias, inputs][row]
    assert np.array_equal(stream[:, 0, :].ravel()[:w.shape[0]], b.astype(np.float64))
    assert np.array_equal(stream[:, 1:, :].transpose(0, 2, 1).reshape(-1, w.shape[1])[:w.shape[0]],
                          w.astype(np.float64))
    assert np.array_equal(vals.astype(np.float32).astype(np.float64), vals)  # exactly float32 values
    assert export_mod.cfloat(-0.0) == "-0.0f" and export_mod.cfloat(1.0) == "0x1p+0f"


def test_fixed_stream_layout(exported):
    """The packed int32 stream decodes to the quantized int16 weights and biases."""
    layer = exported.em.q15.rho[0].layers[0]
    stream = export_mod.fixed_layout(layer.w, layer.b, layer.shift)
    nq = layer.w.shape[1] // 4
    blocks = stream.reshape(-1, 4 + 8 * nq)
    half = (1 << (layer.shift - 1)) if layer.shift else 0
    assert np.array_equal(blocks[:, :4].ravel()[:layer.w.shape[0]], layer.b.astype(np.int64) + half)
    words = blocks[:, 4:].reshape(-1, 2 * nq, 4)  # [block][input pair][row]
    lo = ((words & 0xFFFF) ^ 0x8000) - 0x8000
    hi = (words - (words & 0xFFFF)) // 65536
    w = np.stack([lo, hi], -1).transpose(0, 2, 1, 3).reshape(-1, 4 * nq)  # [block, row][pair, half]
    assert np.array_equal(w[:layer.w.shape[0]], layer.w)


@pytest.mark.parametrize("header", HEADERS)
def test_headers_compile_stand_alone(model, tmp_path, header):
    exported = model
    f = flags()
    src = tmp_path / "one.c"
    src.write_text(f'#include "{header}"\nint main(void) {{ return 0; }}\n')
    r = subprocess.run(["gcc", *f["NS2_STD_FLAGS"], *f["NS2_WARN_FLAGS"], "-I", str(exported.gen_dir),
                        "-c", str(src), "-o", str(tmp_path / "one.o")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_manifest_and_overflow_proof(exported):
    man = exported.manifest
    em = exported.em
    assert man["model_hash"] == em.model_hash and len(man["model_hash"]) == 64
    assert man["dims"]["phi"] == [6, 25, 40, 40, 20] and man["dims"]["max_neighbors"] == 16
    proof = man["overflow_proof"]["layers"]
    assert len(proof) == 5 * 4 + 1
    for p in proof:
        assert 0 < p["accumulator_bound"] <= 2**31 - 1
    # re-derive every bound independently: own interval propagation from the box
    q = em.q15

    def sat(a, s):
        a = (a + ((1 << (s - 1)) if s else 0)) >> s
        return np.clip(a, -32768, 32767)

    def run(net, lo, hi, name):
        for l, layer in enumerate(net.layers):
            w = layer.w.astype(np.int64)[:, :layer.n_in]
            b = layer.b.astype(np.int64)
            half = (1 << (layer.shift - 1)) if layer.shift else 0
            amax = np.maximum(np.abs(lo), np.abs(hi))
            bound = (np.abs(b) + np.abs(w) @ amax + half).max()
            assert bound <= 2**31 - 1
            p = next(p for p in proof if p["layer"] == f"{name}.layer{l}")
            assert p["accumulator_bound"] >= bound and p["max_abs_inputs"] == amax.tolist()
            a_lo = b + np.minimum(w * lo, w * hi).sum(1)
            a_hi = b + np.maximum(w * lo, w * hi).sum(1)
            lo, hi = sat(a_lo, layer.shift), sat(a_hi, layer.shift)
            if l + 1 < len(net.layers):
                lo, hi = np.maximum(lo, 0), np.maximum(hi, 0)
        return lo, hi

    outs = []
    for t, net in enumerate(q.phi):
        box = em.boxes[t]
        lo = ref.quantize_input(box[:, 0], q.in_scale[t])
        hi = ref.quantize_input(box[:, 1], q.in_scale[t])
        outs.append(run(net, lo, hi, f"phi[{em.cfg.neighbor_types[t]}]"))
    env_lo, env_hi = outs[em.env_index]
    n = em.max_neighbors
    h_lo = env_lo + n * np.minimum(np.minimum.reduce([o[0] for o in outs[:-1]]), 0)
    h_hi = env_hi + n * np.maximum(np.maximum.reduce([o[1] for o in outs[:-1]]), 0)
    for r, net in enumerate(q.rho):
        run(net, sat(h_lo, q.sum_shift), sat(h_hi, q.sum_shift), f"rho[{em.cfg.robot_types[r]}]")
    err = man["fixed_vs_float_error_g"]
    assert err["box"]["max_abs_g"] < 0.5 and err["typical"]["mean_abs_g"] < 0.05
    assert man["lipschitz"]["per_neighbor_input"] == pytest.approx(
        max(man["lipschitz"]["rho"]) * max(man["lipschitz"]["phi"]))
    assert "C" not in man["q_formats"]["in_frac"] and set(man["q_formats"]["in_frac"]) == {"small", "large", "env"}


def test_proof_holds_on_extreme_inputs(model):
    """Corners of the box with the maximum number of neighbours, all at the same
    extreme: the integer model checks every accumulator against int32."""
    cfg, em = model.cfg, model.em
    q = random_queries(cfg, 4000, seed=11, max_given=cfg.model["max_neighbors"], inside=1.0, edge=1.0)
    q.n[:] = cfg.model["max_neighbors"]
    out, sel = ref.predict_q15(em, q)  # raises OverflowError if the proof were wrong
    assert (sel.status == 0).all() and out.dtype == np.int16


@needs(ARM)
@pytest.mark.parametrize("opt", ["-O2", "-Os", "-O0"])  # -O0: Crazyflie debug builds (portable kernels)
def test_cross_compiles_for_cortex_m4f_without_fma(model, tmp_path, opt):
    exported = model
    f = flags()
    inc = [f"-I{REPO / i}" for i in f["NS2_INCLUDES"]] + [f"-I{exported.gen_dir}"]
    for src in f["NS2_SOURCES"]:
        obj = tmp_path / (os.path.basename(src) + ".o")
        r = subprocess.run([ARM_CC, *f["NS2_ARM_FLAGS"], *f["NS2_STD_FLAGS"], opt, *f["NS2_WARN_FLAGS"], *inc,
                            "-c", str(REPO / src), "-o", str(obj)], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        dis = subprocess.run(["arm-none-eabi-objdump", "-d", str(obj)], capture_output=True, text=True).stdout
        assert "vfma" not in dis and "vfms" not in dis and "vfnm" not in dis
        if src.endswith("ns2_q15.c"):  # the SMLAD kernels in optimized builds only
            assert ("\tsmlad\t" in dis) == (opt != "-O0")
        if src.endswith("ns2_f32.c"):
            # hardware float, not soft-float calls; VMLA is the unfused (twice rounded) form
            assert ("vmul.f32" in dis or "vmla.f32" in dis) and "vadd.f32" in dis


# ------------------------------------------------------------------ bad input
@pytest.fixture
def previous_out(exported, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(exported.gen_dir, out)
    return out


def _unchanged(exported, out):
    for name in HEADERS:
        assert filecmp.cmp(exported.gen_dir / name, out / name, shallow=False)
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]


def test_truncated_and_garbage_checkpoints(exported, tmp_path, previous_out):
    data = exported.checkpoint.read_bytes()
    for name, blob in (("trunc.pt", data[: len(data) // 2]), ("garbage.pt", os.urandom(4096)), ("empty.pt", b"")):
        p = tmp_path / name
        p.write_bytes(blob)
        r = _cli("export", p, "--out", previous_out)
        assert r.returncode != 0 and "corrupt or truncated" in r.stderr, r.stderr
        _unchanged(exported, previous_out)
    r = _cli("export", tmp_path / "missing.pt", "--out", previous_out)
    assert r.returncode != 0 and "not found" in r.stderr


def _tampered(exported, tmp_path, fn):
    obj = torch.load(exported.checkpoint, weights_only=True)
    fn(obj)
    p = tmp_path / "tampered.pt"
    torch.save(obj, p)
    return p


def test_nan_weights_and_wrong_shapes(exported, tmp_path, previous_out):
    def nan(obj):
        obj["state_dict"]["rho.1.layers.2.weight"][3, 4] = float("nan")

    def shape(obj):
        obj["state_dict"]["phi.0.layers.1.weight"] = torch.zeros(40, 24)

    def meta(obj):
        m = json.loads(obj["meta_json"])
        m["config"]["model"]["hidden"] = 10
        obj["meta_json"] = json.dumps(m)

    for fn, msg in ((nan, "NaN"), (shape, "shape"), (meta, "shape")):
        r = _cli("export", _tampered(exported, tmp_path, fn), "--out", previous_out)
        assert r.returncode != 0 and msg in r.stderr, r.stderr
        _unchanged(exported, previous_out)


def test_unwritable_output(exported, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for out in (blocker, blocker / "sub"):
        r = _cli("export", exported.checkpoint, "--out", out)
        assert r.returncode != 0 and "Error" in r.stderr and "Traceback" not in r.stderr
    assert blocker.read_text() == "x"


def test_failure_mid_write_leaves_old_headers(exported, previous_out, monkeypatch):
    calls = []
    real_fsync = os.fsync

    def failing_fsync(fd):
        calls.append(fd)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", failing_fsync)
    from ns2codegen.fileio import OutputError

    with pytest.raises(OutputError, match="No space left"):
        export_mod.export(exported.checkpoint, previous_out)
    assert len(calls) == 3  # two headers were written before the third failed
    monkeypatch.setattr(os, "fsync", real_fsync)
    _unchanged(exported, previous_out)
    assert sorted(p.name for p in previous_out.parent.iterdir()) == ["out"]  # no new set left behind


# ------------------------------------------------------------------ a third robot type
def test_third_robot_type_by_config_only(cfg, tmp_path):
    raw = copy.deepcopy(cfg.raw)
    raw["robot_types"].append({"name": "heavy-lifter 2", "mass_g": 120.0, "max_thrust_g": 250.0,
                               "diameter_m": 0.25, "lambda": 12.0})
    cfg3 = Config.from_dict(raw)
    assert cfg3.neighbor_types == ["small", "large", "heavy-lifter 2", "env"]
    ex = train_and_export(cfg3, tmp_path, samples=150, epochs=1)
    text = (ex.gen_dir / "ns2_model_config.h").read_text()
    assert "#define NS2_TYPE_HEAVY_LIFTER_2 2" in text and "#define NS2_ENV_TYPE 3" in text
    assert "ns2_f32_rho_heavy_lifter_2_layers" in (ex.gen_dir / "ns2_model_float.h").read_text()
    c = ex.cmodel()
    assert c.lib.NS2_NUM_ROBOT_TYPES == 3
    q = random_queries(cfg3, 5000, seed=2, wild=0.05)
    f_c, _ = c.predict(q, False)
    f_r, _ = ref.predict_f32(ex.em, q)
    assert np.array_equal(f_c.view(np.uint32), f_r.view(np.uint32))
    i_c, _ = c.predict(q, True)
    i_r, _ = ref.predict_q15(ex.em, q)
    assert np.array_equal(i_c, i_r)
    assert (q.robot_type == 2).sum() > 1000
