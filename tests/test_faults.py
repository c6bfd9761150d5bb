"""Hostile input to the controller and the peer table through the host build (issue 17
D2, D3): one bad tick or sample must not leave NaN behind; a status is reported
while the controller recovers, and recovery is bounded (NS2_CTRL_RECOVERY_TICKS)."""
import math

import numpy as np
import pytest


@pytest.mark.parametrize("trigger", ["yaw", "dt_att", "w", "sp_p"])
def test_one_bad_tick_recovers_within_the_bound(small_ctl, trigger):
    ffi, lib = small_ctl.ffi, small_ctl.lib
    c, fresh = small_ctl.fresh(), small_ctl.fresh()
    st, sp = small_ctl.hover()
    bound = lib.NS2_CTRL_RECOVERY_TICKS
    flags = []
    for k in range(5 * 100):
        bad_st, bad_sp, dt_att = ffi.new("ns2_ctrl_state_t *", st[0]), ffi.new("ns2_setpoint_t *", sp[0]), 0.002
        if k == 250:  # the smallest triggers of issue 17 D2
            if trigger == "yaw":
                bad_sp.yaw = 1e12
            elif trigger == "dt_att":
                dt_att = math.inf
            elif trigger == "w":
                bad_st.w = [1e38, 0, 0]
            else:
                bad_sp.p = [1e20, 0, 1]
        if k % 5 == 0:
            lib.ns2_ctrl_position(c, bad_st, bad_sp, ffi.NULL, 0.01)
        lib.ns2_ctrl_attitude(c, bad_st, dt_att, 3.9)
        flags.append(c.status)
        assert all(0.0 <= c.pwm[i] <= 1.0 for i in range(4)) and all(math.isfinite(c.u[i]) for i in range(4))
    flags = np.array(flags)
    after = flags[251:]
    if trigger in ("yaw", "sp_p"):  # bad setpoint: kept the last valid one, no reset
        assert flags[250] & lib.NS2_CTRL_BAD_SETPOINT and not (flags[250] & lib.NS2_CTRL_BAD_STATE)
        assert list(c.sp.p) == [0, 0, 1]
        assert (after[4:] & ~lib.NS2_CTRL_SATURATED == 0).all()
    else:  # bad state: motors off, then a reported, bounded recovery
        assert flags[250] & lib.NS2_CTRL_BAD_STATE and flags[250] & lib.NS2_CTRL_RECOVERING
        recovering = np.nonzero(after & lib.NS2_CTRL_RECOVERING)[0]
        assert 0 < len(recovering) <= 5 + bound and recovering.max() < 5 + bound
        assert (after[5 + bound:] & ~lib.NS2_CTRL_SATURATED == 0).all()
    # and it flies: the outputs match a controller that never saw the glitch to 1e-4
    for k in range(5 * 200):
        if k % 5 == 0:
            lib.ns2_ctrl_position(c, st, sp, ffi.NULL, 0.01)
            lib.ns2_ctrl_position(fresh, st, sp, ffi.NULL, 0.01)
        lib.ns2_ctrl_attitude(c, st, 0.002, 3.9)
        lib.ns2_ctrl_attitude(fresh, st, 0.002, 3.9)
    assert c.status == 0 and min(c.pwm) > 0.1
    np.testing.assert_allclose(list(c.u), list(fresh.u), atol=1e-4)


def test_unusable_vehicle_parameters_keep_the_motors_off(small_ctl):
    ffi, lib = small_ctl.ffi, small_ctl.lib
    veh = ffi.new("ns2_vehicle_t *", small_ctl.ctrl[0].veh)
    veh.arm_m = 0.0  # issue 17 D4: arm_length_m = 0 made the controller output NaN at hover
    c = small_ctl.fresh(veh)
    st, sp = small_ctl.hover()
    lib.ns2_ctrl_position(c, st, sp, ffi.NULL, 0.01)
    lib.ns2_ctrl_attitude(c, st, 0.002, 3.9)
    assert c.status & lib.NS2_CTRL_BAD_CONFIG and list(c.pwm) == [0, 0, 0, 0]


def test_absurd_peer_sample_is_rejected_and_velocity_recovers(exported):
    c = exported.cmodel()
    ffi, lib = c.ffi, c.lib
    s = ffi.new("ns2_peers_t *")
    lib.ns2_peers_init(s, 0.5)
    up = lambda t, p: lib.ns2_peers_update(s, 3, 0, t, ffi.new("float[3]", p))  # noqa: E731
    assert up(1000, [0, 0, 1]) == 0
    assert up(1010, [1e37, 0, 1]) == -1  # issue 17 D3: x = 1e37 m, 10 ms later
    assert up(1020, [1.5, 0, 1]) == 1    # a 75 m/s jump: the track restarts (status), velocity unknown
    assert s.peer[0].samples == 1 and list(s.peer[0].v) == [0, 0, 0]
    for k in range(1, 101):              # 1 s of good samples at 0.5 m/s
        assert up(1020 + 10 * k, [1.5 + 0.005 * k, 0, 1]) == 0
    assert s.peer[0].v[0] == pytest.approx(0.5, abs=1e-3)
    out = ffi.new("ns2_neighbor_t[4]")
    z = ffi.new("float[3]", [0, 0, 0])
    assert lib.ns2_peers_neighbors(s, 9, z, z, 2030, 100, out, 4) == 1
    assert all(math.isfinite(x) for x in out[0].rel)
    assert up((2030 - 5000) % 2**32, [0.9, 0, 1]) == 1  # a peer whose clock went back (reboot): restarted, not stuck
