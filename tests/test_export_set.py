"""Export atomic as a set (issue 17 D5): the new set is written to a new folder and
swapped in; a kill at any step leaves the complete old or the complete new set,
never a mix, and headers of two models refuse to compile together (#error)."""
import copy
import filecmp
import shutil
import subprocess
import sys

import pytest

from ns2codegen.config import Config
from ns2host.cbuild import flags

HEADERS = ("ns2_model_config.h", "ns2_model_float.h", "ns2_model_fixed.h", "ns2_vehicles.h")
SET = HEADERS + ("ns2_model_manifest.json",)


def _compile(tmp_path, inc_dirs, headers):
    f = flags()
    src = tmp_path / "mix.c"
    src.write_text("".join(f'#include "{h}"\n' for h in headers) + "int main(void) { return 0; }\n")
    return subprocess.run(["gcc", *f["NS2_STD_FLAGS"], *f["NS2_WARN_FLAGS"], *[f"-I{d}" for d in inc_dirs],
                           "-c", str(src), "-o", str(tmp_path / "mix.o")], capture_output=True, text=True)


def test_mixed_set_does_not_compile(exported, onboard, tmp_path):
    assert exported.manifest["model_hash"] != onboard.manifest["model_hash"]
    r = _compile(tmp_path, [exported.gen_dir], HEADERS)
    assert r.returncode == 0, r.stderr
    mixed = tmp_path / "mixed"   # the D5 state: config and float of model B, the rest of model A
    shutil.copytree(exported.gen_dir, mixed)
    for h in ("ns2_model_config.h", "ns2_model_float.h"):
        shutil.copy(onboard.gen_dir / h, mixed / h)
    r = _compile(tmp_path, [mixed], HEADERS)
    assert r.returncode != 0 and "mixed export set" in r.stderr, r.stderr
    r = _compile(tmp_path, [mixed], ("ns2_model_fixed.h", "ns2_model_float.h"))  # any order, any pair
    assert r.returncode != 0 and "mixed export set" in r.stderr


# a subprocess writes the set of model B over model A's and is SIGKILLed at one step
KILLER = """
import os, signal, sys
from pathlib import Path
from ns2codegen import fileio
step, out, src = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
files = {p.name: p.read_text() for p in src.iterdir() if p.name.startswith("ns2_")}
die = lambda *a, **k: os.kill(os.getpid(), signal.SIGKILL)
n = [0]
def nth(real, k):
    def f(*a, **kw):
        n[0] += 1
        if n[0] == k:
            die()
        return real(*a, **kw)
    return f
if step == "writing":
    os.fsync = nth(os.fsync, 3)
elif step == "before-swap":
    fileio._exchange = die
elif step == "between-renames":
    fileio._exchange = lambda a, b: False
    os.rename = nth(os.rename, 2)
elif step == "after-swap":
    fileio.shutil.rmtree = die
fileio.write_folder_set(out, files)
"""


def _same(a, b):
    return all(filecmp.cmp(a / n, b / n, shallow=False) for n in SET)


@pytest.mark.parametrize("step", ["writing", "before-swap", "between-renames", "after-swap"])
def test_a_kill_at_any_step_leaves_one_whole_set(exported, onboard, tmp_path, step):
    out = tmp_path / "gen"
    shutil.copytree(exported.gen_dir, out)
    (out / "README.md").write_text("kept\n")
    r = subprocess.run([sys.executable, "-c", KILLER, step, str(out), str(onboard.gen_dir)],
                       capture_output=True, text=True)
    assert r.returncode == -9, r.stderr   # it was killed at that step
    if step == "between-renames":   # the folder is briefly absent, the old set is complete beside it
        assert not out.exists()
        (aside,) = tmp_path.glob(".gen.old-*")
        assert _same(exported.gen_dir, aside)
    elif step == "after-swap":
        assert _same(onboard.gen_dir, out) and (out / "README.md").read_text() == "kept\n"
    else:
        assert _same(exported.gen_dir, out)
    if out.exists():
        assert _compile(tmp_path, [out], HEADERS).returncode == 0
    # the next export repairs and cleans up: the new set, the README, nothing left over
    r = subprocess.run([sys.executable, "-m", "ns2cli", "export", str(onboard.checkpoint), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert _same(onboard.gen_dir, out) and (out / "README.md").read_text() == "kept\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gen", "mix.c", "mix.o"] or \
        sorted(p.name for p in tmp_path.iterdir()) == ["gen"]


def test_fixed_output_range_is_stated_and_covers_the_controller_limit(cfg, exported):
    """The fixed-point output saturates at +-32768 2^-out_frac g (the float path does
    not): the manifest and the header state that range, the export checks that the
    controller's fa_max lies inside it, so that after the controller's clamp a
    saturated fixed output and the float output agree (16 large neighbours just
    overhead: the legal worst case of issue 17)."""
    import dataclasses

    from ns2codegen.export import check_output_range, output_range_g
    from ns2codegen.quantize import QuantizationError
    from ns2codegen.vehicle import G, default_gains, vehicle

    em, man = exported.em, exported.manifest
    lo, hi = output_range_g(em)
    assert man["fixed_output_range_g"]["value"] == [lo, hi] == [-32768 * 2.0 ** -em.q15.out_frac,
                                                                32767 * 2.0 ** -em.q15.out_frac]
    text = (exported.gen_dir / "ns2_model_config.h").read_text()
    assert "#define NS2_Q_OUT_MIN_G" in text and "#define NS2_Q_OUT_MAX_G" in text
    c = exported.cmodel()
    ffi, lib = c.ffi, c.lib
    n = lib.NS2_MAX_NEIGHBORS
    nb = ffi.new("ns2_neighbor_t[]", n)
    large = cfg.robot_types.index("large")
    for j in range(n):
        nb[j].type = large
        nb[j].rel = [0.0, 0.0, 0.2 + 0.01 * j, 0.0, 0.0, 0.0]
    p, v = ffi.new("float[3]", [0, 0, 1.0]), ffi.new("float[3]", [0, 0, 0])
    for rt in range(len(cfg.robot_types)):
        f = lib.ns2_predict_f32(rt, p, v, nb, n, ffi.NULL)
        g = lib.ns2_predict_q15_g(rt, p, v, nb, n, ffi.NULL)
        assert lo <= g <= hi
        fa_max = default_gains(vehicle(cfg, cfg.robot_types[rt]))["fa_max_N"] * 1000.0 / G
        assert fa_max <= min(-lo, hi)
        clamp = lambda x: max(-fa_max, min(fa_max, x))  # noqa: E731
        assert abs(clamp(f) - clamp(g)) <= 2.0 ** -em.q15.out_frac + 0.05 * abs(clamp(f)) + 0.5
    heavy = copy.deepcopy(cfg.raw)
    heavy["robot_types"][0]["mass_g"] = 1e5   # fa_max 30 kg: beyond any int16 output range
    bad = dataclasses.replace(em, cfg=Config.from_dict(heavy))
    with pytest.raises(QuantizationError, match="fa_max"):
        check_output_range(bad)
