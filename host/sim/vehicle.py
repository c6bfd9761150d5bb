"""Vehicle parameters of the simulator: those of ns2codegen.vehicle (one source for
the simulator, the controller's gains and the generated firmware header)."""
from ns2codegen.vehicle import G, STRONG, Vehicle, base_type, default_gains, vehicle

__all__ = ["AUTHORS_GAINS", "AUTHORS_PWM_EXACT", "G", "READ_LAW", "read_law_gains", "STRONG", "Vehicle", "authors_gains", "base_type", "default_gains", "vehicle"]

# The controller that flew the paper's real flights (host/ctrl_authors.c): the position
# gains of controller_sjc.c in the authors' Crazyswarm configuration
# (aerorobotics/neural-swarm, hardware/neural-swarm-ros-pkg/launch/crazyflieTypes.yaml,
# ctrlSJC.mass / Kpos_P / Kpos_D / Kpos_I / Kpos_I_limit), per robot by its
# allCrazyflies.yaml: cf50-52 CF21SingleMarker, cf101-102 parrotFrameCF21SingleMarker;
# cf100, the Crazyflie 2.0 on the large frame, parrotFrameSingleMarker.  One stored
# version of that file (commit 0103346d); which one flew on 16 June 2020 is not recorded.
#
# "att": its attitude gains as the project's attitude law's (ns2_ctrl_attitude, the same
# law on a quaternion error: tau = J w_r_dot - (J w) x w_r - Kw (w - w_r) - Gw int(w - w_r)
# - Kwd d(w - w_r)/dt, w_r = -Lq q~v, q~v about half the angle error): Lq = 2 Katt_P
# (controller_sjc's lambda on the Euler angle error), Kw = Katt_D (its K), Gw = Katt_I,
# int_w_max = Katt_I_limit, Kwd = Katt_Dw (its D on the angular velocity error's
# derivative, "to deal with motor delays", in the stored controller_sjc.c with the same
# sign).  Its Jtune (16e-6) is about J already.
AUTHORS_GAINS = {
    "CF21SingleMarker": {"mass_kg": 0.034, "kp": [20.0, 20.0, 10.0], "kd": [10.0, 10.0, 5.0],
                         "ki": [3.0, 3.0, 3.0], "i_max": 2.0,
                         "att": {"Lq": [20.0, 20.0, 8.0], "Kw": [0.002, 0.002, 0.001], "Gw": [0.002, 0.002, 0.004],
                                 "Kwd": [8e-5, 8e-5, 2e-5], "int_w_max": 2.0}},
    "parrotFrameCF21SingleMarker": {"mass_kg": 0.067, "kp": [20.0, 20.0, 10.0], "kd": [10.0, 10.0, 5.0],
                                    "ki": [3.0, 3.0, 3.0], "i_max": 2.0,
                                    "att": {"Lq": [20.0, 20.0, 8.0], "Kw": [0.009, 0.009, 0.004],
                                            "Gw": [0.005, 0.005, 0.005], "Kwd": [2e-4, 2e-4, 0.0], "int_w_max": 2.0}},
    "parrotFrameSingleMarker": {"mass_kg": 0.067, "kp": [40.0, 40.0, 30.0], "kd": [20.0, 20.0, 15.0],
                                "ki": [3.0, 3.0, 3.0], "i_max": 2.0,
                                "att": {"Lq": [12.0, 12.0, 8.0], "Kw": [0.006, 0.006, 0.004],
                                        "Gw": [0.005, 0.005, 0.005], "Kwd": [1e-4, 1e-4, 0.0], "int_w_max": 2.0}},
}
AUTHORS_TYPE = {"small": "CF21SingleMarker", "large": "parrotFrameCF21SingleMarker"}
# The motor map of the firmware that flew the real flights: the motor forces its controller
# commands become PWM through the exact inverse of psi_1 (host/ns2_fly.c), not through psi_2
# as the project's firmware does.  Table cfprops' psi_1 and psi_2 are not each other's
# inverse: psi_1(psi_2(f)) of the large robot is 8 % under f at hover and its slope is 0.86
# there, 0.68-0.79 at 1.3-1.6 times hover (the small robot's 1.1).  The real flights show no
# such compression: the z law read off them (flightstats.z_law) leaves a flat residual through
# a large robot's passage under another (L2L), where a replay through psi_2 falls 1.3-2.7
# m/s^2 under its own law as the wake arrives (docs/simulator.md).
AUTHORS_PWM_EXACT = True
AUTHORS_ROBOT_TYPE = {"cf100": "parrotFrameSingleMarker"}


def authors_gains(robot_type: str, robot: str | None = None) -> dict:
    """AUTHORS_GAINS of a robot: by its id where it had its own (cf100), else by its type."""
    if robot in AUTHORS_ROBOT_TYPE:
        return AUTHORS_GAINS[AUTHORS_ROBOT_TYPE[robot]]
    bt = base_type(robot_type)
    if bt not in AUTHORS_TYPE:
        raise ValueError(f"robot type {robot_type!r}: the authors' controller gains are known for "
                         f"{sorted(AUTHORS_TYPE)} only")
    return AUTHORS_GAINS[AUTHORS_TYPE[bt]]


# The z law read off the real flights (issue 23; ``make calibrate``,
# experiments/calibrate.py fit_read_law): per type, the z gains of the authors' law, the
# share k_fa of the learned force it takes off and its mass parameter, fitted so that
# replays of the real swaps read back (host/sim/flightstats.py z_law) what the real
# flights read, and their mean z error.  Not a configuration anyone wrote: what the
# logs say flew (softer than crazyflieTypes.yaml, no integral to speak of, the small
# robots taking off about a third of their prediction).  The values make calibrate
# fitted (docs/simulator.md).
READ_LAW = {"small": {"kp": 8.9309, "kd": 2.8506, "ki": 0.4604, "k_fa": 0.3729, "mass_kg": 0.033207},
            "large": {"kp": 7.9323, "kd": 2.5174, "ki": 0.5582, "k_fa": 0.8295, "mass_kg": 0.06533}}


def read_law_gains(robot_type: str, law: dict | None = None) -> dict:
    """The authors' gains of the type (authors_gains; every robot of a type alike) with
    the z axis's Kp, Kd, Ki, k_fa and the mass parameter of ``law`` (READ_LAW's form;
    READ_LAW by default)."""
    zl = (READ_LAW if law is None else law)[base_type(robot_type)]
    g = dict(authors_gains(robot_type))
    for k in ("kp", "kd", "ki"):
        g[k] = [*g[k][:2], float(zl[k])]
    g["k_fa"], g["mass_kg"] = float(zl["k_fa"]), float(zl["mass_kg"])
    return g
