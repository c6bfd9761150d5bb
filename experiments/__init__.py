"""ns2exp: the paper's experiments on the simulator and the planner.

swarm.py     swaps and rings with the C controller in the loop (Table "swap", Fig. rings)
planning/    the planning experiments (SL, SS, LL, SSL, SLL; NN vs BL), model check
margin.py    the planning margin from the model's error on held-out flights
tracking.py  flying a plan in the simulator with the firmware controller
calibrate.py the simulator's roughness fitted to the real flights, the replays compared
calibrate_tables.py  calibration.md's tables
real.py, blind.py, realscore.py, onboard_faz.py  the 2020 collection: data, scores, the
             on-board prediction reproduced

They build on the paper's reproduction (ns2paper, paper/: the authors' networks,
controller and gains, their collections, replays, flight statistics).  Both sit apart
from the product: no product module (ns2ground, the CLI's product commands) imports
ns2exp or ns2paper (tests/test_layers.py).
"""
