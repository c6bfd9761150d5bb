"""Quadrotor swarm simulator (RotorPy-style: one module per concern).

vehicle.py   parameters from the config file, actuation matrix B0, motor maps
dynamics.py  rigid-body dynamics with the first-order motor delay, eq. (dynamics),
             vectorized over robots, RK4
cloop.py     C-in-the-loop: the firmware controller (built for the host) per robot
"""
