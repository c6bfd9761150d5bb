"""Algorithm "planning": Stage 1 (AO-RRT), PostProcess (uniform length), Stage 2 (SCP)."""
from __future__ import annotations

from dataclasses import dataclass, field

from .aorrt import AORRT, Stage1Result, post_process
from .forces import ForceModel, single_thread
from .problem import Problem, RRTParams, SCPParams
from .scp import SCPResult, scp


@dataclass
class PlanResult:
    stage1: Stage1Result
    initial: list           # Stage 1 after post-processing (uniform length)
    stage2: SCPResult

    @property
    def trajs(self) -> list:
        return self.stage2.trajs

    forces: dict = field(default_factory=dict)   # ForceModel.counts of this plan (both stages)

    def timings(self) -> dict:
        return {"stage1_s": self.stage1.time_s, "stage2_s": self.stage2.time_s,
                "stage1_per_robot_s": self.stage1.time_per_robot_s,
                "stage2_per_robot_s": self.stage2.time_per_robot_s}

    def profile(self) -> dict:
        """Where the planning time went: Stage 1's search (per-robot trees and the
        composite-state search), Stage 2's iterations and convex solves (program
        build or parameter setting with the Jacobians, cvxpy canonicalization, the
        solver itself; the linearizations: one per solve with the rebuilt program, one
        per new team solution with the parametrized one), and the learned-force
        evaluations of both stages."""
        s2 = self.stage2.profile
        return {"stage1_s": self.stage1.time_s, "stage1_joint_s": self.stage1.joint_time_s,
                "stage1_samples": int(sum(self.stage1.samples_per_robot)) + self.stage1.joint_samples,
                "stage2_s": self.stage2.time_s, "scp_iterations": self.stage2.iterations,
                "convex_solves": int(s2.get("solves", 0)), "scp_linearizations": int(s2.get("linearizations", 0)),
                "cp_build_s": s2.get("build_s", 0.0),
                "cp_canon_s": s2.get("canon_s", 0.0), "cp_solver_s": s2.get("solver_s", 0.0),
                "force_calls": self.forces.get("calls", 0), "force_queries": self.forces.get("queries", 0),
                "force_forward_s": self.forces.get("forward_s", 0.0), "force_jacobians": self.forces.get("jacobians", 0),
                "force_backward_s": self.forces.get("backward_s", 0.0)}


def plan(pb: Problem, fm: ForceModel, rrt: RRTParams = RRTParams(), scp_params: SCPParams = SCPParams()) -> PlanResult:
    fm.reset_counts()
    with single_thread():
        s1 = AORRT(pb, fm, rrt).run()
        initial = post_process(s1.trajs, pb.kappa())
        s2 = scp(pb, fm, initial, scp_params)
    return PlanResult(s1, initial, s2, dict(fm.counts))
