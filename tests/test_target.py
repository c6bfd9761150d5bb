"""The library on the STM32F405 itself: cross-compiled for Cortex-M4F and run in
QEMU (netduinoplus2), compared bit for bit with the host C and the references."""
import numpy as np
import pytest

from ns2codegen import reference as ref
from ns2codegen.queries import random_queries
from conftest import ARM, QEMU, needs
from ns2host import target

pytestmark = needs(ARM, QEMU)


def _compare(exported, cmodel, q, res):
    f_ref, sel = ref.predict_f32(exported.em, q)
    q_ref, _ = ref.predict_q15(exported.em, q)
    f_host, info = cmodel.predict(q, fixed=False)
    q_host, _ = cmodel.predict(q, fixed=True)
    bits = res["f32"].view(np.uint32)
    assert np.array_equal(bits, f_ref.view(np.uint32)), np.flatnonzero(bits != f_ref.view(np.uint32))[:5]
    assert np.array_equal(bits, f_host.view(np.uint32))
    assert np.array_equal(res["q15"], q_ref) and np.array_equal(res["q15"], q_host)
    assert np.array_equal(res["f32_sliced"].view(np.uint32), bits)  # ns2_job_*, sliced
    assert np.array_equal(res["q15_sliced"], res["q15"])
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


def test_qemu_onboard_variant_bit_exact(onboard):
    """The one-tick on-board network (other layer widths, other kernel sizes)."""
    elf = target.build_image(onboard.gen_dir)
    q = random_queries(onboard.cfg, 4_000, seed=34, wild=0.05)
    _compare(onboard, onboard.cmodel(), q, target.run_vectors(elf, q))


@pytest.mark.parametrize("opt", [None, "-Os"])
def test_qemu_history_network_bit_exact(history, opt):
    """The network with wake memory (24 inputs per neighbour, the robot's own past,
    the *_hist entry points): other kernel sizes, NaN/Inf in past states too."""
    elf = target.build_image(history.gen_dir, opt=opt)
    q = random_queries(history.cfg, 4_000, seed=35, wild=0.05)
    assert q.past.shape[1] == 3 and q.nbr_rel.shape[-1] == 24
    _compare(history, history.cmodel(), q, target.run_vectors(elf, q))


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


def test_tables_in_ram_bit_exact(exported, cmodel):
    """Weight tables placed in SRAM (copied from flash at start-up: the hot tables of
    robot type 0, fixed point and float) give the same bits as the host."""
    name = exported.cfg.robot_types[0]
    elf = target.build_image(exported.gen_dir, defines=target.ram_placement(name, "q15") +
                             target.ram_placement(name, "f32"))
    tb = target.table_bytes(elf)
    for k in ("q15", "f32"):
        assert tb[f"{k}_phi"]["in_ram_bytes"] == tb[f"{k}_phi"]["bytes"] > 0
        rho = tb[f"{k}_rho"]
        assert rho["bytes"] == len(exported.cfg.robot_types) * rho["in_ram_bytes"] > 0  # its own type only
    q = random_queries(exported.cfg, 3_000, seed=35, wild=0.05)
    _compare(exported, cmodel, q, target.run_vectors(elf, q))


def test_target_reports_failure(exported, tmp_path):
    """A query the image rejects (too many neighbours for its buffer) is a clear error."""
    elf = target.build_image(exported.gen_dir)
    q = random_queries(exported.cfg, 3, seed=1, max_given=70)
    q.n[:] = 70
    with pytest.raises(target.TargetError, match="exited with"):
        target.run_vectors(elf, q)


def _controller_steps(ffi, n, seed):
    """n controller steps: states around a hover setpoint, attitudes up to 0.6 rad,
    random rates, yaw setpoints all around, learned forces, 2 % NaN/Inf states and
    setpoints, position updates every 5th step, some without a learned term."""
    rng = np.random.default_rng(seed)
    steps = ffi.new("ns2_step_in_t[]", n)
    for k in range(n):
        st = steps[k]
        axis = rng.normal(size=3)
        ang = rng.uniform(0, 0.6)
        q = [np.cos(ang / 2), *(np.sin(ang / 2) * axis / np.linalg.norm(axis))]
        st.s.p = list(rng.normal([0, 0, 1], 0.2))
        st.s.v = list(rng.normal(0, 0.5, 3))
        st.s.q = q
        st.s.w = list(rng.normal(0, 1.0, 3))
        st.sp.p = list(rng.normal([0, 0, 1], 0.1))
        st.sp.v = list(rng.normal(0, 0.3, 3))
        st.sp.a = list(rng.normal(0, 0.5, 3))
        st.sp.yaw = float(rng.uniform(-np.pi, np.pi))
        st.fa = list(rng.normal(0, 0.05, 3))
        st.dt_pos, st.dt_att, st.battery_V = 0.01, 0.002, float(rng.uniform(3.5, 4.2))
        st.flags = (1 if k % 5 == 0 else 0) | (2 if rng.uniform() < 0.2 else 0)
        if rng.uniform() < 0.02:
            st.s.w = [float("nan"), 0.0, 0.0]
        if rng.uniform() < 0.02:
            st.sp.p = [float("inf"), 0.0, 1.0]
    return steps


@pytest.mark.parametrize("kind", ["small", "large"])
def test_controller_steps_bit_exact_on_stm32(exported, cfg, kind):
    """5,000 controller steps on the emulated MCU equal the host build bit for bit."""
    from ns2host.sim.vehicle import vehicle

    cm = exported.cmodel()
    ffi, lib = cm.ffi, cm.lib
    n = 5000
    steps = _controller_steps(ffi, n, seed=12)
    ctrl = cm.controller([vehicle(cfg, kind)])
    c = ffi.addressof(ctrl, 0)
    veh, gains = bytes(ffi.buffer(ffi.addressof(c[0], "veh"))), bytes(ffi.buffer(ffi.addressof(c[0], "g")))
    host_out = ffi.new("ns2_step_out_t[]", n)
    fresh = ffi.new("ns2_ctrl_t *")
    lib.ns2_ctrl_init(fresh, ffi.addressof(c[0], "veh"), ffi.addressof(c[0], "g"))
    lib.ns2_ctrl_run_steps(fresh, steps, host_out, n)
    elf = target.build_controller_image(exported.gen_dir)
    data = target.run_controller_vectors(elf, veh, gains, bytes(ffi.buffer(steps)),
                                         ffi.sizeof("ns2_step_in_t"), ffi.sizeof("ns2_step_out_t"))
    host = bytes(ffi.buffer(host_out))
    assert data == host
    out = np.frombuffer(host, np.uint8).reshape(n, -1)[:, :40].copy().view(np.float32)
    assert np.isfinite(out).all() and (out[:, 4:8] >= 0).all() and (out[:, 4:8] <= 1).all()
    status = np.frombuffer(host, np.uint8).reshape(n, -1)[:, 40:44].copy().view(np.uint32)[:, 0]
    assert (status & 1).any() and (status & 2).any() and ((status & 3) == 0).any()
