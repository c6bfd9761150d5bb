"""ns2host: the host side of ns2codegen, built on the firmware C sources of a source
checkout (firmware/; an installed wheel has none: cbuild.firmware_sources says so).

cbuild.py           cffi build of the firmware library + host helpers (the very STM32 sources)
target.py           Cortex-M4F cross builds of the library and runs in QEMU (netduinoplus2)
cm4_count.py        instruction counts of cross-compiled functions on an emulated Cortex-M4
budget.py           the 2 ms-tick budget of inference and controller on that model
firmware_report.py  flash, RAM and worst-case stack of the cross-built library
hil.py              serial hardware-in-the-loop client (a board or QEMU)
crazyflie.py        the real crazyflie-firmware tree (shared tarball or CRAZYFLIE_BASE)
sim/                the swarm simulator (ns2host.sim)
"""
