"""ns2ground: the ground side of a flight (docs/flying.md).

``swarm`` reads Crazyswarm2's ``crazyflies.yaml`` and writes the app's parameters into
it; ``fingerprint`` ties the robots' firmware to the export; the flight itself
talks to the robots through bitcraze's cflib, or to the simulator (``--sim``).
Product code: imports the core, the host side, the simulator and the planner, never the
experiments; the CLI sits on top (tests/test_layers.py)."""
