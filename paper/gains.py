"""The gains of the controller that flew the paper's real flights and the z law read off
them: parameter files in params/ (the authors' configuration, copied; the read law,
fitted by ``make calibrate``), loaded as data (ns2host.sim.paramfile)."""
from pathlib import Path

from ns2codegen.vehicle import base_type
from ns2host.sim.paramfile import Param, ParamsError, dump_params, load_params

__all__ = ["AUTHORS_GAINS", "AUTHORS_PWM_EXACT", "READ_LAW", "authors_gains", "dump_read_law", "load_authors_gains",
           "load_read_law", "read_law_gains"]

PARAMS_DIR = Path(__file__).resolve().parent / "params"   # package data (pyproject.toml)

# The controller that flew the paper's real flights (paper/c/ctrl_authors.c): the position
# gains of controller_sjc.c in the authors' Crazyswarm configuration and its attitude
# gains as the project's attitude law's (ns2_ctrl_attitude, the same law on a quaternion
# error: tau = J w_r_dot - (J w) x w_r - Kw (w - w_r) - Gw int(w - w_r) - Kwd d(w - w_r)/dt,
# w_r = -Lq q~v, q~v about half the angle error; Lq = 2 Katt_P).  The numbers, their units
# and sources (aerorobotics/neural-swarm crazyflieTypes.yaml and allCrazyflies.yaml at
# commit 0103346d): params/authors_gains.toml.
_GAIN_KEYS = ("mass_kg", "kp", "kd", "ki", "i_max")
_ATT_KEYS = ("Lq", "Kw", "Gw", "Kwd", "int_w_max")
_YAML = "aerorobotics/neural-swarm hardware/neural-swarm-ros-pkg/launch/"
AUTHORS_PARAMS = {
    "mass_kg": Param("kg", _YAML + "crazyflieTypes.yaml ctrlSJC.mass", keyed=True, nonneg=True),
    "kp": Param("1/s^2", _YAML + "crazyflieTypes.yaml ctrlSJC.Kpos_P", kind="vector3", keyed=True, nonneg=True),
    "kd": Param("1/s", _YAML + "crazyflieTypes.yaml ctrlSJC.Kpos_D", kind="vector3", keyed=True, nonneg=True),
    "ki": Param("1/s^3", _YAML + "crazyflieTypes.yaml ctrlSJC.Kpos_I", kind="vector3", keyed=True, nonneg=True),
    "i_max": Param("m s", _YAML + "crazyflieTypes.yaml ctrlSJC.Kpos_I_limit", keyed=True, nonneg=True),
    "Lq": Param("1/s", _YAML + "crazyflieTypes.yaml 2 x ctrlSJC.Katt_P (controller_sjc's lambda on the Euler "
                "angle error; the project's law's q~v is about half the angle)", kind="vector3", keyed=True,
                nonneg=True),
    "Kw": Param("N m s", _YAML + "crazyflieTypes.yaml ctrlSJC.Katt_D (its K; its Jtune, 16e-6, is about J "
                "already)", kind="vector3", keyed=True, nonneg=True),
    "Gw": Param("N m", _YAML + "crazyflieTypes.yaml ctrlSJC.Katt_I", kind="vector3", keyed=True, nonneg=True),
    "Kwd": Param("N m s^2", _YAML + "crazyflieTypes.yaml ctrlSJC.Katt_Dw (its D on the angular velocity error's "
                 "derivative, with the same sign in the stored controller_sjc.c)", kind="vector3", keyed=True,
                 nonneg=True),
    "int_w_max": Param("rad", _YAML + "crazyflieTypes.yaml ctrlSJC.Katt_I_limit", keyed=True, nonneg=True),
    "type_of": Param("crazyflieTypes.yaml type", _YAML + "allCrazyflies.yaml: cf50-52 CF21SingleMarker, cf101-102 "
                     "parrotFrameCF21SingleMarker, by the project's robot type", kind="string", keyed=True),
    "type_of_robot": Param("crazyflieTypes.yaml type", _YAML + "allCrazyflies.yaml: a robot of a type of its own "
                           "(cf100, the Crazyflie 2.0 on the large frame)", kind="string", keyed=True),
}
AUTHORS_GAINS_FILE = PARAMS_DIR / "authors_gains.toml"


def _by_name(values: dict, keys, path, what: str) -> dict:
    """{name: {key: values[key][name]}} of keyed parameters that are all keyed alike."""
    names = list(values[keys[0]])
    for k in keys:
        if set(values[k]) != set(names):
            raise ParamsError(f"parameter file {path}: {k}.value: {what} {sorted(values[k])}, "
                              f"{keys[0]} has {sorted(names)}")
    return {n: {k: values[k][n] for k in keys} for n in names}


def load_authors_gains(path) -> tuple[dict, dict, dict]:
    """(gains by crazyflieTypes.yaml type in AUTHORS_GAINS' form, the type of each robot
    type, the type of each robot with one of its own) of an authors' gains file."""
    values = load_params(path, AUTHORS_PARAMS)[0]
    gains = _by_name(values, (*_GAIN_KEYS, *_ATT_KEYS), path, "types")
    gains = {n: {**{k: g[k] for k in _GAIN_KEYS}, "att": {k: g[k] for k in _ATT_KEYS}} for n, g in gains.items()}
    for k in ("type_of", "type_of_robot"):
        for who, t in values[k].items():
            if t not in gains:
                raise ParamsError(f"parameter file {path}: {k}.value.{who}: {t!r} is not a type of the file "
                                  f"{sorted(gains)}")
    return gains, values["type_of"], values["type_of_robot"]


AUTHORS_GAINS, AUTHORS_TYPE, AUTHORS_ROBOT_TYPE = load_authors_gains(AUTHORS_GAINS_FILE)
# The motor map of the firmware that flew the real flights: the motor forces its controller
# commands become PWM through the exact inverse of psi_1 (host/ns2_fly.c), not through psi_2
# as the project's firmware does.  Table cfprops' psi_1 and psi_2 are not each other's
# inverse: psi_1(psi_2(f)) of the large robot is 8 % under f at hover and its slope is 0.86
# there, 0.68-0.79 at 1.3-1.6 times hover (the small robot's 1.1).  The real flights show no
# such compression: the z law read off them (flightstats.z_law) leaves a flat residual through
# a large robot's passage under another (L2L), where a replay through psi_2 falls 1.3-2.7
# m/s^2 under its own law as the wake arrives (docs/simulator.md).
AUTHORS_PWM_EXACT = True


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
# replays of the real swaps read back (paper/flightstats.py z_law) what the real
# flights read, and their mean z error: what the logs say flew, not a configuration
# anyone wrote.  The numbers, units and the fit's commit and command:
# params/read_law.toml (docs/simulator.md).
_LAW_SOURCE = ("fit_read_law: the authors' law whose replays of the real swaps read back (flightstats.z_law) what "
               "the real flights read, and their mean z error")
READ_LAW_PARAMS = {
    "kp": Param("1/s^2", _LAW_SOURCE + "; z axis Kp", keyed=True, nonneg=True),
    "kd": Param("1/s", _LAW_SOURCE + "; z axis Kd", keyed=True, nonneg=True),
    "ki": Param("1/s^3", _LAW_SOURCE + "; z axis Ki", keyed=True, nonneg=True),
    "k_fa": Param("1 (share of the learned force taken off)", _LAW_SOURCE, keyed=True, nonneg=True),
    "mass_kg": Param("kg", _LAW_SOURCE + "; the law's mass parameter", keyed=True, nonneg=True),
}
READ_LAW_FILE = PARAMS_DIR / "read_law.toml"


def load_read_law(path) -> dict:
    """The z law of a read-law file in READ_LAW's form: {type: {kp, kd, ki, k_fa, mass_kg}}."""
    return _by_name(load_params(path, READ_LAW_PARAMS)[0], tuple(READ_LAW_PARAMS), path, "robot types")


def dump_read_law(law: dict, origin: dict) -> str:
    """params/read_law.toml's text of ``law`` (READ_LAW's form), made as ``origin`` says."""
    values = {k: {ty: zl[k] for ty, zl in law.items()} for k in READ_LAW_PARAMS}
    return dump_params(values, READ_LAW_PARAMS, origin,
                       "The z law read off the real flights of 16 June 2020 (ns2paper.gains READ_LAW);\n"
                       "`make calibrate` writes a new one beside its report.")


READ_LAW = load_read_law(READ_LAW_FILE)


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
