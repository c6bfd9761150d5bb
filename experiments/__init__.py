"""ns2exp: the paper's experiments on the simulator and the planner.

swarm.py     swaps and rings with the C controller in the loop (Table "swap", Fig. rings)
planning.py  the planning experiments (SL, SS, LL, SSL, SLL; NN vs BL), model check
margin.py    the planning margin from the model's error on held-out flights
tracking.py  flying a plan in the simulator with the firmware controller
"""
