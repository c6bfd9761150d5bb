"""Simulator physics and the firmware controller in the loop (interactions off)."""
import hashlib
import math

import numpy as np
import pytest

from ns2host.sim.cloop import CLoopSwarm, MellingerController, Robot, figure_eight, hover_setpoints, robots_of
from ns2host.sim.collect import CRASH_MARGIN_S, crash_cut
from ns2host.sim.dynamics import Dynamics, SwarmState
from ns2host.sim.vehicle import G, vehicle
from ns2paper.controller import AuthorsController


@pytest.fixture(scope="module")
def vehicles(cfg):
    return [vehicle(cfg, "small"), vehicle(cfg, "large")]


def test_hover_equilibrium(vehicles):
    dyn = Dynamics(vehicles)
    st = SwarmState.hover([[0, 0, 1], [1, 0, 2]], vehicles)
    u_c = st.u.copy()
    for _ in range(1000):
        st = dyn.step(st, u_c, 0.002)
    assert np.abs(st.p - [[0, 0, 1], [1, 0, 2]]).max() < 1e-9
    assert np.abs(st.v).max() < 1e-9 and np.abs(st.w).max() < 1e-9


def test_free_fall(vehicles):
    dyn = Dynamics(vehicles)
    st = SwarmState.hover([[0, 0, 10], [0, 0, 10]], vehicles)
    st.u[:] = 0.0
    for _ in range(500):
        st = dyn.step(st, np.zeros((2, 4)), 0.002)
    assert st.p[:, 2] == pytest.approx(10 - 0.5 * G * 1.0 ** 2, abs=1e-9)
    assert st.v[:, 2] == pytest.approx(-G, abs=1e-9)


def test_pure_yaw_torque_spins_about_z(vehicles):
    small = vehicles[0]
    dyn = Dynamics([small])
    st = SwarmState.hover([[0, 0, 1]], [small])
    d = 0.002  # N: motors 2 and 4 up, 1 and 3 down -> +tau_z, no net thrust change
    u = st.u + np.array([[-d, d, -d, d]])
    st.u = u.copy()
    tau_z = 4 * d * small.kappa
    for _ in range(50):
        st = dyn.step(st, u, 0.002)
    assert st.w[0, 2] == pytest.approx(tau_z / small.inertia[2] * 0.1, rel=1e-6)
    assert abs(st.w[0, 0]) < 1e-9 and abs(st.w[0, 1]) < 1e-9
    assert np.abs(st.p[0] - [0, 0, 1]).max() < 1e-9  # thrust unchanged: no translation


def test_firmware_mixer_matches_simulator_B0(exported, vehicles):
    ffi, lib = exported.cmodel().ffi, exported.cmodel().lib
    rng = np.random.default_rng(0)
    for veh in vehicles:
        v = ffi.new("ns2_vehicle_t *")
        v.arm_m, v.kappa_m = veh.arm, veh.kappa
        for _ in range(10):
            u = rng.uniform(0, 0.2, 4)
            eta = ffi.new("float[4]")
            lib.ns2_ctrl_wrench(v, list(u), eta)
            np.testing.assert_allclose(list(eta), veh.B0 @ u, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("kind", ["small", "large"])
def test_controller_tracks_a_figure_eight(cfg, exported, kind):
    """Interactions off: after a 6 s transient the C controller keeps the robot
    within 5 cm of a 1 m x 0.5 m figure-eight flown in 6 s (peak speed 0.7 m/s)."""
    sw = CLoopSwarm(cfg, robots_of([kind], [[0, 0, 1.0]]), exported.gen_dir)
    log = sw.run(12.0, figure_eight([0, 0, 1.0]))
    err = np.linalg.norm(log["truth_p"][:, 0] - log["p_d"][:, 0], axis=1)
    assert err[log["t"] > 6.0].max() < 0.05, err.max()
    assert (log["status"] & 1).sum() == 0  # never a bad state


def test_controller_safety(cfg, exported):
    cm = exported.cmodel()
    ffi, lib = cm.ffi, cm.lib
    ctrl = cm.controller([vehicle(cfg, "small")])
    c = ffi.addressof(ctrl, 0)
    st, sp = ffi.new("ns2_ctrl_state_t *"), ffi.new("ns2_setpoint_t *")
    st.q = [1, 0, 0, 0]
    st.p = [0, 0, 1]
    sp.p = [0, 0, 1]
    lib.ns2_ctrl_position(c, st, sp, ffi.NULL, 0.01)
    lib.ns2_ctrl_attitude(c, st, 0.002, 3.9)
    assert c.status == 0 and min(c.pwm) > 0.1
    sp.p = [math.nan, 0, 1]  # bad setpoint: the last valid one is kept
    lib.ns2_ctrl_position(c, st, sp, ffi.NULL, 0.01)
    assert c.status & 2 and list(c.sp.p) == [0, 0, 1]
    big = ffi.new("float[3]", [0, 0, 10.0])  # learned force far beyond fa_max: limited
    lib.ns2_ctrl_position(c, st, ffi.NULL, big, 0.01)
    assert c.status & 4
    st.w = [math.inf, 0, 0]  # bad state: motors off
    lib.ns2_ctrl_position(c, st, sp, ffi.NULL, 0.01)
    lib.ns2_ctrl_attitude(c, st, 0.002, 3.9)
    assert c.status & 1 and list(c.pwm) == [0, 0, 0, 0] and list(c.u) == [0, 0, 0, 0]
    for i in range(4):
        assert 0.0 <= c.pwm[i] <= 1.0


def test_mixing_capped_as_the_firmware(cfg, exported):
    """Thrust and torque demand beyond the motors: as the firmware's
    powerDistributionCap, every motor is lowered by the excess of the highest one,
    so the differences between motors (the torques) are those of the uncapped
    command and the top motor sits at f_max (thrust priority would scale them)."""
    cm = exported.cmodel()
    ffi, lib = cm.ffi, cm.lib
    veh = vehicle(cfg, "small")
    us, status = [], []
    for f_max in (veh.f_max, 1e3):  # the real motors, and motors that never cap
        ctrl = cm.controller([veh])
        c = ffi.addressof(ctrl, 0)
        c.veh.f_max_N = f_max
        st, sp = ffi.new("ns2_ctrl_state_t *"), ffi.new("ns2_setpoint_t *")
        st.q, st.p, st.w = [1, 0, 0, 0], [0, 0, 1], [1.5, -1.0, 0.3]  # rotating
        sp.p = [0, 0, 3.0]  # 2 m below the setpoint: full thrust asked
        lib.ns2_ctrl_position(c, st, sp, ffi.NULL, 0.01)
        lib.ns2_ctrl_attitude(c, st, 0.002, 4.0)
        us.append(np.array(list(c.u)))
        status.append(c.status)
    capped, free = us
    assert status == [lib.NS2_CTRL_SATURATED, 0] and free.max() > veh.f_max  # beyond the motors
    assert capped.max() == pytest.approx(veh.f_max, rel=1e-6) and capped.min() > 0
    np.testing.assert_allclose(capped - capped.mean(), free - free.mean(), rtol=0, atol=1e-6)


# sha256 (first 16 hex digits) of the logs of three 1 s figure-eight flights of one robot,
# made at commit 7e89027 (before issue 55 item 5 split ns2_fly_run into its tasks and gave
# CLoopSwarm controller objects and per-robot specs) through the constructor of that commit
# (controllers=, fa_given=, battery_given=, battery_V=); a lone robot without the learned term
# flies the same whatever network the export holds (checked with two trainings).
GOLDEN = {"ns2": "5d23b8b28fe798f0", "authors": "5a08fc85c3048918", "mellinger": "88fe8582ad890950"}
GOLDEN_FIELDS = ("p", "v", "q", "w", "pwm", "battery_V", "truth_p", "truth_v", "p_d", "fa_hat")


def test_the_simulator_flies_bit_for_bit_as_before_its_refactor(cfg, exported):
    """Every controller kind (with a given prediction and a supply voltage of its own for
    the authors' one, a nominal voltage for Mellinger's) logs the same flight, bit for
    bit, as the simulator before its refactor (GOLDEN)."""
    p0 = (0.0, 0.0, 1.0)
    swarms = {"ns2": CLoopSwarm(cfg, [Robot("small", p0)], exported.gen_dir, seed=5),
              "authors": CLoopSwarm(cfg, [Robot("large", p0, AuthorsController(given=lambda t: 2.0 * np.sin(3 * t)),
                                                battery=lambda t: 3.8 - 0.2 * t)], exported.gen_dir, seed=6),
              "mellinger": CLoopSwarm(cfg, [Robot("small", p0, MellingerController(), battery=3.7)],
                                      exported.gen_dir, seed=7)}
    got = {}
    for kind, sw in swarms.items():
        log = sw.run(1.0, figure_eight(p0, period=3.0), settle_s=0.5)
        h = hashlib.sha256()
        for k in GOLDEN_FIELDS:
            h.update(k.encode() + np.ascontiguousarray(log[k], np.float64).tobytes())
        got[kind] = h.hexdigest()[:16]
    assert got == GOLDEN


def test_crash_cuts_the_log():
    """A robot below the floor (a crash: the simulator has no floor contact) ends the
    usable log CRASH_MARGIN_S before it; a flight without one is kept whole."""
    t = np.arange(0.0, 10.0, 0.01)
    p = np.ones((t.size, 2, 3))
    assert crash_cut(t, p) == t.size
    p[700:, 1, 2] = -0.01  # robot 1 through the floor at t = 7 s
    assert crash_cut(t, p) == np.searchsorted(t, 7.0 - CRASH_MARGIN_S)


def test_hover_holds(cfg, exported):
    sw = CLoopSwarm(cfg, robots_of(["small", "large"], [[0, 0, 1.0], [1.0, 0, 1.0]]), exported.gen_dir)
    log = sw.run(4.0, hover_setpoints([[0, 0, 1.0], [1.0, 0, 1.0]]))
    late = log["t"] > 2.0
    assert np.abs(log["truth_p"][late] - log["p_d"][late]).max() < 0.03


@pytest.mark.parametrize("robots", [5, 16])
def test_paper_ring_geometry(robots):
    """The rings as the authors flew them (their 16-robot trajectory files): a horizontal
    ellipse 0.5 x 0.3 m and vertical circles of 0.3 m in the xz plane centred on its x
    vertices, all at 0.7 m; one lap per 5 s from rest to rest over 10 s (696 deg); the
    horizontal robots pass 0.25-0.3 m over and under the vertical rings' robots."""
    from ns2host.sim.scenarios import intertwined_rings, ring_angle

    types, sp, start, vertical = intertwined_rings(robots)
    counts = {t: types.count(t) for t in set(types)}
    assert counts == ({"large": 2, "small*": 3} if robots == 5 else {"large": 2, "small*": 9, "small": 5})
    assert len(vertical) == (3 if robots == 5 else 10) and "large" not in {types[k] for k in vertical}
    assert np.degrees(ring_angle(10.0)[0]) == pytest.approx(696.0, abs=1.0)
    for t in (0.0, 10.0, 11.0):                                  # from rest to rest
        assert np.abs(sp(t).v).max() < 1e-12 and np.abs(sp(t).a).max() < 1e-9
    ts = np.arange(0.0, 10.0, 0.01)
    P = np.stack([sp(t).p for t in ts])                          # [T, N, 3]
    assert np.allclose(P[0], start)
    cruise = (ts > 1.0) & (ts < 4.0)                             # one lap per 5 s
    assert np.allclose(P[cruise], np.stack([sp(t + 5.0).p for t in ts[cruise]]), atol=1e-9)
    horizontal = [k for k in range(robots) if k not in vertical]
    H = P[:, horizontal]
    a, b = (0.5, 0.5) if robots == 5 else (0.5, 0.3)
    assert np.allclose(H[..., 2], 0.7) and np.allclose((H[..., 0] / a) ** 2 + (H[..., 1] / b) ** 2, 1.0)
    V = P[:, vertical]
    assert np.allclose(V[..., 1], 0.0)
    assert np.allclose(np.hypot(np.abs(V[..., 0]) - 0.5, V[..., 2] - 0.7), 0.3)
    # the numerical derivatives are the setpoints' velocity and acceleration
    k = 300
    assert np.allclose((P[k + 1] - P[k - 1]) / 0.02, sp(ts[k]).v, atol=1e-3)
    assert np.allclose((P[k + 1] - 2 * P[k] + P[k - 1]) / 1e-4, sp(ts[k]).a, atol=1e-2)
    d = np.linalg.norm(P[:, :, None] - P[:, None], axis=3) + 9 * np.eye(robots)
    assert d.min() > 0.25
    # a large robot passes right above an S* (within 10 cm sideways, 0.25-0.3 m above)
    L = [k for k in range(robots) if types[k] == "large"]
    S = [k for k in vertical if types[k] == "small*"]
    PL, PV = P[:, L][:, :, None], P[:, S][:, None]
    dxy = np.linalg.norm(PL[..., :2] - PV[..., :2], axis=3)
    dz = PL[..., 2] - PV[..., 2]
    assert ((dxy < 0.1) & (dz > 0.25) & (dz < 0.3)).any()
    with pytest.raises(ValueError, match="5 or 16"):
        intertwined_rings(7)
