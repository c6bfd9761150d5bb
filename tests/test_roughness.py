"""The rough simulator (issue 23): each effect of host/sim/roughness.py switchable and
doing only its part, the statistics of paper/flightstats.py (the same code on real
and simulated flights), the fit's arithmetic, and the replay of a real swap."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import REAL_DATA, needs, real_logs
from ns2codegen.data.labels import psi1_newtons
from ns2codegen.logs.align import logs_to_flights
from ns2paper.collection import COLLECTION
from ns2exp.calibrate import _quadrature, lateral_k_xy, thrust_sd
from ns2paper import flightstats as fs
from ns2host.sim.aero import K_XY
from ns2host.sim.cloop import CLoopSwarm, hover_setpoints, robots_of
from ns2paper.replay import logged_battery, logged_prediction, logged_setpoints, pieces_by_flight, replay
from ns2host.sim import collect as collect_mod
from ns2host.sim.roughness import EFFECTS, LOW_BATTERY_V, Roughness, Turbulence, hp_share
from ns2host.sim.scenarios import swap

SWAPS = "neural-swarm-2020-06-16-swaps.tar.xz"
SL = [f"{COLLECTION}/swap_sl/cf51_03", f"{COLLECTION}/swap_sl/cf101_03"]


def _fly(cfg, exported, rough, seconds=1.0, seed=4):
    sp, start = swap(2, [0.5, 0.8], radius=0.3, duration=1.0, rest=0.2, seed=seed)
    sw = CLoopSwarm(cfg, robots_of(["small", "large"], start), exported.gen_dir, aero=True, seed=seed, rough=rough)
    return sw, sw.run(seconds, sp, settle_s=0.2)


def test_every_effect_off_is_the_clean_simulator_bit_for_bit(cfg, exported):
    _, clean = _fly(cfg, exported, None)
    _, off = _fly(cfg, exported, Roughness().only())
    _, rough = _fly(cfg, exported, Roughness())
    for k in ("p", "v", "q", "pwm", "truth_p", "truth_fa", "battery_V"):
        assert np.array_equal(clean[k], off[k]), k
    assert not np.array_equal(clean["pwm"], rough["pwm"])
    with pytest.raises(ValueError, match="unknown roughness"):
        Roughness().without("wind")
    # the calibrated simulator has every effect on; plus() turns one back on
    assert Roughness().enabled == EFFECTS and Roughness().without("lateral").plus("lateral") == Roughness()
    with pytest.raises(ValueError, match="unknown roughness"):   # deleted after 96ed0bd (the wakes' moments)
        Roughness().plus("moment")


def test_a_flight_lasts_one_battery_charge(cfg, monkeypatch):
    """On the rough simulator a collection flight ends before the sag reaches the
    firmware's low-battery voltage: longer ones are flown as several on full batteries
    (a robot flown 10 min on the fitted sag falls); the clean simulator's are not split."""
    r = Roughness()
    limit = r.flight_limit_s()
    assert r.battery_V(limit, 3.9) == pytest.approx(LOW_BATTERY_V)
    assert 64.0 < limit < 600.0                  # above the real flights' longest
    assert math.isinf(r.without("battery").flight_limit_s())
    flown = []
    monkeypatch.setattr(collect_mod, "fly_many", lambda fn, args, *a, **k: flown.append(args) or [])
    monkeypatch.setattr(collect_mod, "flights_to_dataset", lambda cfg, flights: None)
    teams = [("small",), ("small", "large")]
    for rough in (r, None, r.without("battery")):
        collect_mod.collect(cfg, "gen", 700.0, seed=7, team_list=teams, rough=rough)
    rough_jobs, clean_jobs, no_sag_jobs = ([(a[1], a[3], a[4], a[5]) for a in args] for args in flown)
    assert [(t, k, d) for t, k, d, _ in clean_jobs] == [(("small",), "random", 700.0),
                                                         (("small", "large"), "random", 350.0),
                                                         (("small", "large"), "swap", 350.0)]
    assert no_sag_jobs == clean_jobs
    assert [d for *_, d, _ in rough_jobs] == [175.0] * 4 + [175.0] * 2 + [175.0] * 2
    assert all(d <= limit for *_, d, _ in rough_jobs)
    seeds = [s for *_, s in rough_jobs]
    assert len(set(seeds)) == len(seeds)
    # the first flight of each keeps the clean simulator's seed
    assert [seeds[0], seeds[4], seeds[6]] == [s for *_, s in clean_jobs]


def test_each_effect_does_its_part(cfg, exported):
    r = Roughness()
    sw, log = _fly(cfg, exported, r.only("thrust"))
    fac = r.thrust_factors(4, 2)
    assert abs(fac - 1).max() > 0 and abs(fac - 1).max() < 5 * r.thrust_sd
    for i, veh in enumerate(sw.vehicles):
        assert list(sw.robots[i].psi1) == pytest.approx(list(np.asarray(veh.psi1) * fac[i]), rel=1e-12)
    sw, _ = _fly(cfg, exported, r.only("vibration"), seconds=0.1)
    se = sw.sensing
    for i, t in enumerate(sw.types):
        assert sw.robots[i].sd_acc_g == pytest.approx(math.hypot(se.acc_sd_g, r.vibration_acc_g[t]), rel=1e-6)
        assert sw.robots[i].sd_gyro_dps == pytest.approx(math.hypot(se.gyro_sd_dps, r.vibration_gyro_dps[t]), rel=1e-6)
    _, log = _fly(cfg, exported, r.only("battery"))
    t_from_start = np.asarray(log["t"]) + 0.2
    want = r.battery_start_V - r.battery_sag_V_per_min * t_from_start / 60
    assert np.allclose(log["battery_V"][:, 0], want, atol=1e-3)
    sw, _ = _fly(cfg, exported, replace(r, wake_sigma0_scale=0.8, wake_spread_scale=0.5).only("wake"), seconds=0.1)
    paper, _ = _fly(cfg, exported, r.only(), seconds=0.1)
    assert np.allclose(sw.aero.sigma0, 0.8 * paper.aero.sigma0, rtol=1e-12) and sw.aero.spread == 0.5 * paper.aero.spread
    assert r.without("wake", "lateral").aero_kwargs(["small"]) == {}
    lat = replace(r, lateral_k_xy={"small": -0.05, "large": -0.17}).only("lateral")
    sw, _ = _fly(cfg, exported, lat, seconds=0.1)
    assert list(sw.aero.k_xy) == [{"small": -0.05, "large": -0.17}[t] for t in sw.types]
    assert np.all(paper.aero.k_xy == K_XY) and "k_xy" not in r.without("lateral").aero_kwargs(["small"])
    _, clean = _fly(cfg, exported, None)
    _, turb = _fly(cfg, exported, replace(r, turbulence_ratio=0.3).only("turbulence"))
    d = turb["truth_fa"][0, :, 2] - clean["truth_fa"][0, :, 2]     # first log row: same state, own step
    assert np.all(np.abs(d) > 0) and np.all(np.abs(d) <= 0.3 * 6 * np.abs(clean["truth_fa"][0, :, 2]))


def test_turbulence_is_the_stated_process():
    r = Roughness(turbulence_ratio=0.2, turbulence_tau_s=0.02)
    tu = Turbulence(r, 2, 0.002, seed=1)
    f = np.array([[0.0, 0.0, -0.1], [0.0, 0.0, 0.0]])
    x = np.array([tu.force(f)[:, 2] for _ in range(40000)])
    assert np.all(x[:, 1] == 0.0)                       # no wake, no turbulence
    assert np.std(x[:, 0]) == pytest.approx(0.2 * 0.1, rel=0.05)
    rho = np.corrcoef(x[:-1, 0], x[1:, 0])[0, 1]
    assert rho == pytest.approx(math.exp(-0.002 / 0.02), abs=0.01)


def test_hp_share_matches_a_simulated_process():
    rng = np.random.default_rng(0)
    for tau in (0.01, 0.1, 1.0):
        rho = math.exp(-0.01 / tau)
        x = np.zeros(200000)
        e = rng.standard_normal(len(x)) * math.sqrt(1 - rho ** 2)
        for k in range(1, len(x)):
            x[k] = rho * x[k - 1] + e[k]
        h = fs.HP_WINDOW // 2
        fast = (x - fs.moving_average(x, fs.HP_WINDOW))[h:-h]
        assert hp_share(tau) == pytest.approx(fast.var() / x.var(), rel=0.05)


def test_fit_arithmetic():
    # quadrature: the probe doubles the statistic's variance at 0.1 -> reach the real 2.0 from 1.0
    x = _quadrature(2.0, 1.0, math.sqrt(2.0), 0.1)
    assert 1.0 + (x / 0.1) ** 2 == pytest.approx(4.0)
    assert _quadrature(0.5, 1.0, 2.0, 0.1) == 0.0       # already as rough: no extra
    with pytest.raises(ValueError):
        _quadrature(2.0, 1.0, 1.0, 0.1)
    hover = {"a": {"median_g": 30.0}, "b": {"median_g": 33.0}, "c": {"median_g": 60.0}}
    sd = thrust_sd(hover, {"a": "small", "b": "small", "c": "large"})
    m = np.array([30.0, 33.0])
    assert sd == pytest.approx(np.std(m / m.mean(), ddof=1))
    with pytest.raises(ValueError):
        thrust_sd({"c": {"median_g": 60.0}}, {"c": "large"})


def test_free_air_statistics_see_the_vibration(cfg, exported):
    """The simulator's free-air statistics move with the effect fitted to them: the
    fast part of the label with the accelerometer's noise, the motor noise with the gyro's."""
    from ns2codegen.data.from_logs import Flight

    p0 = [[0.0, 0.0, 1.0]]

    def stats(rough):
        log = CLoopSwarm(cfg, robots_of(["small"], p0), exported.gen_dir, aero=True, seed=2, rough=rough).run(
            4.0, hover_setpoints(p0), settle_s=0.5)
        fl = Flight(["small"], *(log[k] for k in ("t", "p", "v", "q", "pwm", "battery_V")), p_d=log["p_d"])
        return fs.free_air(cfg, [fl])["small"], fs.z_loop(cfg, [fl])

    base = Roughness().only("vibration")
    calm, z_calm = stats(replace(base, vibration_acc_g={"small": 0.0}, vibration_gyro_dps={"small": 0.0}))
    acc, _ = stats(replace(base, vibration_acc_g={"small": 0.08}, vibration_gyro_dps={"small": 0.0}))
    gyro, _ = stats(replace(base, vibration_acc_g={"small": 0.0}, vibration_gyro_dps={"small": 2.0}))
    assert calm["samples"] == 396 and calm["band_fraction"] is not None and sum(calm["band_fraction"]) == pytest.approx(1, abs=0.01)
    assert acc["fast_std_g"] > 1.5 * calm["fast_std_g"]
    assert gyro["motor_noise"] > 1.5 * calm["motor_noise"] and abs(gyro["fast_std_g"] / calm["fast_std_g"] - 1) < 0.3
    assert z_calm["by_type"]["small"]["z_error_std_m"] < 0.01 and z_calm["fit"]["samples"] == 400


def test_z_law_reads_the_law_that_made_the_motor_commands(cfg):
    """z_law on a constructed flight whose PWM is the law's thrust exactly (psi_1
    inverted per motor), with a prediction flown: it reads the law's gains back, with
    or without an integral; below Z_LAW_MIN_Z_M and without a setpoint nothing is read."""
    from ns2codegen.data.from_logs import Flight

    veh = cfg.vehicle("small")
    m, k = veh["mass_g"] / 1000.0, np.asarray(veh["psi1"], float)
    t = np.arange(0.0, 20.0, 0.01)
    e = 0.05 * np.sin(1.3 * t) + 0.03 * np.sin(3.1 * t + 1.0)
    ev = 0.05 * 1.3 * np.cos(1.3 * t) + 0.03 * 3.1 * np.cos(3.1 * t + 1.0)
    ie = np.concatenate([[0.0], np.cumsum(0.5 * (e[1:] + e[:-1]) * 0.01)])
    fa_g = -3.0 * np.exp(-((t - 10.0) / 2.0) ** 2)            # a wake, predicted and flown

    def flight(kp, kd, ki, k_fa=1.0):
        T = m * (fs.G + 0.2 - kp * e - kd * ev - ki * ie) - k_fa * fa_g * 1e-3 * fs.G    # N, c = 0.2 m/s^2
        f_g = T / 4.0 / fs.G * 1000.0
        vb = 3.7 / 4.2
        a2, a1, a0 = k[3], k[1] + k[4] * vb, k[0] + k[2] * vb - f_g             # psi_1 = f_g, per motor
        pwm = (-a1 + np.sqrt(a1 ** 2 - 4 * a2 * a0)) / (2 * a2)
        n = len(t)
        p = np.zeros((n, 1, 3))
        p[:, 0, 2] = 1.0 + e
        v = np.zeros_like(p)
        v[:, 0, 2] = ev
        p_d = np.zeros_like(p)
        p_d[:, 0, 2] = 1.0
        return Flight(["small"], t, p, v, np.tile([1.0, 0, 0, 0], (n, 1, 1)), np.repeat(pwm[:, None, None], 4, 2),
                      np.full((n, 1), 3.7), p_d=p_d, fa_onboard_g=fa_g[:, None])

    fl = flight(10.0, 5.0, 3.0)
    np.testing.assert_allclose(psi1_newtons(k, fl.pwm[:, 0], fl.battery_V[:, 0]).sum(1),
                               m * (fs.G + 0.2 - 10 * e - 5 * ev - 3 * ie) - fa_g * 1e-3 * fs.G, rtol=1e-9)
    law = fs.z_law(cfg, [fl])["small"]
    assert law["kp_per_s2"] == pytest.approx(10.0, abs=0.01) and law["kd_per_s"] == pytest.approx(5.0, abs=0.01)
    assert law["ki_per_s3"] == pytest.approx(3.0, abs=0.01) and law["r2"] > 0.999 and law["samples"] == len(t)
    assert law["k_fa"] == pytest.approx(1.0, abs=0.01)
    assert law["z_error_mean_m"] == pytest.approx(e.mean(), abs=1e-4)
    soft = fs.z_law(cfg, [flight(4.0, 2.0, 0.0)])["small"]
    assert soft["kp_per_s2"] == pytest.approx(4.0, abs=0.01) and soft["kd_per_s"] == pytest.approx(2.0, abs=0.01)
    assert soft["ki_per_s3"] == pytest.approx(0.0, abs=0.01)
    half = fs.z_law(cfg, [flight(10.0, 5.0, 3.0, k_fa=0.5)])["small"]      # half the prediction taken off
    assert half["k_fa"] == pytest.approx(0.5, abs=0.01) and half["kp_per_s2"] == pytest.approx(10.0, abs=0.01)
    # the prediction flown is part of the law: not logged, the wake reads as something else
    fl.fa_onboard_g = None
    unlogged = fs.z_law(cfg, [fl])["small"]
    assert unlogged["r2"] < 0.99 and unlogged["k_fa"] is None
    fl.p[:, 0, 2] = 0.2                                      # on the ground: nothing to read
    assert fs.z_law(cfg, [fl]) == {}
    fl.p[:, 0, 2], fl.p_d[:, 0, 2] = 1.0 + e, np.nan        # no setpoint logged
    assert fs.z_law(cfg, [fl]) == {}


def test_swap_statistics_by_hand():
    """swap_errors on a constructed flight: the bottom robot, the windows, the name."""
    from ns2codegen.data.from_logs import Flight

    t = np.arange(0, 12, 0.01)
    n = len(t)
    p_d = np.zeros((n, 2, 3))
    p_d[:, 0, 2], p_d[:, 1, 2] = 1.0, 0.5               # robot 1 (small) is the bottom one
    x = np.where((t % 3) < 1.5, np.sin(np.pi * (t % 3) / 1.5) ** 2, 0.0) * 0.2
    p_d[:, :, 0] = np.cumsum(x)[:, None] * 0.01
    p = p_d.copy()
    bump = np.array([0.01, 0.03, 0.02, 0.05])           # a dip in each of the 4 windows
    for k, b in enumerate(bump):
        p[int((k * 3 + 0.7) * 100), 1, 2] -= b
    fl = Flight(["large", "small"], t, p, np.zeros_like(p), np.tile([1.0, 0, 0, 0], (n, 2, 1)),
                np.full((n, 2, 4), 0.5), np.full((n, 2), 3.9), p_d=p_d)
    res = fs.swap_errors([fl])
    assert list(res) == ["L2S"]
    # movements start just after 0, 3, 6, 9: whole windows up to the next start, the last
    # one (no next start in the flight) not counted: dips 0.01, 0.03, 0.02; 0.05 left out
    assert res["L2S"]["swaps"] == 3 and res["L2S"]["worst_m"] == pytest.approx(0.03)
    assert res["L2S"]["median_worst_z_error_m"] == pytest.approx(0.02, abs=1e-4)
    # swap_attitude over the same windows: a tilt about x and a sideways error in each
    for k, (deg, dy) in enumerate([(4.0, 0.01), (12.0, 0.05), (8.0, 0.02), (30.0, 0.09)]):
        j = int((k * 3 + 1.0) * 100)
        fl.q[j, 1] = [np.cos(np.radians(deg) / 2), np.sin(np.radians(deg) / 2), 0.0, 0.0]
        fl.p[j, 1, 1] += dy
    for k, (spread, rise) in enumerate([(0.1, 0.05), (0.3, 0.02), (0.2, 0.2), (0.4, 0.3)]):
        j = int((k * 3 + 1.2) * 100)
        fl.pwm[j, 1] = [0.5 + rise + spread, 0.5 + rise - spread, 0.5 + rise, 0.5 + rise]
    att = fs.swap_attitude([fl])["L2S"]
    assert att["swaps"] == 3 and att["median_max_tilt_deg"] == pytest.approx(8.0, abs=0.01)
    assert att["median_max_xy_error_m"] == pytest.approx(0.02, abs=1e-4)
    assert att["median_max_motor_spread"] == pytest.approx(0.2, abs=1e-4)
    assert att["median_mean_pwm_rise"] == pytest.approx(0.05, abs=1e-4)
    # largest single motor per swap 0.65, 0.82, 0.9 (0.5 + rise + spread)
    assert att["median_max_motor_pwm"] == pytest.approx(0.82, abs=1e-4)
    assert fs.tilt_deg(np.array([0.0, 1.0, 0.0, 0.0])) == pytest.approx(180.0)


@needs(REAL_DATA)
def test_the_swap_experiments_fly_the_real_swaps_geometry(cfg):
    """experiments/swarm.py's swap (the paper's swap experiments, "similar" to its data
    collection's swaps): travel 2 r and peak setpoint speed pi r / T of the cosine
    profile within 3 % of the medians over every swap of the 16 June collection."""
    import tarfile

    from ns2paper.collection import write_manifest
    from ns2exp.calibrate import swap_flights
    from ns2exp.swarm import SWAP_RADIUS_M, SWAP_S
    from ns2host import crazyflie

    with tarfile.open(crazyflie.SHARED / "neural-swarm-data" / SWAPS) as tar:
        logs = sorted(m.name for m in tar.getmembers() if m.isfile() and m.name.startswith(f"{COLLECTION}/swap_")
                      and "/cf" in m.name)
    root = real_logs(SWAPS, logs)
    write_manifest(root)
    flights, _ = logs_to_flights(cfg, root)
    geo = fs.swap_geometry(swap_flights(flights))
    assert geo["swaps"] > 200
    assert 2 * SWAP_RADIUS_M == pytest.approx(geo["median_travel_m"], rel=0.03)
    assert math.pi * SWAP_RADIUS_M / SWAP_S == pytest.approx(geo["median_peak_speed_mps"], rel=0.03)


@needs(REAL_DATA)
def test_a_real_swap_measured_and_replayed(cfg, exported):
    root = real_logs(SWAPS, SL)
    (root / "flights.toml").write_text(
        'rate_hz = 100\n[ground_plane_m]\nsmall = 0.05\nlarge = 0.06\n[[flight]]\nname = "swap_sl/03"\n'
        f'robots = [{{file = "{SL[0]}", type = "small"}}, {{file = "{SL[1]}", type = "large"}}]\n')
    flights, _ = logs_to_flights(cfg, root)
    pieces = pieces_by_flight(flights)["swap_sl/03"]
    assert all(p.p_d is not None and np.isfinite(p.p_d).all() for p in pieces)
    real = fs.swap_errors(pieces)
    (case, r), = real.items()
    assert case == "S2L" and r["swaps"] >= 4                # the large robot flies under the small one
    sc = fs.wake_scatter(cfg, pieces)
    assert list(sc) == ["large under small"] and sc["large under small"]["scatter_g"] > 0
    sp, start, t0, dur = logged_setpoints(pieces)
    for p in pieces:                                        # the setpoints replayed are the logged ones
        k = np.arange(0, len(p.t), 50)
        got = np.array([sp(tt - t0).p for tt in p.t[k]])
        assert np.abs(got - p.p_d[k]).max() < 1e-6
    assert np.allclose(start, pieces[0].p_d[0])
    sim = replay(cfg, pieces, exported.gen_dir, learned="float", rough=Roughness())
    assert sim.t[0] == pytest.approx(t0) and sim.t[-1] == pytest.approx(t0 + dur, abs=0.011)
    s = fs.swap_errors([sim])
    assert list(s) == ["S2L"] and abs(s["S2L"]["swaps"] - r["swaps"]) <= 1
    assert 0 < s["S2L"]["median_worst_z_error_m"] < 0.5
    # what the prediction flown left: the same statistic on both sides (the real robots' logged
    # ctrlFa.Faz, the replay's C prediction), over the bottom robot's labels beyond 3 g
    ur, us = fs.unpredicted(cfg, pieces), fs.unpredicted(cfg, [sim])
    assert list(ur) == list(us) == ["S2L"]
    for u in (ur["S2L"], us["S2L"]):
        assert u["samples"] > 50 and 0 < u["rms_g"] < u["label_rms_g"] + abs(u["mean_g"]) + 10
    assert np.isfinite(sim.fa_onboard_g).all() and np.abs(sim.fa_onboard_g[:, 1]).max() > 1.0   # the bottom robot
    # the controller that flew it (paper/c/ctrl_authors.c) flies the same replay, every robot known by its id
    auth = replay(cfg, pieces, exported.gen_dir, learned="float", rough=Roughness(), controller="authors")
    assert auth.robots == pieces[0].robots == [SL[0], SL[1]]
    sa = fs.swap_errors([auth])
    assert list(sa) == ["S2L"] and abs(sa["S2L"]["swaps"] - r["swaps"]) <= 1
    assert 0 < sa["S2L"]["median_worst_z_error_m"] < 0.5
    assert sa["S2L"]["median_worst_z_error_m"] != s["S2L"]["median_worst_z_error_m"]
    # beside the wake's axis: the truth (K_XY > 0) pushes a replayed robot out; the rough
    # simulator's "lateral" (fitted on the real flights, the authors' controller) draws a large
    # robot in, as the real one is drawn in; the least squares of experiments/calibrate.py
    # reads the push off the labels, in part only (the EKF takes some of it for tilt)
    out = replay(cfg, pieces, exported.gen_dir, learned="float", rough=Roughness().without("lateral"))
    lat, real_lat = fs.wake_lateral(cfg, [out]), fs.wake_lateral(cfg, pieces)
    assert list(lat) == list(real_lat) == ["large under small"]
    assert lat["large under small"]["push_out_g"] > 0 > real_lat["large under small"]["push_out_g"]
    assert fs.wake_lateral(cfg, [sim])["large under small"]["push_out_g"] < lat["large under small"]["push_out_g"]
    k, k_in, real_k = lateral_k_xy(cfg, [out]), lateral_k_xy(cfg, [sim]), lateral_k_xy(cfg, pieces)
    assert k["truth_k_xy"] == K_XY and k["all"]["samples"] > 100
    assert 0.0 < k["all"]["k_xy"] < K_XY and real_k["large"]["k_xy"] < 0
    assert k_in["large"]["k_xy"] < k["large"]["k_xy"] - 0.02
    # the same controller flying the prediction the real robots logged: what the replay flew is it
    flown = logged_prediction(pieces)
    lg = replay(cfg, pieces, exported.gen_dir, learned="logged", rough=Roughness(), controller="authors")
    want = np.array([flown(tt - t0) for tt in lg.t])
    assert np.allclose(lg.fa_onboard_g, want.astype(np.float32), atol=1e-4)
    for p in pieces:                                        # ... and that is the logged one
        got, ok = np.array([flown(tt - t0) for tt in p.t]), np.isfinite(p.fa_onboard_g)
        assert ok.mean() > 0.9 and np.abs(got[ok] - p.fa_onboard_g[ok]).max() < 1e-6
    assert lg.w is not None and lg.w.shape == lg.p.shape and np.isfinite(lg.w).all()   # the gyro, as logged
    sl = fs.swap_errors([lg])
    assert list(sl) == ["S2L"] and abs(sl["S2L"]["swaps"] - r["swaps"]) <= 1
    # every robot flies on the voltage its real robot logged (pm.vbat); the simulator's own
    # sag instead puts the motors elsewhere: the replay hovers on the real robots' PWM
    bat = logged_battery(pieces)
    assert np.allclose(lg.battery_V, [bat(tt - t0) for tt in lg.t])
    for p in pieces:
        got, ok = np.array([bat(tt - t0) for tt in p.t]), np.isfinite(p.battery_V)
        assert ok.mean() > 0.9 and np.abs(got[ok] - p.battery_V[ok]).max() < 1e-6
    own = replay(cfg, pieces, exported.gen_dir, learned="logged", rough=Roughness(), controller="authors",
                 battery="model")
    assert np.allclose(own.battery_V[:, 0], [Roughness().battery_V(tt - t0 + 2.0, 0.0) for tt in own.t], atol=1e-3)
    real_V = np.nanmean(np.concatenate([p.battery_V for p in pieces]))
    assert abs(real_V - own.battery_V.mean()) > 0.05                 # this flight's battery is not the model's
    real_pwm = np.nanmean(np.concatenate([p.pwm for p in pieces]))
    print("mean PWM real", real_pwm, "logged battery", lg.pwm.mean(), "model", own.pwm.mean())
    assert abs(lg.pwm.mean() - real_pwm) < 0.6 * abs(own.pwm.mean() - real_pwm)
    with pytest.raises(ValueError, match="battery"):
        replay(cfg, pieces, exported.gen_dir, learned="logged", controller="authors", battery="full")
    assert 0 < fs.unpredicted(cfg, [lg])["S2L"]["slow_rms_g"] < 20
    # the position law read off the same flight, real and replayed: the replay's is the authors' law
    # (Kp 10, Kd 5, Ki 3 on z; read with the motors' delay and the estimator in the loop)
    zr, zs = fs.z_law(cfg, pieces), fs.z_law(cfg, [lg])
    assert sorted(zr) == sorted(zs) == ["large", "small"] and min(z["samples"] for z in zr.values()) > 1000
    print("z law real", zr, "replay", zs)
    for z in zs.values():
        assert 6.0 < z["kp_per_s2"] < 14.0 and 1.5 < z["ki_per_s3"] < 5.0 and z["r2"] > 0.5
        assert 0.6 < z["k_fa"] < 1.6                        # the prediction flown taken off whole, as read
    # a z law read off logs, flown: softer, no integral, half the prediction taken off; read so
    law = {ty: {"kp": 5.0, "kd": 2.0, "ki": 0.0, "k_fa": 0.5, "mass_kg": m} for ty, m in (("small", 0.034),
                                                                                       ("large", 0.067))}
    zsoft = fs.z_law(cfg, [replay(cfg, pieces, exported.gen_dir, learned="logged", rough=Roughness(),
                                  controller="authors", law=law)])
    for ty, z in zsoft.items():
        print("z law read off the soft law's replay", ty, z)
        assert z["kp_per_s2"] < zs[ty]["kp_per_s2"] and z["ki_per_s3"] < 0.5 * zs[ty]["ki_per_s3"]
        assert z["k_fa"] < 0.7 * zs[ty]["k_fa"]
    with pytest.raises(ValueError, match="authors"):
        replay(cfg, pieces, exported.gen_dir, learned="logged")
    with pytest.raises(ValueError, match="authors"):
        replay(cfg, pieces, exported.gen_dir, law=law)


def test_sim_to_real_and_paper_tables():
    from ns2exp.calibrate_tables import paper_l2s_table, sim_to_real_table

    sw = lambda x: {"L2S": {"median_worst_z_error_m": x, "swaps": 5}}   # noqa: E731
    cmp = {"flights": [], "real": {"swaps": {"L2S": {"median_worst_z_error_m": 0.059, "swaps": 5},
                                             "S2L": {"median_worst_z_error_m": 0.038, "swaps": 2}}},
           "simulators": {"clean": {"swaps": sw(0.015)},
                          "rough": {"swaps": {**sw(0.070), "S2L": {"median_worst_z_error_m": 0.02}}}}}
    t = sim_to_real_table(cmp).splitlines()
    assert t[2] == "| L2S | 5 | 5.9 | 1.5 (0.25) | 7.0 (1.19*) |"
    assert t[3] == "| S2L | 2 | 3.8 | - | 2.0 (0.53) |"
    assert t[4] == "| within 30 % (*) | | | 0 of 2 | 1 of 2 |"
    p = paper_l2s_table({"BL-authors": {"median_worst_z_error_m": 0.084, "worst_z_error_m": [0.08] * 6, "paper_m": 0.17}})
    assert p.splitlines()[2] == "| BL-authors | 6 | 8.4 | 17 | 0.49 | no |"


def test_calibration_markdown_keeps_the_simulators_in_their_order():
    """calibration.json is written with sorted keys; calibration.md reads it back with
    its simulators in VARIANTS' order whatever the JSON's (here reversed: five
    simulators' names happen to sort in VARIANTS' order), and metadata never becomes a
    simulator column."""
    import json

    from ns2exp.calibrate import READ_LAW, VARIANTS, markdown

    sw = lambda x: {"swaps": {"L2S": {"median_worst_z_error_m": x, "swaps": 5}}, "free_air": {},   # noqa: E731
                    "wake_scatter": {}, "battery": {}}
    cmp = {"flights": ["swap_ls_1"], "free_air_flights": ["randomwalk_ss_1"],
           "real": sw(0.06), "simulators": {v: sw(0.01 * (k + 1)) for k, v in reversed(list(enumerate(VARIANTS)))}}
    res = json.loads(json.dumps({"fit": None, "compare": cmp, "read_law": READ_LAW, "paper_l2s": {}}))
    assert list(res["compare"]["simulators"]) == list(VARIANTS)[::-1]
    rows = markdown(res).splitlines()
    head = next(r for r in rows if r.startswith("| statistic | real |"))
    assert head == "| statistic | real | " + " | ".join(VARIANTS) + " | rough / real |"
    l2s = next(r for r in rows if r.startswith("| L2S | 5 |"))
    assert l2s == "| L2S | 5 | 6.0 | 1.0 (0.17) | 2.0 (0.33) | 3.0 (0.50) | 4.0 (0.67) | 5.0 (0.83*) |"


def test_roughness_table_rows_of_the_wake_and_the_swaps():
    from ns2exp.calibrate_tables import roughness_table

    side = lambda push, tilt: {"free_air": {}, "wake_scatter": {}, "battery": {},   # noqa: E731
                               "wake_lateral": {"large under small": {"push_out_g": push, "fz_g": -4.0}},
                               "attitude": {"L2S": {"median_max_tilt_deg": tilt, "median_max_xy_error_m": 0.04}},
                               "swaps": {}}
    real = side(-0.5, 6.3)
    real["lateral_k_xy"] = {"truth_k_xy": 0.15, "all": {"k_xy": -0.08}, "small": {"k_xy": -0.02},
                            "large": {"k_xy": -0.09}}
    clean, rough = side(0.8, 3.0), side(0.7, 3.15)
    rough["lateral_k_xy"] = {"truth_k_xy": 0.15, "all": {"k_xy": 0.04}}
    real["z_law"] = {"small": {"kp_per_s2": 6.52, "kd_per_s": 2.0, "ki_per_s3": 0.3, "r2": 0.36,
                               "z_error_mean_m": 0.0077}}
    rough["z_law"] = {"small": {"kp_per_s2": 10.47, "kd_per_s": 7.17, "ki_per_s3": 3.38, "r2": 0.77,
                                "z_error_mean_m": 0.001}}
    t = roughness_table({"flights": [], "real": real, "simulators": {"clean": clean, "rough": rough}})
    rows = t.splitlines()
    assert "| large under small, beside the wake's axis: push_out_g | -0.500 | 0.800 | 0.700 | -1.40 |" in rows
    assert "| swap flights, z law read off every robot, small: kd_per_s | 2.000 | - | 7.170 | 3.58 |" in rows
    assert "| swap flights, z law read off every robot, small: z_error_mean_m | 0.0077 | - | 0.0010 | 0.13 |" in rows
    assert "| swap L2S, bottom robot: median largest tilt (deg) | 6.3 | 3.0 | 3.1 | 0.50 |" in rows
    assert ("| wake's lateral push per unit r / sigma read off the labels (aero.py K_XY, the truth's 0.15), "
            "all robots | -0.080 | - | 0.040 | -0.50 |") in rows
    assert all(r.count("|") == rows[0].count("|") for r in rows)


def test_read_law_step_and_table():
    """fit_read_law's step: a gain the replay reads 20 % high is scaled down by it, a
    reading of ~0 leaves the gain, none goes below 0; a replay 1 cm under the real mean
    z error raises the mass parameter by 1 cm x m Kp / g; the table prints the law and
    each iteration against the real reading."""
    from ns2exp.calibrate import law_step
    from ns2exp.calibrate_tables import read_law_table

    law = {"small": {"kp": 7.0, "kd": 2.0, "ki": 0.3, "k_fa": 0.7, "mass_kg": 0.034}}
    real = {"small": {"kp_per_s2": 7.0, "kd_per_s": 2.0, "ki_per_s3": 0.3, "k_fa": 0.7, "z_error_mean_m": 0.008}}
    read = {"small": {"kp_per_s2": 8.4, "kd_per_s": 2.0, "ki_per_s3": 0.0, "k_fa": 1.4, "z_error_mean_m": -0.002}}
    new = law_step(law, real, read)["small"]
    assert new["kp"] == pytest.approx(7.0 / 1.2, abs=1e-4) and new["kd"] == 2.0 and new["ki"] == 0.3
    assert new["k_fa"] == pytest.approx(0.35, abs=1e-4)
    assert new["mass_kg"] == pytest.approx(0.034 + 0.01 * 0.034 * 7.0 / 9.81, abs=2e-6)
    assert law["small"]["kp"] == 7.0                                   # the law given is left as it was
    # with the step before: the mass parameter by the secant (0.5 g heavier read 0.5 cm higher)
    prev = ({"small": dict(law["small"], mass_kg=0.0335)}, {"small": dict(read["small"], z_error_mean_m=-0.007)})
    assert law_step(law, real, read, prev)["small"]["mass_kg"] == pytest.approx(0.035, abs=2e-6)
    prev[1]["small"]["z_error_mean_m"] = 0.003                          # a slope of the wrong sign: not used
    assert law_step(law, real, read, prev)["small"]["mass_kg"] == pytest.approx(new["mass_kg"], abs=2e-6)
    rows = [{"flights": ["swap_ss/00"], "real": real},
            {"iteration": 0, "law": law, "read": read, "miss": 1.0}]
    t = read_law_table(law, rows).splitlines()
    assert t[2] == "| small | 7.00 | 2.00 | 0.30 | 0.70 | 34.0 |"
    assert t[-1] == "| 0 | small | 7.00 / 2.00 / 0.30 / 0.70 / 0.80 | 8.40 / 2.00 / 0.00 / 1.40 / -0.20 | 1.000 |"
    assert len(read_law_table(law).splitlines()) == 3


def test_moving_average_of_any_length():
    """The centred moving average is the mean over the partial window at the edges, for a
    series shorter than the window too (a real flight piece of 20 samples under the 21 of
    HP_WINDOW once crashed make calibrate)."""
    rng = np.random.default_rng(0)
    for n_samples in (1, 5, 20, 21, 60):
        x = rng.normal(size=(n_samples, 3))
        for n in (11, 21):
            ref = np.array([x[max(0, i - n // 2):i + n // 2 + 1].mean(axis=0) for i in range(n_samples)])
            assert fs.moving_average(x, n).shape == x.shape
            np.testing.assert_allclose(fs.moving_average(x, n), ref, rtol=1e-12, atol=1e-12)


def test_first_per_folder():
    """The flights make calibrate, the z law's fit and the turbulence fit replay: the
    first n names of each folder, by name, in order of folder."""
    from ns2exp.calibrate import first_per_folder

    names = ["swap_sl/02", "swap_ll/01", "swap_sl/00", "swap_ll/00", "swap_ss/00", "swap_sl/01"]
    assert first_per_folder(names, 2) == ["swap_ll/00", "swap_ll/01", "swap_sl/00", "swap_sl/01", "swap_ss/00"]
    assert first_per_folder(names, 1, ("swap_sl", "swap_ll")) == ["swap_sl/00", "swap_ll/00"]
    assert first_per_folder(names, 5) == sorted(names)


def test_the_vibration_fit_replays_the_pair_random_walks():
    """fit_vibration and the free-air rows replay the pair random walks (the one-robot
    walks fly in ground effect), the first two of each, every piece of a flight."""
    from types import SimpleNamespace

    from ns2exp.calibrate import free_air_pieces

    names = ["randomwalk_s/00", "randomwalk_l/01", "randomwalk_ss/02", "randomwalk_ss/00", "randomwalk_ss/01",
             "randomwalk_ll/03", "randomwalk_sl/00", "randomwalk_sss/00", "swap_ss/00", "randomwalk_ss/00"]
    flights = [SimpleNamespace(name=n) for n in names]
    got = free_air_pieces(flights)
    assert list(got) == ["randomwalk_ss/00", "randomwalk_ss/01", "randomwalk_sl/00", "randomwalk_ll/03"]
    assert [len(got[n]) for n in got] == [2, 1, 1, 1]


def test_the_wake_read_off_labels_at_logged_states(cfg):
    """fit_wake's pieces: the truth of many snapshots at once is each snapshot's own to
    within rounding; labels made by a wake 0.8 x as wide at the rotor and spreading
    at 0.6 x the rate, at states under a neighbour, are read back as those scales; the
    profile and its table put real and truth side by side per pair and offset."""
    from ns2exp.calibrate import fit_wake_scales, wake_profile, wake_truth_g
    from ns2host.sim.aero import calibrated, forces_of_snapshots
    from ns2exp.calibrate_tables import wake_profile_table
    from ns2host.sim.vehicle import vehicle

    types = ("small", "large")
    rng = np.random.default_rng(3)
    K = 240
    P = np.zeros((K, 2, 3))
    P[:, 0] = [0.0, 0.0, 1.0]
    P[:, 1, :2] = rng.uniform(-0.2, 0.2, (K, 2))
    P[:, 1, 2] = 1.0 + rng.uniform(0.15, 0.9, K)
    V = rng.normal(0.0, 0.3, (K, 2, 3))
    vs = [vehicle(cfg, t) for t in types]
    small = vehicle(cfg, "small")
    one = np.array([calibrated(vs, small).forces(P[k], V[k]) for k in range(K)])
    assert np.allclose(forces_of_snapshots(lambda k: calibrated(vs * k, small), P, V), one, rtol=0, atol=1e-9)
    r = np.hypot(*P[:, 1, :2].T)
    samples = {types: {"P": P, "V": V, "i": np.zeros(K, int), "label_g": np.zeros(K),
                       "pair": np.array(["small under large"] * K), "r_m": r}}
    samples[types]["label_g"] = wake_truth_g(cfg, samples, 0.8, 0.6)
    assert np.allclose(wake_truth_g(cfg, samples), one[:, 0, 2] * 1e3 / 9.81, atol=1e-6)
    s0, sp = fit_wake_scales(cfg, samples)
    assert s0 == pytest.approx(0.8, abs=0.02) and sp == pytest.approx(0.6, abs=0.02)
    prof = wake_profile(samples, {"paper_g": wake_truth_g(cfg, samples), "fitted_g": samples[types]["label_g"]})
    rows = prof["small under large"]
    assert sum(x["samples"] for x in rows) == int((r < 0.3).sum()) and rows[0]["r_m"] == [0.0, 0.05]
    assert rows[0]["real_g"] == rows[0]["fitted_g"]
    assert abs(rows[2]["paper_g"]) > abs(rows[2]["real_g"])    # the wider wake reads more 10-15 cm off its axis
    t = wake_profile_table({"sigma0_scale": s0, "spread_scale": sp, "samples": K, "rms_paper_g": 1.0,
                            "rms_fitted_g": 0.0, "profile": prof}).splitlines()
    assert t[0].startswith("The wake's initial width x 0.8") and t[4].startswith("| small under large | 0-5 | ")


def test_the_vibration_fit_flies_without_turbulence(monkeypatch):
    """fit_vibration replays with the turbulence off whatever its base has (it is fitted
    after, on the vibration): the fit does not depend on the turbulence default."""
    from types import SimpleNamespace

    from ns2exp import calibrate as cal
    from ns2paper import flightstats as fs
    from ns2host.sim.roughness import Roughness

    flown = []
    monkeypatch.setattr(cal, "replay_all", lambda cfg, gen, pieces, rough, *a, **k: flown.append(rough) or [rough])

    def free_air(cfg, fls):                    # the real flights' statistics, or grows with the vibration flown
        r = fls[0]
        if not isinstance(r, Roughness):
            return {"small": {"fast_std_g": 0.4, "motor_noise": 0.02}}
        return {"small": {"fast_std_g": 0.1 + r.vibration_acc_g["small"], "motor_noise": 0.01 + r.vibration_gyro_dps["small"] / 100}}

    monkeypatch.setattr(fs, "free_air", free_air)
    cfg = SimpleNamespace(robot_types=["small"])
    base = Roughness(turbulence_ratio=0.5)
    assert base.on("turbulence")
    acc, gyro, _ = cal.fit_vibration(cfg, None, [SimpleNamespace(name="randomwalk_ss/00")], base)
    assert acc["small"] > 0 and gyro["small"] > 0
    assert len(flown) == 5 and not any(r.on("turbulence") for r in flown)
    assert all(r.turbulence_ratio == 0.5 and r.on("vibration") for r in flown)


def test_the_lateral_fit_solves_the_line_of_two_replays(monkeypatch):
    """fit_lateral: the labels' reading of the lateral push is linear in the constant
    flown; two replays (the truth's K_XY and the probe) give each type's line, solved
    for the real reading; the replays fly the lateral effect, the authors' controller
    and the logged prediction, the turbulence off."""
    from types import SimpleNamespace

    from ns2exp import calibrate as cal

    flown = []
    monkeypatch.setattr(cal, "fit_pieces", lambda flights: {"swap_sl/00": ["real"]})

    def replay_all(cfg, gen, pieces, rough, workers, **kw):
        flown.append((rough, kw))
        return [rough]
    monkeypatch.setattr(cal, "replay_all", replay_all)
    line = {"small": (0.01, 0.4), "large": (0.006, 0.42)}

    def read(cfg, fls):
        if fls == ["real"]:
            return {"small": {"k_xy": -0.02}, "large": {"k_xy": -0.07}}
        k = fls[0].lateral_k_xy
        return {t: {"k_xy": a + b * k[t]} for t, (a, b) in line.items()}
    monkeypatch.setattr(cal, "lateral_k_xy", read)
    cfg = SimpleNamespace(robot_types=["small", "large"])
    fit, rows = cal.fit_lateral(cfg, None, [], Roughness(turbulence_ratio=0.5))
    assert fit == {"small": round((-0.02 - 0.01) / 0.4, 3), "large": round((-0.07 - 0.006) / 0.42, 3)}
    assert [r.lateral_k_xy for r, _ in flown] == [{"small": K_XY, "large": K_XY},
                                                  {"small": cal.LATERAL_PROBE, "large": cal.LATERAL_PROBE}, fit]
    assert all(r.on("lateral") and not r.on("turbulence") and r.on("wake") for r, _ in flown)
    assert all(kw == {"controller": "authors", "learned": "logged"} for _, kw in flown)
    assert rows["check"] == {t: {"k_xy": pytest.approx(-0.02 if t == "small" else -0.07, abs=2e-3)} for t in line}
    from ns2exp.calibrate_tables import lateral_table
    t = lateral_table(rows).splitlines()
    assert t[0] == "| reading (K_XY of the labels) | large | small |" and t[2] == "| real | -0.070 | -0.020 |"
    assert t[3].startswith("| replay, K_XY 0.15 | 0.069 | 0.070 |") and t[5].startswith("| replay at the fit |")
    assert "Fitted: large -0.181, small -0.075" in t[-1]
    monkeypatch.setattr(cal, "lateral_k_xy", lambda cfg, fls: {"small": {"k_xy": 0.0}, "large": {"k_xy": 0.0}})
    with pytest.raises(ValueError, match="does not move"):
        cal.fit_lateral(cfg, None, [], Roughness())
