"""Interaction-aware motion planner (planner/): Stage 1 AO-RRT, Stage 2
SCP, outputs and tracking.  Every rule is re-checked on the result here."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from ns2plan.aorrt import AORRT, post_process
from ns2plan.dynamics import hold_arrays, step, team_substates
from ns2plan.forces import ForceModel, single_thread
from ns2plan.output import MAX_PIECES, POLY4D_BYTES, eval_pieces, poly4d_bytes, read_poly4d, write_plan
from ns2plan.problem import (JointParams, Limits, PlanningError, Problem, RelaxParams, Robot, RRTParams, SCPParams,
                             SearchParams)
from ns2plan.scp import scp
from ns2plan.verify import check_solution

RRT = RRTParams(SearchParams(max_nodes=4000, max_samples=30000), joint=JointParams(tries=0), ao_iterations=2,
                seed=3)   # the paper's Stage 1
SWAP_SL = [Robot("small", (0.0, -0.4, 1.0), (0.0, 0.4, 1.0)), Robot("large", (0.0, 0.4, 1.0), (0.0, -0.4, 1.0))]
LIMITS = Limits(pos_lo=(0.0, -0.9, 0.3), pos_hi=(0.0, 0.9, 2.0))


class StrongDownwash(torch.nn.Module):
    """Artificial downwash with the deep set's call interface: a neighbour above
    pushes down with a Gaussian plume, 40 g from a large robot, 8 g from a small one;
    with ``decay`` (m) it fades with the vertical gap dz as exp(-dz / decay)."""

    def __init__(self, cfg, small_g: float = 8.0, large_g: float = 40.0, width: float = 0.15,
                 decay: float | None = None):
        super().__init__()
        self.env = cfg.env_index
        self.amp = torch.tensor([small_g if t == "small" else large_g for t in cfg.robot_types])
        self.width, self.decay = width, decay

    def forward(self, robot_type, sample_of, nbr_type, nbr_state):
        rob = nbr_type != self.env
        s = nbr_state[rob]
        above = torch.sigmoid((s[:, 2] - 0.05) / 0.03)
        plume = torch.exp(-(s[:, 0] ** 2 + s[:, 1] ** 2) / (2 * self.width ** 2))
        contrib = -self.amp[nbr_type[rob]] * above * plume
        if self.decay is not None:
            contrib = contrib * torch.exp(-torch.clamp(s[:, 2], min=0.0) / self.decay)
        return torch.zeros(robot_type.shape[0]).index_add(0, sample_of[rob], contrib)


@pytest.fixture(scope="module")
def fm(cfg, exported):
    return ForceModel(cfg, exported.model)


@pytest.fixture(scope="module")
def stage1(cfg, fm):
    pb = Problem(cfg, SWAP_SL, LIMITS)
    with single_thread():
        return pb, AORRT(pb, fm, RRT).run()


def _fine_min_distance(pa, pb, sub=10):
    s = np.linspace(0, 1, sub + 1)[None, :, None]
    a = pa[:-1, None] + s * (pa[1:, None] - pa[:-1, None])
    b = pb[:-1, None] + s * (pb[1:, None] - pb[:-1, None])
    return float(np.linalg.norm(a - b, axis=2).min())


def _assert_team_within_limits(pb, fm, trajs):
    """verify.check_solution of a team: every force limit, clearance, box and speed."""
    for rep in check_solution(pb, fm, trajs)["robots"]:
        assert rep["worst_fa_g"] <= rep["fa_max_g"] + 1e-4 and rep["min_clearance_m"] >= 0.0
        assert rep["box_violation_m"] == 0.0 and rep["speed_violation_mps"] == 0.0


def _check_joint_paths(pb, fm, trajs, par):
    """The rules of the composite-state search (joint.py), re-checked on its paths:
    one length for all, start and goal, box, speed and action limits, dynamics exact
    with the forces stored, those forces the model's for the whole team at every
    knot, every robot within its force limit at the knots and inside the steps, and
    no pair closer than r at any time."""
    lim, kappa, types = pb.limits, pb.kappa(), pb.type_index()
    lo, hi = pb.box()
    ax = list(pb.axes)
    assert len({t.T for t in trajs}) == 1
    for i, tr in enumerate(trajs):
        assert np.allclose(tr.p[0], pb.starts()[i]) and np.linalg.norm(tr.p[-1] - pb.goals()[i]) <= par.eps_p + 1e-9
        assert np.linalg.norm(tr.v[-1]) <= par.eps_v + 1e-9
        assert np.all(tr.p[:, ax] >= lo[ax] - 1e-9) and np.all(tr.p[:, ax] <= hi[ax] + 1e-9)
        assert np.abs(tr.v).max() <= lim.v_max + 1e-9 and np.abs(tr.u).max() <= lim.u_max + 1e-9
        p1, v1 = step(tr.p[:-1], tr.v[:-1], tr.u, tr.fa[:-1], kappa[i], par.dt)
        np.testing.assert_allclose(tr.p[1:], p1, atol=1e-9)
        np.testing.assert_allclose(tr.v[1:], v1, atol=1e-9)
    P = np.stack([t.p for t in trajs], 1)
    F = fm.team_np(types, P, np.stack([t.v for t in trajs], 1))
    np.testing.assert_allclose(np.stack([t.fa for t in trajs], 1), F, atol=1e-4)
    Ps, Vs = team_substates(trajs, kappa, lim.fa_substeps)
    Fs = fm.team_np(types, Ps, Vs)
    fa_max = pb.fa_max()
    assert np.all(np.abs(F) <= fa_max + 1e-4) and np.all(np.abs(Fs) <= fa_max + 1e-4)
    r = pb.r_pair()
    for i in range(pb.n):
        for j in range(i + 1, pb.n):
            assert _fine_min_distance(P[:, i], P[:, j]) >= r[i, j] - 1e-9


def test_stage1_path_respects_every_validity_rule(cfg, fm, stage1):
    pb, res = stage1
    lim, par = pb.limits, RRT.search
    r, fa_max, kappa = pb.r_pair(), pb.fa_max(), pb.kappa()
    lo, hi = pb.box()
    types = pb.type_index()
    assert all(t is not None for t in res.trajs) and res.accept_history
    for i, tr in enumerate(res.trajs):
        assert np.allclose(tr.p[0], pb.starts()[i]) and np.allclose(tr.v[0], 0.0)
        assert np.linalg.norm(tr.p[-1] - pb.goals()[i]) <= par.eps_p + 1e-9
        assert np.linalg.norm(tr.v[-1]) <= par.eps_v + 1e-9
        assert np.all(tr.p[:, 1:] >= lo[1:] - 1e-9) and np.all(tr.p[:, 1:] <= hi[1:] + 1e-9)
        assert np.all(tr.p[:, 0] == 0.0) and np.all(tr.u[:, 0] == 0.0)      # yz plane
        assert np.abs(tr.v).max() <= lim.v_max + 1e-9 and np.abs(tr.u).max() <= lim.u_max + 1e-9
    # every accepted plan: dynamics with the learned force it was planned with, that
    # force equal to the model's with the team of that moment, and for every
    # neighbour the bound and the trust region on the change of ITS force
    H = par.max_steps
    costs = {}
    for it, i, cost, P0, V0, FA0, relaxed0, tr in res.accept_history:
        p1, v1 = step(tr.p[:-1], tr.v[:-1], tr.u, tr.fa[:-1], kappa[i], par.dt)
        np.testing.assert_allclose(tr.p[1:], p1, atol=1e-9)
        np.testing.assert_allclose(tr.v[1:], v1, atol=1e-9)
        planned = np.array([np.any(FA0[:, j] != 0) or np.any(P0[1:, j] != P0[0, j]) for j in range(pb.n)])
        planned[i] = False
        P, V = P0.copy(), V0.copy()
        P[:, i], V[:, i] = hold_arrays(tr, H)
        present = np.repeat(np.where(np.arange(pb.n) == i, True, planned)[None], H + 1, 0)
        F = fm.team_np(types, P, V, present)
        np.testing.assert_allclose(tr.fa, F[:tr.T + 1, i], atol=1e-4)
        assert np.abs(F[:, i]).max() <= fa_max[i] + 1e-4
        for j in np.flatnonzero(planned):
            assert np.abs(F[:, j]).max() <= fa_max[j] + 1e-4
            if not relaxed0[j]:         # a relaxed placeholder's forces are no reference
                assert np.abs(F[:, j] - FA0[:, j]).max() <= lim.b_fa_g + 1e-4
            assert _fine_min_distance(P[:, i], P[:, j]) >= r[i, j] - 1e-9
        assert cost < costs.get(i, np.inf)              # AO-RRT: decreasing cost bound
        costs[i] = cost
    # the final team: joint forces within the limits, no collision
    chk = check_solution(pb, fm, res.trajs)
    for i, rep in enumerate(chk["robots"]):
        assert rep["worst_fa_g"] <= fa_max[i] + 1e-4
    P = np.stack([hold_arrays(tr, H)[0] for tr in res.trajs])
    assert _fine_min_distance(P[0], P[1]) >= r[0, 1] - 1e-9
    # the tree only holds valid nodes within the cost bound
    assert any(tree is not None for tree in res.trees)
    for i, tree in enumerate(res.trees):
        if tree is None:            # a promoted relaxed path has no valid tree
            assert any(r == i for _, r in res.promotions)
            continue
        assert np.abs(tree.fa).max() <= fa_max[i] + 1e-9 and np.abs(tree.v).max() <= lim.v_max + 1e-9


@pytest.fixture(scope="module")
def refined(fm, stage1):
    pb, res = stage1
    init = post_process(res.trajs, pb.kappa())
    with single_thread():
        return pb, init, scp(pb, fm, init, SCPParams(max_iterations=6, seed=1))


def test_scp_decreases_cost_monotonically_and_reaches_goal(cfg, fm, refined):
    pb, init, out = refined
    assert len({t.T for t in init}) == 1 and all(t.T == init[0].T for t in out.trajs)
    m = np.array(out.merit_history)
    assert len(m) >= 3 and np.all(np.diff(m) <= 1e-9), m
    assert m[-1] < 0.5 * m[0], m
    chk = check_solution(pb, fm, out.trajs)
    for i, rep in enumerate(chk["robots"]):
        assert rep["goal_error_m"] < 0.01 and rep["goal_speed_mps"] < 0.02, rep
        assert rep["max_defect"] < 1e-3, rep
        assert rep["worst_fa_g"] <= rep["fa_max_g"] + 0.05, rep
        assert rep["min_clearance_m"] > -0.005 and rep["box_violation_m"] < 1e-3, rep
        assert rep["action_violation"] < 1e-6, rep
    # the effort is lower than that of the jerky Stage-1 trajectories
    assert sum((t.u ** 2).sum() for t in out.trajs) < sum((t.u ** 2).sum() for t in init)


@pytest.mark.parametrize("dims, name, model", [(2, "SSL", "NN"), (3, "SLL", "NN"), (2, "SLL", "BL"), (3, "SSL", "BL")])
def test_parametrized_scp_plans_as_the_rebuilt_program(cfg, fm, dims, name, model):
    """Stage 2's one DPP program per run (SCPParams.program "parametrized", the default)
    gives the plans of the program rebuilt at every solve ("rebuilt") within the
    solver's tolerance, on the paper's three-robot cases with the model and with f_a = 0:
    the same iterations and solves, the same merits, the same trajectories."""
    from ns2exp.planning import scenario_problem
    from ns2plan.scp import _Stage2

    pb = scenario_problem(cfg, name, dims)
    fm = fm if model == "NN" else ForceModel(cfg, None)
    with single_thread():
        s1 = AORRT(pb, fm, RRTParams(SearchParams(max_nodes=4000, max_samples=20000), ao_iterations=1, seed=0)).run()
        init = post_process(s1.trajs, pb.kappa())
        prog = _Stage2(pb, init[0].T, init[0].dt, SCPParams(), not fm.is_zero)
        assert prog.problem.is_dpp()
        old, new = (scp(pb, fm, init, SCPParams(max_iterations=3, program=p)) for p in ("rebuilt", "parametrized"))
    assert old.iterations == new.iterations and old.profile["solves"] == new.profile["solves"]
    assert new.profile["linearizations"] <= new.profile["solves"] == old.profile["linearizations"]
    np.testing.assert_allclose(new.merit_history, old.merit_history, rtol=1e-4)
    for a, b in zip(old.trajs, new.trajs):
        np.testing.assert_allclose(b.p, a.p, atol=1e-4)
        np.testing.assert_allclose(b.v, a.v, atol=1e-4)
        np.testing.assert_allclose(b.u, a.u, atol=1e-3)
        np.testing.assert_allclose(b.fa, a.fa, atol=1e-3)
    assert old.max_defect == pytest.approx(new.max_defect, abs=1e-4)


def test_plan_output_and_tracking(cfg, exported, refined, tmp_path):
    from ns2exp.tracking import track

    pb, _, out = refined
    rep = write_plan(tmp_path, out.trajs, [r.type for r in pb.robots], pb.kappa())
    for i, tr in enumerate(out.trajs):
        name = f"robot{i}_{pb.robots[i].type}"
        pieces = read_poly4d((tmp_path / f"{name}.bin").read_bytes())
        assert rep[name]["pieces"] == len(pieces) and rep[name]["fits_trajectory_memory"]
        p, v = eval_pieces(pieces, tr.t)
        assert np.abs(p - tr.p).max() < 2e-3 and np.abs(v - tr.v).max() < 0.05
        csv = (tmp_path / f"{name}.csv").read_text().splitlines()
        assert csv[0].startswith("Duration,x^0") and len(csv) == len(pieces) + 1
        assert abs(sum(float(l.split(",")[0]) for l in csv[1:]) - tr.T * tr.dt) < 1e-6
    rows = (tmp_path / "setpoints.csv").read_text().splitlines()
    assert rows[0].startswith("t_s,robot,type,x,y,z")
    last = [l for l in rows[1:] if l.split(",")[1] == "robot0_small"][-1].split(",")
    assert np.allclose([float(x) for x in last[3:6]], out.trajs[0].p[-1], atol=1e-5)
    # flown by the C controller with the simulator's true interactions
    res = track(pb, out.trajs, exported.gen_dir)
    assert max(res["worst_error_m"]) < 0.15, res["worst_error_m"]
    assert res["log"]["t"][-1] >= 1.0 + out.trajs[0].T * out.trajs[0].dt


def _crossing_z(trajs):
    """z_small - z_large where the two robots are closest in y (finished robots rest)."""
    H = max(t.T for t in trajs)
    a, b = hold_arrays(trajs[0], H)[0], hold_arrays(trajs[1], H)[0]
    dy = np.abs(a[:, 1] - b[:, 1])
    k = int(dy.argmin())
    return a[k, 2] - b[k, 2], dy


def test_homotopy_keeps_small_robot_out_from_under_the_large_one(cfg):
    pb = Problem(cfg, SWAP_SL, LIMITS)
    nn = ForceModel(cfg, StrongDownwash(cfg))
    # the artificial model: 40 g under a large robot, 8 g under a small one
    P = np.array([[[0, 0, 1.0], [0, 0, 1.3]]])
    F = nn.team_np(pb.type_index(), P, np.zeros_like(P))[0]
    assert F[0] < -30 and F[1] == pytest.approx(0.0, abs=0.5)
    F = nn.team_np(pb.type_index(), P[:, ::-1], np.zeros_like(P))[0]
    assert -9 < F[1] < -6
    from ns2plan.planner import plan

    res = plan(pb, nn, RRT, SCPParams(max_iterations=4))
    for trajs in (res.stage1.trajs, res.trajs):
        dz, dy = _crossing_z(trajs)
        assert dz > 0.15, dz                     # the small robot passes above
        P = np.stack([hold_arrays(t, 200)[0] for t in trajs], 1)
        under = (np.abs(P[:, 0, 1] - P[:, 1, 1]) < 0.3) & (P[:, 0, 2] < P[:, 1, 2])
        assert not under.any()
    chk = check_solution(pb, nn, res.trajs)
    assert all(r["worst_fa_g"] <= r["fa_max_g"] + 0.05 for r in chk["robots"])
    # without the model (BL) the planner does not know: over a few seeds it also
    # sends the small robot under the large one
    below = []
    for seed in range(4):
        with single_thread():
            s1 = AORRT(pb, ForceModel(cfg, None), RRTParams(SearchParams(max_nodes=4000), joint=JointParams(tries=0),
                                                            ao_iterations=1, seed=seed)).run()
        below.append(_crossing_z(s1.trajs)[0] < 0)
    assert any(below), below


def test_relax_and_repair_solves_a_crossing_that_needs_both_robots_to_deviate(cfg):
    """Two large robots swap in the yz plane; the lower one stays within 10 g only with
    a vertical gap >= 0.55 m at the crossing, and in the box z in [0.55, 1.45] each can
    leave z = 1 by 0.45 m only: neither the first-planned robot's path nor the second's
    alone can open the gap.  Sequential planning alone fails; relax-and-repair (the
    second robot's relaxed path, the first re-planned to make room for it, the relaxed
    path promoted) finds a team that respects every limit, checked on the result."""
    lim = Limits(pos_lo=(0.0, -0.9, 0.55), pos_hi=(0.0, 0.9, 1.45))
    pb = Problem(cfg, [Robot("large", (0.0, -0.4, 1.0), (0.0, 0.4, 1.0)),
                       Robot("large", (0.0, 0.4, 1.0), (0.0, -0.4, 1.0))], lim)
    fm = ForceModel(cfg, StrongDownwash(cfg, large_g=30.0, decay=0.5))   # 10 g under a large robot at 0.55 m
    P = np.array([[[0, 0, 1.0], [0, 0, 1.55]]])
    assert fm.team_np(pb.type_index(), P, np.zeros_like(P))[0, 0] == pytest.approx(-10.0, abs=0.2)
    par = RRTParams(SearchParams(max_nodes=4000, max_samples=20000), joint=JointParams(tries=0), max_rounds=6,
                    ao_iterations=1, seed=5)
    with single_thread():
        with pytest.raises(PlanningError, match="no path found"):
            AORRT(pb, fm, replace(par, relax=RelaxParams(levels_g=()))).run()
        res = AORRT(pb, fm, par).run()
    assert res.relaxations              # the relaxed path was needed
    _assert_team_within_limits(pb, fm, res.trajs)
    dz, _ = _crossing_z(res.trajs)
    assert abs(dz) >= 0.5                       # the gap is open where they cross ...
    H = max(t.T for t in res.trajs)
    P = np.stack([hold_arrays(t, H)[0] for t in res.trajs], 1)
    k = int(np.abs(P[:, 0, 1] - P[:, 1, 1]).argmin())
    assert P[k, :, 2].max() > 1.05 and P[k, :, 2].min() < 0.95   # ... because both left z = 1
    for it, i, cost, P0, V0, FA0, relaxed0, tr in res.accept_history:
        p1, v1 = step(tr.p[:-1], tr.v[:-1], tr.u, tr.fa[:-1], pb.kappa()[i], par.search.dt)
        np.testing.assert_allclose(tr.p[1:], p1, atol=1e-9)      # promoted paths: dynamics exact
        assert np.abs(tr.u).max() <= lim.u_max + 1e-9


def test_joint_search_solves_an_exchange_that_sequential_planning_cannot(cfg):
    """Three robots (small, large, large) rotate places in the yz plane under a strong
    downwash that fades slowly with the gap: the large robot that crosses both others
    must pass under them while they climb out of its way, in turn.  Sequential planning
    with relax-and-repair finds no team in 4 rounds; the composite-state search
    (joint.py) does, and its paths and the final team respect every limit."""
    pb = Problem(cfg, [Robot("small", (0.0, -0.4, 1.0), (0.0, 0.0, 1.0)),
                       Robot("large", (0.0, 0.0, 1.0), (0.0, 0.4, 1.0)),
                       Robot("large", (0.0, 0.4, 1.0), (0.0, -0.4, 1.0))], LIMITS)
    fm = ForceModel(cfg, StrongDownwash(cfg, large_g=30.0, decay=0.7))   # 10 g under a large robot at 0.77 m
    par = RRTParams(SearchParams(max_nodes=4000, max_samples=20000), max_rounds=4, ao_iterations=1, seed=3)
    with single_thread():
        with pytest.raises(PlanningError, match="no path found"):
            AORRT(pb, fm, replace(par, joint=JointParams(tries=0))).run()
        res = AORRT(pb, fm, par).run()
    assert res.joint_round == 0 and res.joint_samples > 0
    _check_joint_paths(pb, fm, res.joint_trajs, par.search)
    _assert_team_within_limits(pb, fm, res.trajs)


def test_margin_by_relative_speed_is_kept(cfg):
    """A margin conditioned on the relative speed (issue 24): Stage 1 and SCP keep every
    robot within f_a,max less the margin at its relative speed; the plan made with the
    margin at rest only breaks that bound (a large robot under the small one while they
    move apart), so the check has teeth."""
    from ns2plan.planner import plan

    tab = {"small": {"speeds_mps": [0.3], "margins_g": [0.5, 4.0]},
           "large": {"speeds_mps": [0.3], "margins_g": [0.5, 9.0]}}
    pb = Problem(cfg, SWAP_SL, replace(LIMITS, fa_margin_g=tab))
    fm = ForceModel(cfg, StrongDownwash(cfg))
    par = RRTParams(SearchParams(max_nodes=4000, max_samples=20000), ao_iterations=1, seed=2)
    with single_thread():
        res = plan(pb, fm, par, SCPParams(max_iterations=4))
        rest = plan(Problem(cfg, SWAP_SL, replace(LIMITS, fa_margin_g=0.5)), fm, par, SCPParams(max_iterations=4))
    for trajs in (res.stage1.trajs, res.trajs):
        for rep in check_solution(pb, fm, trajs)["robots"]:
            assert rep["fa_over_bound_g"] <= 1e-4, rep
    assert max(r["fa_over_bound_g"] for r in check_solution(pb, fm, rest.trajs)["robots"]) > 1.0


def test_force_margin_and_clearance_are_kept(cfg):
    """Limits.fa_margin_g: the planner keeps f_a,max - margin (Stage 1 and SCP);
    Limits.clearance_m: every pair stays that much beyond the tight spheres."""
    lim = Limits(pos_lo=LIMITS.pos_lo, pos_hi=LIMITS.pos_hi, fa_margin_g=1.5, clearance_m=0.1)
    pb = Problem(cfg, SWAP_SL, lim)
    tight = Problem(cfg, SWAP_SL, LIMITS)
    np.testing.assert_allclose(pb.fa_plan(), pb.fa_max() - 1.5)
    np.testing.assert_allclose(pb.r_pair(), tight.r_pair() + 0.1)
    fm = ForceModel(cfg, StrongDownwash(cfg))
    from ns2plan.planner import plan

    res = plan(pb, fm, RRTParams(SearchParams(max_nodes=4000, max_samples=20000), ao_iterations=1, seed=2),
               SCPParams(max_iterations=4))
    prof = res.profile()          # where the time went: counts that must agree with the result
    assert prof["scp_iterations"] == res.stage2.iterations >= 1
    assert prof["convex_solves"] >= prof["scp_iterations"] * pb.n
    # knots and inside-step points per linearization, at most one per solve (none after a rejected step)
    assert prof["force_jacobians"] == 2 * prof["scp_linearizations"]
    assert prof["scp_linearizations"] <= prof["convex_solves"]
    assert prof["force_queries"] >= prof["force_calls"] > 0
    assert 0 < prof["cp_solver_s"] <= prof["stage2_s"] and prof["stage1_joint_s"] <= prof["stage1_s"]
    for trajs in (res.stage1.trajs, res.trajs):
        chk = check_solution(pb, fm, trajs)
        for i, rep in enumerate(chk["robots"]):
            assert rep["worst_fa_g"] <= rep["fa_max_g"] - 1.5 + 0.05, rep
            assert rep["min_clearance_m"] >= -1e-6     # measured against r_pair, clearance included
    for bad, msg in (({"fa_margin_g": -1.0}, "fa_margin_g"), ({"fa_margin_g": 5.0}, "fa_margin_g must be positive"),
                     ({"clearance_m": -0.1}, "clearance_m")):
        with pytest.raises(PlanningError, match=msg):
            Problem(cfg, SWAP_SL, Limits(pos_lo=LIMITS.pos_lo, pos_hi=LIMITS.pos_hi, **bad)).validate()


def test_planning_model_sees_the_long_range_downwash(cfg):
    """One volume policy for control and planning: the config's volumes reach over
    the planner's whole height range (no private widening for the planner)."""
    import ns2exp.planning as ex

    assert not hasattr(ex, "planning_config")
    height = ex.LIMITS_3D.pos_hi[2] - ex.LIMITS_3D.pos_lo[2]
    for r in range(cfg.num_robot_types):
        for t in range(cfg.num_robot_types):
            lo, hi = cfg.volume(r, t)
            assert hi[2] >= height and hi[2] <= cfg.input_box(t)[2][1]   # inside the input box (not clamped)


def test_bad_input_is_refused_quickly(cfg):
    fm = ForceModel(cfg, StrongDownwash(cfg))
    with pytest.raises(PlanningError, match="collision at the start"):
        Problem(cfg, [Robot("small", (0, 0, 1), (0, 0.5, 1)), Robot("large", (0, 0.1, 1), (0, -0.5, 1))],
                LIMITS).validate()
    with pytest.raises(PlanningError, match="outside the state box"):
        AORRT(Problem(cfg, [Robot("small", (0, 0, 1), (0, 0, 3.0))], LIMITS), fm).run()
    with pytest.raises(PlanningError, match="infeasible limits"):
        AORRT(Problem(cfg, [Robot("small", (0, 0, 1.0), (0, 0.5, 1)), Robot("large", (0, 0.05, 1.3), (0, -0.5, 1.5))],
                      LIMITS), fm).run()
    with pytest.raises(PlanningError, match="infeasible limits"):
        Problem(cfg, SWAP_SL, Limits(pos_lo=LIMITS.pos_lo, pos_hi=LIMITS.pos_hi, v_max=0.0)).validate()
    # bounded by counts, not by time: the refusal comes after max_rounds rounds of at
    # most max_samples samples each (no test asserts on wall-clock time; see benchmarks)
    slow = Limits(pos_lo=LIMITS.pos_lo, pos_hi=LIMITS.pos_hi, v_max=0.02)   # goal out of reach in H steps
    with pytest.raises(PlanningError, match="no path found .* in 2 rounds"):
        AORRT(Problem(cfg, SWAP_SL[:1], slow), fm, RRTParams(SearchParams(max_samples=3000), max_rounds=2)).run()
    # the wall-clock safety net: an absurd sample budget still ends, with a clear message
    with pytest.raises(PlanningError, match="safety time limit"):
        AORRT(Problem(cfg, SWAP_SL[:1], slow), fm,
              RRTParams(SearchParams(max_samples=10 ** 9, time_s=0.3), total_time_s=0.8)).run()
    # parameters are refused where they are constructed
    with pytest.raises(PlanningError, match="max_samples must be a positive integer"):
        SearchParams(max_samples=0)
    with pytest.raises(PlanningError, match="tries must be an integer >= 0"):
        JointParams(tries=-1)
    with pytest.raises(PlanningError, match="dt must be a finite number > 0"):
        SearchParams(dt=float("nan"))
    with pytest.raises(PlanningError, match="ao_iterations must be a positive integer"):
        RRTParams(ao_iterations=0)
    with pytest.raises(PlanningError, match="levels_g must be positive"):
        RelaxParams(levels_g=(2.0, -1.0))
    with pytest.raises(PlanningError, match="max_iterations must be a positive integer"):
        SCPParams(max_iterations=1.5)
    with pytest.raises(PlanningError, match="b_p must be a finite number > 0"):
        SCPParams(b_p=0.0)


def test_stage1_is_deterministic_for_a_seed(cfg, fm):
    """Counted stopping rules: the same seed gives the same Stage 1 output, however
    generous the wall-clock safety nets (so on any machine, at any load)."""
    pb = Problem(cfg, SWAP_SL, LIMITS)
    par = RRTParams(SearchParams(max_nodes=3000, max_samples=8000), ao_iterations=2, seed=11)
    runs = []
    for p in (par, replace(par, search=replace(par.search, time_s=1e6), total_time_s=1e6), replace(par, seed=12)):
        with single_thread():
            runs.append(AORRT(pb, fm, p).run())
    a, b, c = runs
    assert not a.hit_time_limit and not b.hit_time_limit
    assert a.order_history == b.order_history and a.costs == b.costs and a.samples_per_robot == b.samples_per_robot
    for ta, tb in zip(a.trajs, b.trajs):
        assert ta.T == tb.T
        for name in ("p", "v", "u", "fa"):
            assert np.array_equal(getattr(ta, name), getattr(tb, name)), name
    # another seed gives another plan (the comparison above can fail)
    assert a.costs != c.costs or any(ta.T != tc.T or not np.array_equal(ta.p, tc.p) for ta, tc in zip(a.trajs, c.trajs))


def test_poly4d_layout_matches_the_firmware_struct(tmp_path):
    """struct poly4d { float p[4][8]; float duration; }: x, y, z, yaw coefficients in
    ascending powers, then the duration, 132 bytes little-endian per piece; the stock
    4096-byte trajectory memory holds 31 pieces."""
    import struct

    c = np.arange(32, dtype=float).reshape(4, 8) / 8.0
    data = poly4d_bytes([(0.5, c), (0.25, -c)])
    assert POLY4D_BYTES == 132 and len(data) == 264 and MAX_PIECES == 31
    assert struct.unpack_from("<8f", data, 0) == tuple(c[0])          # x^0..x^7
    assert struct.unpack_from("<8f", data, 3 * 32) == tuple(c[3])     # yaw
    assert struct.unpack_from("<f", data, 128) == (0.5,) and struct.unpack_from("<f", data, 132 + 128) == (0.25,)
    back = read_poly4d(data)
    assert back[1][0] == 0.25 and np.array_equal(back[1][1], -c)
    with pytest.raises(ValueError, match="poly4d piece"):
        poly4d_bytes([(0.5, c[:3])])
    with pytest.raises(ValueError, match="poly4d piece"):
        poly4d_bytes([(0.0, c)])


def test_cli_plan_problem_file(cfg, exported, tmp_path):
    from click.testing import CliRunner

    from ns2cli import main

    prob = {"robots": [{"type": "small", "start": [0, -0.4, 1.0], "goal": [0, 0.4, 1.0]}],
            "axes": "yz", "limits": {"pos_lo": [0, -0.9, 0.3], "pos_hi": [0, 0.9, 2.0]}}
    f = tmp_path / "p.json"
    f.write_text(json.dumps(prob))
    r = CliRunner().invoke(main, ["plan", "--problem", str(f), "--checkpoint", str(exported.checkpoint),
                                  "--out", str(tmp_path / "out"), "--time-limit", "20"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "out" / "robot0_small.bin").is_file() and (tmp_path / "out" / "setpoints.csv").is_file()
    assert json.loads((tmp_path / "out" / "plan.json").read_text())["valid"] is True
    prob["robots"].append({"type": "large", "start": [0, -0.35, 1.0], "goal": [0, 0.0, 1.0]})
    f.write_text(json.dumps(prob))
    r = CliRunner().invoke(main, ["plan", "--problem", str(f), "--checkpoint", str(exported.checkpoint),
                                  "--out", str(tmp_path / "out2")])
    assert r.exit_code != 0 and "collision at the start" in r.output, r.output
    prob["robots"][1]["start"] = [0, 0.4, 5.0]
    f.write_text(json.dumps(prob))
    r = CliRunner().invoke(main, ["plan", "--problem", str(f), "--checkpoint", str(exported.checkpoint),
                                  "--out", str(tmp_path / "out3")])
    assert r.exit_code != 0 and "outside the state box" in r.output, r.output
    for bad in ("abc", "-1", "nan"):                 # the experiments' margin: grams, 'measured' or 'calibrated'
        r = CliRunner().invoke(main, ["plan", "--checkpoint", str(exported.checkpoint), "--out", str(tmp_path / "o4"),
                                      "--fa-margin", bad])
        assert r.exit_code == 2 and "--fa-margin" in r.output and not (tmp_path / "o4").exists(), r.output
    # --plan-data-rounds trains on the checkpoint's own data: one without it is refused before any flight
    r = CliRunner().invoke(main, ["plan", "--checkpoint", str(exported.checkpoint), "--out", str(tmp_path / "o5"),
                                  "--plan-data-rounds", "1"])
    assert r.exit_code == 1 and f"{exported.checkpoint}: data_files:" in r.output, r.output
    assert not (tmp_path / "o5").exists()


def test_nearest_is_the_brute_force_nearest_across_rebuilds():
    """ns2plan.nearest.Nearest: a growing set of nodes queried in batches, through many
    rebuilds of its kd-tree, answers exactly what brute force over every node does."""
    from ns2plan.nearest import STALE_FRACTION, Nearest

    rng = np.random.default_rng(5)
    keys = rng.random((6000, 7))
    nn, n, rebuilds, last = Nearest(keys), 1, 0, None
    while n < len(keys):
        q = rng.random((32, 7))
        got = nn.query(q, n)
        want = np.linalg.norm(q[:, None, :] - keys[None, :n], axis=2).argmin(1)
        assert np.array_equal(got, want)
        rebuilds += nn.built != last
        last = nn.built
        n += 10
    assert rebuilds > 10 and STALE_FRACTION > 4
