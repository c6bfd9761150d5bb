"""Algorithm "planning": Stage 1 (AO-RRT), PostProcess (uniform length), Stage 2 (SCP)."""
from __future__ import annotations

from dataclasses import dataclass

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

    def timings(self) -> dict:
        return {"stage1_s": self.stage1.time_s, "stage2_s": self.stage2.time_s,
                "stage1_per_robot_s": self.stage1.time_per_robot_s,
                "stage2_per_robot_s": self.stage2.time_per_robot_s}


def plan(pb: Problem, fm: ForceModel, rrt: RRTParams = RRTParams(), scp_params: SCPParams = SCPParams()) -> PlanResult:
    with single_thread():
        s1 = AORRT(pb, fm, rrt).run()
        initial = post_process(s1.trajs, pb.kappa())
        s2 = scp(pb, fm, initial, scp_params)
    return PlanResult(s1, initial, s2)
