"""The library on the STM32F405 itself: cross-compiled for Cortex-M4F and run in
QEMU (netduinoplus2), compared bit for bit with the host C and the references."""
import numpy as np
import pytest

from ns2codegen import reference as ref
from ns2codegen.queries import random_queries
from ns2host import target

pytestmark = pytest.mark.skipif(not (target.have_toolchain() and target.have_qemu()),
                                reason="arm-none-eabi-gcc / qemu-system-arm missing: run scripts/install-deps.sh")


def _compare(exported, cmodel, q, res):
    f_ref, sel = ref.predict_f32(exported.em, q)
    q_ref, _ = ref.predict_q15(exported.em, q)
    f_host, info = cmodel.predict(q, fixed=False)
    q_host, _ = cmodel.predict(q, fixed=True)
    bits = res["f32"].view(np.uint32)
    assert np.array_equal(bits, f_ref.view(np.uint32)), np.flatnonzero(bits != f_ref.view(np.uint32))[:5]
    assert np.array_equal(bits, f_host.view(np.uint32))
    assert np.array_equal(res["q15"], q_ref) and np.array_equal(res["q15"], q_host)
    for key in ("status", "n_used", "n_invalid", "n_outside", "n_truncated"):
        assert np.array_equal(res["info_f32"][key], info[key]), key
        assert np.array_equal(res["info_q15"][key], info[key]), key
    assert set(np.unique(sel.status)) == {0, -1, -2}


@pytest.fixture(scope="module")
def cmodel(exported):
    return exported.cmodel()


def test_qemu_stm32f405_bit_exact(exported, cmodel):
    """20,000 queries (0..20 neighbours, edges, NaN/Inf, bad types) on the emulated MCU."""
    elf = target.build_image(exported.gen_dir)
    q = random_queries(exported.cfg, 20_000, seed=31, wild=0.05)
    res = target.run_vectors(elf, q)
    _compare(exported, cmodel, q, res)


def test_qemu_crazyflie_flags_os(exported, cmodel):
    """-Os, as the Crazyflie firmware builds: still bit-exact (no fused multiply-add)."""
    elf = target.build_image(exported.gen_dir, opt="-Os")
    q = random_queries(exported.cfg, 3_000, seed=32, wild=0.05)
    _compare(exported, cmodel, q, target.run_vectors(elf, q))


def test_portable_c_kernels_on_the_target(exported, cmodel):
    """The portable C kernels (NS2_NO_ASM) on the Cortex-M4 give the same bits as the
    assembly kernels, the host and the references."""
    elf = target.build_image(exported.gen_dir, defines=("NS2_NO_ASM",))
    q = random_queries(exported.cfg, 2_000, seed=33, wild=0.05)
    _compare(exported, cmodel, q, target.run_vectors(elf, q))


def test_target_reports_failure(exported, tmp_path):
    """A query the image rejects (too many neighbours for its buffer) is a clear error."""
    elf = target.build_image(exported.gen_dir)
    q = random_queries(exported.cfg, 3, seed=1, max_given=70)
    q.n[:] = 70
    with pytest.raises(target.TargetError, match="exited with"):
        target.run_vectors(elf, q)


@pytest.mark.parametrize("cc", ["gcc", "arm-none-eabi-gcc"])
def test_crazyflie_app_glue_compiles(exported, tmp_path, cc):
    """firmware/app against the declaration-only firmware headers, as the firmware
    builds it (-Os, gnu99), warnings as errors, for the host and the Cortex-M4F."""
    import subprocess

    from ns2host.cbuild import REPO, flags

    f = flags()
    arch = f["NS2_ARM_FLAGS"] if cc.startswith("arm") else []
    for src in ("ns2_app.c", "ns2_lib.c"):
        r = subprocess.run([cc, *arch, "-std=gnu99", "-Os", "-ffp-contract=off", *f["NS2_WARN_FLAGS"],
                            "-Wno-pedantic", "-Wno-strict-prototypes",
                            f"-I{REPO / 'firmware/app/test_stubs'}", *[f"-I{REPO / i}" for i in f["NS2_INCLUDES"]],
                            f"-I{exported.gen_dir}", "-c", str(REPO / "firmware/app/src" / src),
                            "-o", str(tmp_path / (src + ".o"))], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    for name in ("Makefile", "Kbuild", "app-config", "src/Kbuild"):
        assert (REPO / "firmware/app" / name).is_file()
    assert "-ffp-contract=off" in (REPO / "firmware/app/Makefile").read_text()
