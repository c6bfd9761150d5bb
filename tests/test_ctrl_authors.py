"""The controller that flew the real flights, for their replay (paper/c/ctrl_authors.c):
ns2_ctrl_force is ns2_ctrl_position's second half bit for bit and safe on a bad force;
the authors' position law holds the steady state its equation predicts in the
simulator, with a given (logged) prediction too; their attitude gains reach the
controller."""
import math

import numpy as np
import pytest

from ns2codegen.vehicle import vehicle
from ns2host.sim.cloop import CLoopSwarm, NS2Controller, Robot, hover_setpoints, robots_of
from ns2paper.controller import AuthorsController
from ns2paper.gains import AUTHORS_GAINS, authors_gains, read_law_gains


def _bits(x) -> list[int]:
    return np.asarray(list(x), np.float32).view(np.uint32).tolist()


def _settled_z_error(log) -> float:
    """Mean p_d,z - p_z of robot 0 over the last 2 s of a flight (m)."""
    last = log["t"] > log["t"][-1] - 2.0
    return float(np.mean(log["p_d"][last, 0, 2] - log["p"][last, 0, 2]))


def test_force_is_the_second_half_of_position_bit_for_bit(small_ctl):
    """With zero position gains and no f_a, ns2_ctrl_position's desired force is
    m a_d + m g e3 (float32): given that force, ns2_ctrl_force leaves the controller
    in the same state, tick after tick, and the motors get the same commands."""
    ffi, lib = small_ctl.ffi, small_ctl.lib
    zero = {"Lp": [0.0] * 3, "Kv": [0.0] * 3, "Gv": [0.0] * 3}
    a, b = small_ctl.fresh(**zero), small_ctl.fresh(**zero)
    rng = np.random.default_rng(3)
    m, g0 = np.float32(small_ctl.ctrl[0].veh.mass_kg), np.float32(9.81)
    st, sp = ffi.new("ns2_ctrl_state_t *"), ffi.new("ns2_setpoint_t *")
    f = ffi.new("float[3]")
    for k in range(400):
        q = rng.normal(size=4) * [1, 0.1, 0.1, 0.3]
        q[0] = abs(q[0]) + 1.0
        st.p, st.v, st.w = rng.uniform(-2, 2, 3).tolist(), rng.uniform(-1, 1, 3).tolist(), rng.uniform(-3, 3, 3).tolist()
        st.q = (q / np.linalg.norm(q)).tolist()
        sp.p, sp.v, sp.a = rng.uniform(-2, 2, 3).tolist(), rng.uniform(-1, 1, 3).tolist(), rng.uniform(-3, 3, 3).tolist()
        sp.yaw = float(rng.uniform(-7, 7))
        fd = m * np.asarray(list(sp.a), np.float32)
        fd[2] = fd[2] + m * g0
        f[0:3] = fd.tolist()
        lib.ns2_ctrl_position(a, st, sp, ffi.NULL, 0.01)
        lib.ns2_ctrl_force(b, st, sp, f, 0.01)
        for _ in range(5):
            lib.ns2_ctrl_attitude(a, st, 0.002, 3.9)
            lib.ns2_ctrl_attitude(b, st, 0.002, 3.9)
        assert a.status == b.status
        assert _bits(a.R_d) == _bits(b.R_d) and _bits([a.T_d, a.T_d_dot]) == _bits([b.T_d, b.T_d_dot])
        assert _bits(a.u) == _bits(b.u) and _bits(a.pwm) == _bits(b.pwm)


@pytest.mark.parametrize("bad", [math.nan, math.inf, 1e3])
def test_a_bad_force_turns_the_motors_off_and_recovers(small_ctl, bad):
    ffi, lib = small_ctl.ffi, small_ctl.lib
    x = small_ctl.fresh()
    st, sp = small_ctl.hover()
    hover = ffi.new("float[3]", [0.0, 0.0, small_ctl.ctrl[0].veh.mass_kg * 9.81])
    lib.ns2_ctrl_force(x, st, sp, hover, 0.01)
    lib.ns2_ctrl_attitude(x, st, 0.002, 3.9)
    assert x.status == 0 and min(x.pwm) > 0.1
    lib.ns2_ctrl_force(x, st, sp, ffi.new("float[3]", [0.0, bad, 0.3]), 0.01)
    assert x.status & lib.NS2_CTRL_BAD_STATE and list(x.pwm) == [0, 0, 0, 0]
    for k in range(5 * 40):
        if k % 5 == 0:
            lib.ns2_ctrl_force(x, st, sp, hover, 0.01)
        lib.ns2_ctrl_attitude(x, st, 0.002, 3.9)
    assert x.status == 0 and min(x.pwm) > 0.1 and all(math.isfinite(v) for v in x.u)


def test_authors_gains_by_robot():
    assert authors_gains("small") is AUTHORS_GAINS["CF21SingleMarker"]
    assert authors_gains("large", "cf101") is AUTHORS_GAINS["parrotFrameCF21SingleMarker"]
    assert authors_gains("large", "cf100")["kp"][2] == 30.0   # the Crazyflie 2.0 flew stiffer gains
    with pytest.raises(ValueError, match="authors' controller gains"):
        authors_gains("medium")


def test_read_law_gains_replace_the_z_axis_only():
    """The z law read off the logs (READ_LAW's form) replaces the authors' z gains, k_fa
    and mass parameter; x, y and the attitude gains stay the type's."""
    law = {"small": {"kp": 7.0, "kd": 2.5, "ki": 0.3, "k_fa": 0.6, "mass_kg": 0.031}}
    g, a = read_law_gains("small", law), authors_gains("small")
    assert g["kp"] == [*a["kp"][:2], 7.0] and g["kd"] == [*a["kd"][:2], 2.5] and g["ki"] == [*a["ki"][:2], 0.3]
    assert g["k_fa"] == 0.6 and g["mass_kg"] == 0.031 and g["att"] == a["att"] and g["i_max"] == a["i_max"]
    assert a["kp"][2] == 10.0 and "k_fa" not in a                 # the stored gains are untouched
    assert set(read_law_gains("large")) >= {"kp", "kd", "ki", "k_fa", "mass_kg"}       # READ_LAW by default
    with pytest.raises(KeyError):
        read_law_gains("large", law)


def test_authors_law_holds_the_steady_state_of_its_equation(cfg, exported):
    """Without the integral the law settles where the thrust k m_p (g + kp e) equals
    m g: e = (m / (k m_p) - 1) g / kp (e = p_d - p).  k, the plant's thrust per thrust
    commanded (the Table cfprops maps psi_1 and psi_2 are fits, not exact inverses),
    comes from a first run with m_p = m; it then predicts the offsets of a mass
    parameter 10 % low at two stiffnesses.  The integral (ki 3) takes the offset away."""
    m = vehicle(cfg, "small").mass
    p0 = [[0.0, 0.0, 1.0]]

    def z_error(seconds, **law):
        gains = dict(authors_gains("small"), **law)
        sw = CLoopSwarm(cfg, robots_of(["small"], p0, AuthorsController(gains)), exported.gen_dir, seed=1)
        return _settled_z_error(sw.run(seconds, hover_setpoints(p0), settle_s=0.5))

    no_i = {"ki": [0.0] * 3}
    e1 = z_error(6.0, mass_kg=m, **no_i)
    k = 1.0 / (1.0 + e1 * 10.0 / 9.81)
    assert 0.9 < k < 1.1
    for kp in (10.0, 20.0):
        e_pred = (1.0 / (k * 0.9) - 1.0) * 9.81 / kp
        assert z_error(6.0, mass_kg=0.9 * m, kp=[20.0, 20.0, kp], **no_i) == pytest.approx(e_pred, abs=0.003)
    assert abs(z_error(16.0, mass_kg=0.9 * m)) < 0.005


@pytest.mark.parametrize("robot_type", ["small", "large"])
def test_the_authors_motor_map_realizes_the_force_commanded(cfg, exported, monkeypatch, robot_type):
    """The firmware that flew the real flights turns its motor forces into PWM through the
    exact inverse of psi_1 (gains.AUTHORS_PWM_EXACT, host/ns2_fly.c): a law without
    integral whose mass parameter is the robot's own hovers on its setpoint (thrust
    realized per thrust commanded k = 1 within 0.3 %), and every logged PWM gives through
    psi_1 the hover thrust; through psi_2 (the project's firmware) k is Table cfprops'
    mismatch (large: about 0.92, small about 1.05)."""
    import ns2paper.controller as authors
    from ns2codegen.data.labels import psi1_newtons, quat_to_R

    veh = vehicle(cfg, robot_type)
    p0 = [[0.0, 0.0, 1.0]]
    gains = dict(authors_gains(robot_type), mass_kg=veh.mass, ki=[0.0] * 3)

    def hover():
        sw = CLoopSwarm(cfg, robots_of([robot_type], p0, AuthorsController(gains)), exported.gen_dir, seed=1)
        return sw.run(6.0, hover_setpoints(p0), settle_s=0.5)

    log = hover()
    k = 1.0 / (1.0 + _settled_z_error(log) * 10.0 / 9.81)
    assert k == pytest.approx(1.0, abs=0.003)
    last = log["t"] > log["t"][-1] - 2.0
    thrust = (psi1_newtons(veh.psi1, log["pwm"][last, 0], log["battery_V"][last, 0]).sum(-1)
              * quat_to_R(log["q"][last, 0])[:, 2, 2])
    assert thrust.mean() == pytest.approx(veh.mass * 9.81, rel=0.005)
    monkeypatch.setattr(authors, "AUTHORS_PWM_EXACT", False)
    k2 = 1.0 / (1.0 + _settled_z_error(hover()) * 10.0 / 9.81)
    assert abs(k2 - 1.0) > 0.03


def test_a_given_prediction_is_flown_as_the_law_says(cfg, exported):
    """AuthorsController's given prediction (a real flight's logged one, ns2paper.replay): a given 0 g flies
    bit for bit as no learned force; a given c g is subtracted from the law's force, so
    without the integral the robot settles where k (m (g + kp e) - k_fa c g0) = m g (k
    from the 0 g run, as above), below the setpoint, for k_fa 1 (the law as written) and
    0.5 (the law read off the real logs takes off part of the prediction); the log
    records what was flown; a step in the given signal is read at the next position tick."""
    m = vehicle(cfg, "small").mass
    p0 = [[0.0, 0.0, 1.0]]
    gains = dict(authors_gains("small"), mass_kg=m, ki=[0.0] * 3)

    def fly(fa_given, seconds=6.0, k_fa=1.0):
        ctrl = AuthorsController(dict(gains, k_fa=k_fa), given=fa_given)
        sw = CLoopSwarm(cfg, robots_of(["small"], p0, ctrl), exported.gen_dir, seed=1)
        return sw.run(seconds, hover_setpoints(p0), settle_s=0.5)

    none, zero = fly(None), fly(lambda t: 0.0)
    assert np.array_equal(none["p"], zero["p"]) and np.array_equal(none["pwm"], zero["pwm"])
    k = 1.0 / (1.0 + _settled_z_error(zero) * 10.0 / 9.81)
    c = 3.0
    given = fly(lambda t: c)
    e_pred = (m * 9.81 / k - m * 9.81 + c * 1e-3 * 9.81) / (m * 10.0)
    assert e_pred > 0.03 and _settled_z_error(given) == pytest.approx(e_pred, abs=0.004)
    e_half = (m * 9.81 / k - m * 9.81 + 0.5 * c * 1e-3 * 9.81) / (m * 10.0)
    assert _settled_z_error(fly(lambda t: c, k_fa=0.5)) == pytest.approx(e_half, abs=0.004)
    assert e_pred - e_half > 0.03
    assert np.allclose(given["fa_hat"][:, 0, 2], c * 1e-3 * 9.81, rtol=1e-6)
    step = fly(lambda t: c if t >= 1.0 else 0.0, 2.0)["fa_hat"][:, 0, 2]
    t = np.arange(len(step)) / 100.0
    assert np.all(step[t < 0.995] == 0.0) and np.allclose(step[t > 1.005], c * 1e-3 * 9.81, rtol=1e-6)
    with pytest.raises(ValueError, match="controller"):   # a controller by name, not an object
        CLoopSwarm(cfg, [Robot("small", p0[0], "authors")], exported.gen_dir)


def test_the_authors_attitude_gains_reach_the_controller_and_it_hovers(cfg, exported):
    """An "authors" robot flies its attitude gains as the project's attitude law
    (gains.AUTHORS_GAINS "att"); an "ns2" robot beside it keeps the defaults; a robot's
    own gains still override; with them the small robot hovers level on its spot."""
    from ns2codegen.vehicle import default_gains

    p0 = [[0.0, 0.0, 1.0], [1.5, 0.0, 1.0]]
    sw = CLoopSwarm(cfg, robots_of(["small", "large"], p0, [AuthorsController(), NS2Controller()]), exported.gen_dir,
                    seed=2)
    att = AUTHORS_GAINS["CF21SingleMarker"]["att"]
    g0, g1 = sw.robots[0].pilot.ctrl.g, sw.robots[1].pilot.ctrl.g
    for k in ("Lq", "Kw", "Gw", "Kwd"):
        assert list(getattr(g0, k)) == pytest.approx(att[k], rel=1e-6)
        assert list(getattr(g1, k)) == pytest.approx(default_gains(vehicle(cfg, "large"))[k], rel=1e-6)
    assert g0.int_w_max == pytest.approx(att["int_w_max"])
    log = sw.run(4.0, hover_setpoints(p0), settle_s=1.0)
    assert np.abs(log["truth_p"][:, 0, :2] - log["p_d"][:, 0, :2]).max() < 0.01   # level, on its spot
    own = CLoopSwarm(cfg, robots_of(["small"], p0[:1], AuthorsController(), gains=[{"Kw": [1e-3] * 3}]),
                     exported.gen_dir)
    assert list(own.robots[0].pilot.ctrl.g.Kw) == pytest.approx([1e-3] * 3)
    assert list(own.robots[0].pilot.ctrl.g.Lq) == pytest.approx(att["Lq"])
