"""ns2host.sim: the quadrotor swarm simulator (RotorPy-style: one module per concern).

vehicle.py    vehicle parameters (those of ns2codegen.vehicle), actuation matrix B0
dynamics.py   rigid-body dynamics with the first-order motor delay, eq. (dynamics),
              vectorized over robots, RK4 in C (host/ns2_sim.c)
aero.py       the ground-truth interaction forces (wakes combined as flows, rotor
              response, ground, drag)
calibration.py  the ground truth against the paper's points (docs/ground-truth.md)
volumes.py    the interaction-volume policy checked against the ground truth
sensing.py    what a Crazyflie senses: mocap (rate, noise, latency, loss), IMU (noise,
              bias), the EKF's measurement noise; sources in docs/sensing.md
cloop.py      C-in-the-loop: every robot as a Crazyflie at 1 kHz (host/ns2_fly.c): IMU,
              the firmware's EKF, the app's code path ns2_pilot or the firmware's Mellinger
scenarios.py  swaps, random walks, the paper's intertwined rings, near-field passes
collect.py    data collection: simulated flights -> uSD logs -> labelled data set
usdlogs.py    the simulator's flight logs as Crazyflie uSD-card files
planmodel.py  the planning model `ns2 plan` trains on simulated flights without a checkpoint
"""
