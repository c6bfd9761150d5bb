"""Data as the paper builds it, from simulated flights: labels from the logs vs the
simulator's ground truth, and the learned term beating the baseline on a swap."""
import numpy as np
import pytest

from ns2codegen.checkpoint import save_checkpoint
from ns2codegen.data.labels import residual_force
from ns2codegen.export import export
from ns2codegen.train import train
from ns2host.sim.cloop import CLoopSwarm
from ns2host.sim.collect import collect
from ns2host.sim.scenarios import swap
from ns2host.sim.vehicle import G, vehicle


def test_labels_from_logs_match_the_ground_truth(cfg, exported):
    """f_a = m v_dot - m g - R f_u from the logged v, q, PWM and voltage (five-point
    differentiation, psi_1 with the motor delay) against the simulator's true f_a."""
    sp, start = swap(2, [0.5, 0.8], radius=0.4, duration=2.5, rest=0.5)
    log = CLoopSwarm(cfg, ["small", "large"], exported.gen_dir, start, aero=True).run(6.0, sp)
    for i, kind in enumerate(["small", "large"]):
        veh = vehicle(cfg, kind)
        fa = residual_force(log["t"], log["v"][:, i], log["q"][:, i], log["pwm"][:, i], log["battery_V"][:, i],
                            veh.mass, veh.psi1, veh.lam)
        ok = ~np.isnan(fa[:, 2])
        assert ok.sum() == len(fa) - 4
        err_g = (fa[ok] - log["truth_fa"][ok, i]) * 1000.0 / G
        rms = np.sqrt((err_g ** 2).mean(axis=0))
        print(f"{kind}: label error rms {rms} g, max {np.abs(err_g).max(axis=0)} g")
        assert rms[2] < 0.5 and np.abs(err_g[:, 2]).max() < 6.0
    assert log["truth_fa"][:, 0, 2].min() * 1000 / G < -9.0  # the swap did produce strong downwash (-11 g)


@pytest.fixture(scope="module")
def sim_trained(cfg, exported, tmp_path_factory):
    # every team of the paper's 12 scenarios, 20 s each: with the flow-based truth a
    # model of one pair's 40 s (S, L, SL) did not carry over to the swap below
    ds = collect(cfg, exported.gen_dir, 20.0, seed=3, workers=2)   # the same data as one worker (tested)
    model, report = train(cfg, ds, epochs=20, seed=0)
    root = tmp_path_factory.mktemp("sim_model")
    save_checkpoint(root / "m.pt", model, cfg, {"seed": 0, "data_hash": ds.content_hash(), "report": report})
    export(root / "m.pt", root / "gen")
    return ds, report, root / "gen"


def test_collected_data_set(sim_trained):
    ds, report, _ = sim_trained
    assert len(set(ds.scenario_names)) == 12 and {"S", "L", "L->S", "{L,L}->S"} <= set(ds.scenario_names)
    # labels carry differentiation noise (from the EKF's velocity estimate, as on the
    # drone), and most samples have no neighbour: the
    # validation error stays well below the label variance, not near zero
    assert report["validation"]["mse"] < 0.75 * report["validation"]["label_var"]


@pytest.mark.parametrize("learned", ["float", "fixed"])
def test_learned_term_beats_the_baseline_on_a_swap(cfg, sim_trained, learned):
    """L2S: a small robot swapping 0.3 m under a large one (seeded, 2 swaps)."""
    _, _, gen = sim_trained
    worst = {}
    for mode in (None, learned):
        sp, start = swap(2, [0.5, 0.8], radius=0.4, duration=2.5, rest=0.5, seed=7)
        log = CLoopSwarm(cfg, ["small", "large"], gen, start, aero=True, learned=mode).run(6.0, sp)
        worst[mode] = np.abs(log["truth_p"][:, 0, 2] - log["p_d"][:, 0, 2]).max()
    print("worst-case z error of the small robot:", worst)
    assert worst[learned] < 0.7 * worst[None]
