"""The simulated Crazyflie (host/ns2_fly.c): the drone's code path ns2_pilot equals a
direct replay of the library calls in the app's order, the firmware's EKF is what the
controllers see, and the firmware's Mellinger controller flies."""
import os

import numpy as np
import pytest

from ns2codegen.vehicle import G
from ns2host.crazyflie import have_firmware
from ns2host.sim.cloop import CLoopSwarm, MellingerController, NS2Controller, hover_setpoints, robots_of
from ns2host.sim.scenarios import swap
from ns2host.sim.sensing import Sensing

pytestmark = pytest.mark.skipif(not have_firmware() and os.environ.get("CI") != "true",
                                reason="crazyflie-firmware missing")


def f32(x) -> float:
    return float(np.float32(x))


def replay(sw: CLoopSwarm, trace, n: int, i: int = 0):
    """The app's per-tick calls (firmware/app/src/ns2_app.c, controllerOutOfTree and
    predict_period), made one by one on fresh library state from the recorded inputs."""
    ffi, lib = sw.ffi, sw.lib
    r = sw.robots[i]
    cfg = r.pilot.cfg
    ctrl, peers, job = ffi.new("ns2_ctrl_t *"), ffi.new("ns2_peers_t *"), ffi.new("ns2_job_t *")
    lib.ns2_ctrl_init(ctrl, ffi.addressof(r.pilot.ctrl, "veh"), ffi.addressof(r.pilot, "gains"))
    lib.ns2_peers_init(peers, 0.5)
    nbrs = ffi.new("ns2_neighbor_t[]", lib.NS2_PEERS_MAX)
    info = ffi.new("ns2_info_t *")
    fa_hat, begun, out = 0.0, False, []
    lim = f32(cfg.fa_limit_g)
    for k in range(n):
        t = trace[k]
        if t.do_pos:
            if begun:
                f = f32(lib.ns2_job_finish_q15(job, info) * 2.0 ** -lib.NS2_Q_OUT_FRAC) if cfg.fixed \
                    else lib.ns2_job_finish_f32(job, info)
                fa_hat = lim if f > lim else (-lim if f < -lim else f)
            for j in range(t.n_peers):
                lib.ns2_peers_update(peers, t.peer_id[j], t.peer_type[j], t.peer_t[j], t.peer_p[j])
            m = lib.ns2_peers_neighbors(peers, i + 1, t.s.p, t.s.v, t.now_ms, cfg.max_age_ms, nbrs, lib.NS2_PEERS_MAX)
            lib.ns2_job_begin(job, cfg.self_type, t.s.p, t.s.v, nbrs, m)
            begun = True
            fz = f32(f32(f32(fa_hat) * f32(1e-3)) * f32(G)) if cfg.enable else 0.0
            lib.ns2_ctrl_position(ctrl, ffi.addressof(t, "s"), ffi.addressof(t, "sp"), [0.0, 0.0, fz],
                                  f32(np.float32(1) / np.float32(100)))
        if cfg.fixed:
            lib.ns2_job_step_q15(job, cfg.phi_per_tick)
        else:
            lib.ns2_job_step_f32(job, cfg.phi_per_tick)
        lib.ns2_ctrl_attitude(ctrl, ffi.addressof(t, "s"), f32(np.float32(1) / np.float32(500)), t.battery_V)
        out.append((list(ctrl.pwm), fa_hat))
    return out


@pytest.mark.parametrize("learned", ["fixed", "float"])
def test_pilot_in_the_loop_equals_direct_replay(cfg, exported, learned):
    """Bit for bit, every 500 Hz tick of a 3-robot swap with interactions, sensing and
    losses: the PWM and f_a of ns2_pilot in the simulator are those of the app's calls
    replayed on the recorded inputs (estimated state, setpoint, peer samples, clock)."""
    types = ["small", "large", "small"]
    sp, start = swap(3, [0.5, 0.8, 1.1], radius=0.4, duration=2.5, rest=0.5, seed=0)
    sw = CLoopSwarm(cfg, robots_of(types, start, NS2Controller(learned)), exported.gen_dir, aero=True, seed=3)
    log = sw.run(3.0, sp, trace_robot=0, settle_s=0.5)
    trace, n = log["trace"]
    assert n == int(3.5 * 500)
    assert sum(trace[k].n_peers for k in range(n)) > 100  # peers were fed (2 per received frame)
    got = replay(sw, trace, n)
    pwm_sim = np.array([list(trace[k].pwm) for k in range(n)], np.float32)
    fa_sim = np.array([trace[k].fa_hat_g for k in range(n)], np.float32)
    pwm_rep = np.array([p for p, _ in got], np.float32)
    fa_rep = np.array([f for _, f in got], np.float32)
    assert np.abs(fa_sim).max() > 1.0  # the learned force was in use
    assert pwm_sim.tobytes() == pwm_rep.tobytes()
    assert fa_sim.tobytes() == fa_rep.tobytes()


def test_controllers_see_the_estimate_not_the_truth(cfg, exported):
    """Hover: the EKF estimate (the drone's log) tracks the true position within
    millimetres but is not it; without mocap (every frame lost) it drifts."""
    p0 = [[0.0, 0.0, 1.0]]
    log = CLoopSwarm(cfg, robots_of(["small"], p0), exported.gen_dir, seed=1).run(3.0, hover_setpoints(p0))
    d = np.abs(log["p"] - log["truth_p"])
    assert 1e-5 < d.max() < 0.01, d.max()
    assert np.abs(log["truth_p"][:, 0, 2] - 1.0).max() < 0.01
    blind = CLoopSwarm(cfg, robots_of(["small"], p0), exported.gen_dir, seed=1, sensing=Sensing(loss=1.0))
    lb = blind.run(3.0, hover_setpoints(p0), settle_s=0.0)
    assert np.abs(lb["p"] - lb["truth_p"]).max() > 5 * d.max()


def test_firmware_mellinger_flies(cfg, exported):
    """The firmware's Mellinger controller (default gains, thrust through the firmware's
    power distribution and battery compensation) hovers the small robot."""
    p0 = [[0.0, 0.0, 1.0]]
    sw = CLoopSwarm(cfg, robots_of(["small"], p0, MellingerController()), exported.gen_dir)
    log = sw.run(4.0, hover_setpoints(p0))
    late = log["t"] > 2.0
    assert np.abs(log["truth_p"][late, 0] - p0[0]).max() < 0.03
    assert 0.2 < log["pwm"][late].mean() < 0.95


def test_mellinger_battery_compensation_is_the_stock_firmwares(exported):
    """The Mellinger robots compensate the battery as the stock firmware does
    (CONFIG_ENABLE_THRUST_BAT_COMPENSATED on in cf2_defconfig), although every other
    firmware file of the kernel has the app's configuration, which turns it off (psi_2
    compensates; there the function returns its input): motor voltage / supply voltage,
    so the command scales as 1 / supply voltage.  Built with the app's configuration
    (the kernel from 3c354c8 on) the Mellinger swap errors fell 3x (L2S 5.9 -> 2.0 cm)."""
    from ns2host import cfapp
    from ns2host.cfhost import load_fly

    assert cfapp.kconfig(cfapp.stock_config())["CONFIG_ENABLE_THRUST_BAT_COMPENSATED"] == "y"
    assert cfapp.kconfig(cfapp.app_config())["CONFIG_ENABLE_THRUST_BAT_COMPENSATED"] == "n"
    _, lib = load_fly(exported.gen_dir)
    for cmd in (20000.0, 35000.0, 50000.0):
        full, low = (lib.motorsCompensateBatteryVoltage(0, cmd, v) for v in (4.2, 3.6))
        assert low > 1.1 * full                        # a low battery gets a higher command,
        assert low * 3.6 == pytest.approx(full * 4.2, rel=1e-5)  # as 1 / supply voltage
    assert lib.motorsCompensateBatteryVoltage(0, 35000.0, 1.5) == 0.0  # the firmware's damaged-battery guard


def test_swap_results_rows(cfg, exported, tmp_path, monkeypatch):
    """swaps.json: a row per case and controller with the metrics; the gain search is
    written once and reused; BL-tuned is the admissible candidate with the lowest objective."""
    import json

    from ns2exp import swarm

    monkeypatch.setattr(swarm, "GAIN_GRID_Z", {"Lp_z": (2.5, 5.0), "Kv_z": (4.0, 8.0)})
    monkeypatch.setattr(swarm, "GAIN_GRID_XY", {"Lp_xy": (2.0,), "Kv_xy": (4.0,)})
    monkeypatch.setattr(swarm, "heat_maps", lambda *a: None)
    res = swarm.swap_experiments(cfg, exported.gen_dir, tmp_path, swaps=1, cases=["L2S"], tune_swaps=2)
    rows = json.loads((tmp_path / "swaps.json").read_text())["rows"]
    assert [r["controller"] for r in rows] == list(swarm.CONTROLLERS) and rows == res["rows"]
    for r in rows:
        assert 0 < r["median_worst_z_error_m"] <= r["max_worst_z_error_m"] < 0.5
        assert 0 < r["z_error_rms_m"] <= r["max_worst_z_error_m"] and 0 < r["motor_cmd_rms"] < 0.1
    search = json.loads((tmp_path / "gain_search.json").read_text())
    assert search["key"] == swarm._search_key(2, None)          # the search the test asked for
    ok = [c for c in search["candidates"] if c["admissible"]]
    best = min(ok, key=lambda c: c["median_worst_z_error_m"])
    assert {k: best[k] for k in swarm.DEFAULT_TUNING} == search["tuning"] == res["tuning"]
    by = {r["controller"]: r for r in rows}
    assert by["BL-tuned"]["median_worst_z_error_m"] <= by["BL"]["median_worst_z_error_m"]
    assert "| L2S |" in (tmp_path / "swaps.md").read_text()
    # the rings reuse that search (same key: no new one) and fly BL-tuned with its tuning
    monkeypatch.setattr(swarm, "RING_CASES", {"5-robot rings": 5})
    before = (tmp_path / "gain_search.json").read_text()
    rings = swarm.ring_experiments(cfg, exported.gen_dir, tmp_path, duration=3.0, controllers=("BL-tuned",),
                                   tune_swaps=2)
    assert (tmp_path / "gain_search.json").read_text() == before and rings["tuning"] == search["tuning"]
    assert rings["rows"] and all(r["controller"] == "BL-tuned" and 0 < r["max_worst_z_error_m"] < 0.5
                                 for r in rings["rows"])


@pytest.mark.parametrize("fixed", [1, 0])
@pytest.mark.parametrize("phi_per_tick", [1, 3, 4, 5, 16])
def test_pilot_step_spreads_the_tick_without_changing_it(exported, fixed, phi_per_tick):
    """The app's 1 kHz schedule (ns2_pilot_step: begin + position, half slices, finish
    in the millisecond before the position tick) gives, at every 500 Hz tick, the motor
    commands, f_a and neighbour count of ns2_pilot_tick, bit for bit: 16 peers of both
    types moving and reported at random milliseconds (17 phi: some left for the
    finish), random states, a stretch on the ground."""
    from ns2host.cbuild import fill_gains, fill_vehicle
    from ns2host.cfhost import load_fly
    from ns2host.sim.vehicle import default_gains, vehicle

    ffi, lib = load_fly(exported.gen_dir)
    veh, gains, pcfg = ffi.new("ns2_vehicle_t *"), ffi.new("ns2_gains_t *"), ffi.new("ns2_pilot_cfg_t *")
    v = vehicle(exported.cfg, exported.cfg.robot_types[0])
    fill_vehicle(veh[0], v)
    fill_gains(gains[0], default_gains(v))
    lib.ns2_pilot_default_cfg(pcfg, 0)
    pcfg.fixed, pcfg.phi_per_tick = fixed, phi_per_tick
    a, b = ffi.new("ns2_pilot_t *"), ffi.new("ns2_pilot_t *")
    for pl in (a, b):
        lib.ns2_pilot_init(pl, pcfg, veh, gains)
    s, sp = ffi.new("ns2_ctrl_state_t *"), ffi.new("ns2_setpoint_t *")
    rng = np.random.default_rng(phi_per_tick + 10 * fixed)
    ang = 2 * np.pi * np.arange(16) / 16
    used, fa = [], []
    for k in range(400):
        for j in rng.choice(16, 3, replace=False):  # three peer positions per millisecond
            p = [f32(0.3 * np.cos(ang[j] + 1e-3 * k)), f32(0.3 * np.sin(ang[j])), f32(1.2 + 0.01 * (j % 3))]
            for pl in (a, b):
                lib.ns2_pilot_peer(pl, int(j) + 2, int(j % 2), k, p)
        if 200 <= k < 230:  # on the ground: the app resets and skips the pilot
            for pl in (a, b):
                lib.ns2_pilot_reset(pl, veh)
            continue
        s.p = rng.normal([0, 0, 1.0], 0.02).tolist()
        s.v, s.w = rng.normal(0, 0.05, 3).tolist(), rng.normal(0, 0.2, 3).tolist()
        q = rng.normal([1, 0, 0, 0], 0.02)
        s.q = (q / np.linalg.norm(q)).tolist()
        sp.p = [0.0, 0.0, 1.0]
        lib.ns2_pilot_step(a, s, sp, k, 1, k, 3.9)
        if k % 2 == 0:
            lib.ns2_pilot_tick(b, s, sp, int(k % 10 == 0), 1, k, 3.9)
            assert bytes(ffi.buffer(a.ctrl.pwm)) == bytes(ffi.buffer(b.ctrl.pwm)), k
            assert (a.fa_hat_g, a.n_used, a.status) == (b.fa_hat_g, b.n_used, b.status), k
            used.append(a.n_used)
            fa.append(a.fa_hat_g)
    assert max(used) == 16 and np.count_nonzero(fa) > 100  # all 16 peers used, the learned term in use
