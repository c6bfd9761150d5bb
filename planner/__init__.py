"""ns2plan: interaction-aware multi-robot motion planning (paper, section "Interaction-Aware
Multi-Robot Planning", Algorithm "planning"), one module per concern:

problem.py      robots, start/goal, limits and planner parameters as plain data,
                validated where constructed (Stage 1: RRTParams with its SearchParams,
                RelaxParams, JointParams; Stage 2: SCPParams)
forces.py       the learned interaction force f_a,z-hat of every robot from its
                neighbour set (the deep set, or f_a = 0 for the baseline), batched,
                with torch autograd Jacobians
dynamics.py     double integrator + learned force, eqs. (planning-dynamics) and
                (planning-discreteDynamics); team forces along trajectories
aorrt.py        Stage 1: sequential AO-RRT with the others as dynamic obstacles
joint.py        Stage 1 fallback: one RRT in the composite state of the whole team
nearest.py      FindClosest of both RRTs: kd-tree plus brute force over the newest nodes
scp.py          Stage 2: sequential convex programming, eq. (scp), one parametrized (DPP)
                cvxpy program per run, solved by Clarabel
verify.py       independent check of a team solution (box, collisions, force bounds)
planner.py      Algorithm "planning": Stage 1, post-processing, Stage 2, timings
output.py       Crazyflie piecewise polynomials (high-level commander upload), CSV
problemfile.py  problem files (`ns2 plan --problem`): JSON -> a validated Problem, planned
"""
