"""The app's on-board label and adaptation in the simulator (issue 53 item 5): off = the
flights of before bit for bit (tests/test_sim.py's digests), on = the C of the app's path,
equal bit for bit to the float32 reference ns2codegen/onboard.py on the simulator's own
inputs, and it learns an unmodelled payload."""
import json

import numpy as np
import pytest

from conftest import FIRMWARE, needs
from ns2codegen.onboard import ADAPT_UPDATED, AdaptCfg, LabelCfg, adapt_f32, label_f32
from ns2host.sim.cloop import CLoopSwarm, NS2Controller, Robot, hover_setpoints

pytestmark = needs(FIRMWARE)   # the simulator's EKF comes from the firmware

P0 = (0.0, 0.0, 1.0)
PAYLOAD_G = 3.0
F32 = np.float32


def _hover(cfg, exported, payload_g, adapt, seconds=4.0, trace=False):
    sw = CLoopSwarm(cfg, [Robot("small", P0, NS2Controller("fixed", adapt), payload_g=payload_g)],
                    exported.gen_dir, seed=3)
    return sw, sw.run(seconds, hover_setpoints(np.array([P0])), trace_robot=0 if trace else None, settle_s=1.0)


def test_adaptation_learns_an_unmodelled_payload(cfg, exported):
    """A lone small robot hovering with 3 g it does not know: the label reads the payload's
    force (-3 g, the clean simulator without wakes), and from 3 s of flight on (after 1 s
    of settling: 4 s after the adaptation started) the adapted f_a,z (network + bias) is within 0.4 g of it; without the
    payload it stays near 0."""
    for payload, want in ((PAYLOAD_G, -PAYLOAD_G), (0.0, 0.0)):
        _, log = _hover(cfg, exported, payload, AdaptCfg(enable=1))
        late = log["t"] >= 3.0
        label = log["adapt_label"][late, 0]
        assert abs(label.mean() - want) < 0.3, (payload, label.mean())
        f_used = log["fa_hat"][late, 0, 2] * 1000.0 / 9.81   # what the controller flew, g
        assert np.all(np.abs(f_used - want) < 0.4), (payload, f_used.min(), f_used.max())
        assert np.all((log["adapt_status"][:, 0] & ADAPT_UPDATED) != 0)
        assert np.array_equal(log["adapt_term"][:, 0], log["adapt_bias"][:, 0])   # scaleMax 0: the bias alone
    # off: theta held at 0, f = the network's, the label still computed and logged
    _, off = _hover(cfg, exported, PAYLOAD_G, None)
    assert np.all(off["adapt_bias"] == 0.0) and np.all(off["adapt_term"] == 0.0)
    assert abs(off["adapt_label"][off["t"] >= 3.0, 0].mean() + PAYLOAD_G) < 0.3


@pytest.mark.parametrize("track_gain", [0.0, 2.0e4])
def test_the_c_path_equals_the_reference_on_the_simulators_inputs(cfg, exported, track_gain):
    """The traced robot's every position tick: the label (from the estimator's v_z, z, q, the
    PWM and supply of the attitude tick before, the vehicle the controller knows and the
    type's psi_1 of the generated header) and the adapted f_a,z and theta (with the pilot's
    wake flag n_used > 0, and with the composite law the pilot's tracking error in z, (v_z -
    v_z,d + Lp_z (z - z_d)) h, from the traced state and setpoint) equal
    onboard.label_f32 / adapt_f32 bit for bit."""
    ad = AdaptCfg(enable=1, track_gain=track_gain)
    sw, log = _hover(cfg, exported, PAYLOAD_G, ad, seconds=3.0, trace=True)
    tr, n = log["trace"]
    recs = [tr[i] for i in range(n)]
    pos = [i for i, r in enumerate(recs) if r.do_pos]
    assert len(pos) > 300
    lc = sw.robots[0].pilot.label.cfg
    assert list(lc.psi1) == [float(F32(x)) for x in sw.vehicles[0].psi1]   # the app's NS2_PSI1_INIT
    lcfg = LabelCfg(lc.mass_kg, lc.__getattribute__("lambda"), tuple(lc.psi1), lc.h_s, lc.min_z_m, lc.min_r33)
    prev = lambda i, f: getattr(recs[i - 1], f) if i > 0 else None  # noqa: E731
    vz = [recs[i].s.v[2] for i in pos]
    z = [recs[i].s.p[2] for i in pos]
    q = [list(recs[i].s.q) for i in pos]
    pwm = [list(prev(i, "pwm")) if i > 0 else [0.0] * 4 for i in pos]
    bat = [prev(i, "battery_V") if i > 0 else 0.0 for i in pos]
    _, label_g, lstatus = label_f32(lcfg, vz, z, q, pwm, bat)
    got_label = np.array([recs[i].label_g for i in pos], F32)
    assert np.array_equal(got_label.view(np.uint32), label_g.view(np.uint32))
    nn = np.array([recs[i].fa_hat_g for i in pos], F32)
    wake = [recs[i].n_used > 0 for i in pos]
    lp, h = F32(sw.robots[0].pilot.gains.Lp[2]), F32(1.0) / F32(100.0)
    s_h = [(F32(recs[i].s.v[2]) - F32(recs[i].sp.v[2]) + lp * (F32(recs[i].s.p[2]) - F32(recs[i].sp.p[2]))) * h
           if track_gain > 0 else F32(0.0) for i in pos]
    ref = adapt_f32(ad, nn, wake, label_g, lstatus, s_h=s_h)
    if track_gain > 0:      # the tracking term moved theta: not the RLS alone
        assert not np.array_equal(ref["theta"], adapt_f32(AdaptCfg(enable=1), nn, wake, label_g, lstatus)["theta"])
    got_f = np.array([recs[i].fa_used_g for i in pos], F32)
    got_theta = np.array([list(recs[i].theta) for i in pos], F32)
    assert np.array_equal(got_f.view(np.uint32), ref["out_g"].view(np.uint32))
    assert np.array_equal(got_theta.view(np.uint32), ref["theta"].view(np.uint32))
    assert ref["updates"][-1] > 200 and np.any(got_f != nn)     # it learned, and flew what it learned


def test_adapt_parameters_are_checked():
    with pytest.raises(ValueError, match="adapt"):
        NS2Controller("fixed", AdaptCfg(forget=7.0))
    with pytest.raises(ValueError, match="payload_g"):
        Robot("small", P0, payload_g=float("nan"))


def test_the_experiment_flies_every_controller_and_reads_the_adaptation(cfg, exported, tmp_path, monkeypatch):
    """`ns2exp.simadapt` at a tiny size (S2S, one swap, seed 0, a 3 s battery flight): a row
    per flight; in the paper's swap the bottom robot updates (a neighbour in range does not
    stop it by default; |NN| stays below wakeG),
    after hovering alone it has learned the payload (bias below -1 g) before the swaps;
    BL-tuned and NN never adapt; the supply reaches the low-battery voltage's side."""
    from ns2exp import simadapt

    monkeypatch.setattr(simadapt, "BATTERY_S", 3.0)
    tuning = {"Lp_xy": 2.0, "Lp_z": 2.5, "Kv_xy": 4.0, "Kv_z": 4.0}
    res = simadapt.experiment(exported.gen_dir, tmp_path, tuning, seeds=(0,), swaps=1, cases=("S2S",), rings=[],
                              battery_seeds=(0,))
    rows = res["flights"]
    assert sorted((r["kind"], r["controller"]) for r in rows) == sorted(
        (k, c) for k in ("swap", "swap-solo", "battery") for c in simadapt.CONTROLLERS)
    by = {(r["kind"], r["controller"]): r for r in rows}
    # the neighbour gate off (the default, gateNbr 0): under the other robot it still learns, |NN| < wakeG
    assert by["swap", "NN+adapt"]["bottom_updated_share"] > 0.5
    solo = by["swap-solo", "NN+adapt"]
    assert solo["bottom_updated_share"] > 0.1 and solo["bottom_bias_g_at_swaps"] < -1.0
    assert all(by[k, c]["bottom_bias_g_end"] == 0.0 for k in ("swap", "swap-solo") for c in ("BL-tuned", "NN"))
    v0, v1 = by["battery", "NN"]["battery_V_start_end"]
    assert v0 == pytest.approx(4.2) and 3.2 <= v1 < 3.3   # the clean simulator starts full
    written = json.loads((tmp_path / "adapt.json").read_text())
    assert written["summary"] == res["summary"]
    assert set(written["provenance"]) == {"commit", "command", "date"} and written["provenance"]["commit"]
    assert "| S2S |" in (tmp_path / "adapt.md").read_text()
    assert len((tmp_path / "adapt.partial.jsonl").read_text().splitlines()) == len(rows)


def test_composite_arms_fly_their_track_gain(exported):
    """`ns2 sim adapt --composite G`: an arm "NN+composite G" flies NN+adapt with
    ns2adapt.trackGain = G (the other parameters the defaults); --no-baselines leaves BL-tuned
    out; every flight of the experiment is flown by every arm."""
    from ns2exp import simadapt

    arms = simadapt.controllers((2000.0, 2e4), baselines=False)
    assert arms == ("NN", "NN+adapt", "NN+composite 2000", "NN+composite 20000")
    assert simadapt._adapt_cfg("NN+composite 20000") == AdaptCfg(enable=1, track_gain=2e4)
    assert simadapt._adapt_cfg("NN+adapt") == AdaptCfg(enable=1) and simadapt._adapt_cfg("NN") is None
    js = simadapt.jobs(exported.gen_dir, {}, seeds=(0,), cases=("S2S",), rings=[], arms=arms)
    assert sorted((j["kind"], j["controller"]) for j in js) == sorted(
        (k, a) for k in ("swap", "swap-solo", "battery") for a in arms)
