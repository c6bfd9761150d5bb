"""Configuration: robot types, vehicle parameters, model dimensions, interaction volume.

Plain data loaded from a TOML file (the package's ``default.toml`` unless given).  Robot types are
data, not code: adding a ``[[robot_types]]`` entry adds a phi and a rho net and
a type id in the generated C headers.  The environment is always the last
neighbour type (paper, Example "small and large robots, and the environment").
"""
from __future__ import annotations

import copy
import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from .errors import Ns2Error

DEFAULT_CONFIG = Path(__file__).resolve().parent / "default.toml"  # package data

# Model overrides of the one-tick on-board variant: the paper's H = 20 and L = 4
# with narrower intermediate layers (phi 6-16-24-24-H, rho H-24-24-24-1), whose
# whole prediction with 15 neighbours plus a controller step fits 20 % of a 2 ms
# tick on the STM32F405 (ns2host.budget, host/budget.py); the paper: "the learning performance is
# not sensitive to ... the number of weights in intermediate layers".
ONBOARD_WIDTHS = {"width": 24, "phi_first": 16}

_C_KEYWORDS = {
    "auto", "break", "case", "char", "const", "continue", "default", "do", "double",
    "else", "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long",
    "register", "restrict", "return", "short", "signed", "sizeof", "static", "struct",
    "switch", "typedef", "union", "unsigned", "void", "volatile", "while", "_Bool",
    "_Complex", "_Imaginary",
}


class ConfigError(Ns2Error, ValueError):
    """The configuration is malformed or inconsistent."""


def c_identifier(name: str) -> str:
    """Lower-case C identifier fragment of a type name (``check_name`` admits only names
    made of letters, digits, '_', '-' and spaces: the last two become '_')."""
    ident = re.sub(r"[^0-9A-Za-z_]", "_", name.strip()).lower()
    ident = re.sub(r"_+", "_", ident).strip("_")
    if not ident:
        raise ConfigError(f"name {name!r} has no usable characters for a C identifier")
    if ident[0].isdigit():
        ident = "t_" + ident
    if ident in _C_KEYWORDS:
        ident = ident + "_"
    return ident


@dataclass(frozen=True)
class Config:
    """Validated configuration; ``raw`` is the JSON-able dict it came from."""

    raw: dict

    # --- types -------------------------------------------------------------
    @property
    def robot_types(self) -> list[str]:
        return [t["name"] for t in self.raw["robot_types"]]

    @property
    def env_name(self) -> str:
        return self.raw["environment"]["name"]

    @property
    def neighbor_types(self) -> list[str]:
        """Robot types followed by the environment (its index is ``env_index``)."""
        return self.robot_types + [self.env_name]

    @property
    def env_index(self) -> int:
        return len(self.robot_types)

    @property
    def num_robot_types(self) -> int:
        return len(self.robot_types)

    def vehicle(self, name: str) -> dict:
        for t in self.raw["robot_types"]:
            if t["name"] == name:
                return t
        raise KeyError(name)

    # --- model -------------------------------------------------------------
    @property
    def model(self) -> dict:
        return self.raw["model"]

    @property
    def train(self) -> dict:
        return self.raw["train"]

    @property
    def history_ms(self) -> list[int]:
        """``model.history_ms``: each neighbour's relative state also this long ago (ms;
        the wake memory of issue 52: exported to C as NS2_HISTORY_LAGS and ns2_history_ms)."""
        return list(self.model.get("history_ms", []))

    @property
    def input_dim(self) -> int:
        """phi's input: x_ij now and at each ``history_ms`` lag (6 each)."""
        return 6 * (1 + len(self.history_ms))

    def phi_dims(self) -> list[int]:
        """6 -> phi_first -> width x (L-2) -> H  (paper: 6-25-40-40-H for L = 4)."""
        m = self.model
        return [self.input_dim, m["phi_first"]] + [m["width"]] * (m["layers"] - 2) + [m["hidden"]]

    def rho_dims(self) -> list[int]:
        """H -> width x (L-1) -> 1  (paper: H-40-40-40-1 for L = 4)."""
        m = self.model
        return [m["hidden"]] + [m["width"]] * (m["layers"] - 1) + [1]

    # --- boxes and volumes ---------------------------------------------------
    def input_box(self, neighbor_type: int) -> list[list[float]]:
        """6 [lo, hi] ranges of the phi input of ``neighbor_type``."""
        sec = self.raw["environment"] if neighbor_type == self.env_index else self.raw["neighbors"]
        return [list(map(float, r)) for r in sec["pos_box"]] + [list(map(float, r)) for r in sec["vel_box"]]

    def volume(self, robot_type: int, neighbor_type: int) -> tuple[list[float], list[float]]:
        vols = self.raw["interaction_volume"]
        key = f"{self.robot_types[robot_type]}.{self.neighbor_types[neighbor_type]}"
        v = vols.get(key, vols["default"])
        return [float(x) for x in v["lo"]], [float(x) for x in v["hi"]]

    def to_json(self) -> str:
        return json.dumps(self.raw, sort_keys=True, separators=(",", ":"))

    def with_overrides(self, **model_overrides) -> "Config":
        raw = copy.deepcopy(self.raw)
        raw["model"].update(model_overrides)
        return Config.from_dict(raw)

    def with_vehicle_files(self, paths) -> "Config":
        """The config with the [vehicle] table of each vehicle parameter file (written by
        ``ns2 sysid``) replacing those parameters of the robot type it names."""
        paths = list(paths)
        if not paths:
            return self
        raw = copy.deepcopy(self.raw)
        for path in paths:
            veh = load_vehicle_file(path)
            entry = next((t for t in raw["robot_types"] if t["name"] == veh["name"]), None)
            if entry is None:
                raise ConfigError(f"vehicle file {path}: robot type {veh['name']!r} is not in the config "
                                  f"{[t['name'] for t in raw['robot_types']]}")
            entry.update({k: v for k, v in veh.items() if k != "name"}, vehicle_file=Path(path).name)
            try:
                _check_vehicle(entry, "vehicle")
            except ConfigError as e:
                raise ConfigError(f"vehicle file {path}: {e}") from None
        return Config.from_dict(raw, "config with vehicle files " + ", ".join(map(str, paths)))

    # --- construction --------------------------------------------------------
    @staticmethod
    def from_dict(raw: dict, where: str = "") -> "Config":
        """The validated config of plain data ``raw``; ``where`` (e.g. "config file
        c.toml") prefixes every error."""
        raw = copy.deepcopy(raw)
        try:
            _validate(raw)
        except ConfigError as e:
            if not where:
                raise
            raise ConfigError(f"{where}: {e}") from None
        return Config(raw)

    @staticmethod
    def load(path: str | Path | None = None) -> "Config":
        path = Path(path) if path is not None else DEFAULT_CONFIG
        return Config.from_dict(read_toml(path, "config file"), f"config file {path}")


def read_toml(path, what: str, error: type[Exception] = ConfigError) -> dict:
    """Parsed TOML file; a missing or invalid file raises ``error`` naming ``what``."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError as e:
        raise error(f"{what} not found: {path}") from e
    except tomllib.TOMLDecodeError as e:
        raise error(f"{what} {path} is not valid TOML: {e}") from e


VEHICLE_KEYS = {"mass_g": 0, "max_thrust_g": 0, "diameter_m": 0, "lambda": 0, "psi1": 5, "psi2": 5, "psi3": 3,
                "arm_length_m": 0, "inertia_kgm2": 3, "thrust_to_torque_m": 0}  # key: list length (0: number)


def load_vehicle_file(path) -> dict:
    """The [vehicle] table of a vehicle parameter file: ``name`` plus keys of VEHICLE_KEYS."""
    veh = read_toml(path, "vehicle file").get("vehicle")
    if not isinstance(veh, dict) or not isinstance(veh.get("name"), str):
        raise ConfigError(f"vehicle file {path}: needs a [vehicle] table with a robot type name")
    try:
        _keys(veh, "vehicle", ("name", *VEHICLE_KEYS))
        _check_vehicle(veh, "vehicle", required=())
    except ConfigError as e:
        raise ConfigError(f"vehicle file {path}: {e}") from None
    return veh


def dump_toml(data: dict, comment: str = "") -> str:
    """TOML text of plain data: numbers, strings, booleans, lists of them, tables and
    arrays of tables whose values are those or lists of inline tables; ``comment``
    lines go first."""
    def string(s: str) -> str:  # a TOML basic string: JSON's escapes, but \uXXXX never a surrogate
        return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")

    def key(k: str) -> str:
        return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else string(k)

    def val(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            if not math.isfinite(v):
                raise ValueError(f"cannot write the non-finite number {v} to TOML")
            return repr(v)
        if isinstance(v, str):
            return string(v)
        if isinstance(v, dict):
            return "{" + ", ".join(f"{key(k)} = {val(x)}" for k, x in v.items()) + "}"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    def body(d: dict) -> list[str]:
        return [f"{key(k)} = {val(v)}" for k, v in d.items()]

    is_tables = lambda v: isinstance(v, list) and v and all(isinstance(x, dict) for x in v)  # noqa: E731
    scalars = {k: v for k, v in data.items() if not isinstance(v, dict) and not is_tables(v)}
    lines = [f"# {c}".rstrip() for c in comment.splitlines()] + body(scalars)
    for k, v in data.items():
        if isinstance(v, dict):
            lines += ["", f"[{key(k)}]"] + body(v)
        elif is_tables(v):
            for item in v:
                lines += ["", f"[[{key(k)}]]"] + body(item)
    return "\n".join(lines) + "\n"


def _number(x) -> bool:
    """A finite number (an int of any size is finite; math.isfinite would overflow)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and (isinstance(x, int) or math.isfinite(x))


# parameters that must be > 0 for the controller (B0 and the motor model divide by them)
POSITIVE_VEHICLE_KEYS = ("mass_g", "max_thrust_g", "lambda", "diameter_m", "arm_length_m", "inertia_kgm2",
                         "thrust_to_torque_m")
# largest physical magnitude of each parameter (beyond: a typo or a corrupt file;
# float32 in the firmware would turn 1e308 into Inf)
VEHICLE_MAX = {"mass_g": 1e5, "max_thrust_g": 1e6, "diameter_m": 10.0, "lambda": 1e4, "psi1": 1e6, "psi2": 1e6,
               "psi3": 1e6, "arm_length_m": 10.0, "inertia_kgm2": 1e3, "thrust_to_torque_m": 1.0}
MODEL_MAX = {"hidden": 1024, "layers": 16, "phi_first": 1024, "width": 1024, "max_neighbors": 255}


HISTORY_MAX, HISTORY_MAX_MS = 8, 2000   # model.history_ms: lags of the neighbours' past states
TRAIN_RANGES = {"epochs": (1, 10 ** 6), "batch_size": (1, 10 ** 7), "seed": (0, 2 ** 32 - 1),
                "pieces_per_scenario": (1, 10 ** 6)}  # integers: [lo, hi]
SECTIONS = ("model", "train", "robot_types", "environment", "neighbors", "interaction_volume")
ROBOT_TYPE_KEYS = ("name", "vehicle_file", *VEHICLE_KEYS)
REQUIRED_VEHICLE_KEYS = ("mass_g", "max_thrust_g", "lambda")

# Robot type and environment names reach the generated C (comments, and identifiers
# through c_identifier), TOML and JSON: a letter, then letters, digits, '_', '-' or
# spaces, not ending in a space.  Excluded on purpose: '*' and '/' (a C comment's
# end; "<type>*" is the simulator's strong-motor variant), '.' (separates the two
# types of an interaction volume key), '\' and '?' (line splices, trigraphs).
NAME_MAX = 32
_NAME = re.compile(r"[A-Za-z](?:[A-Za-z0-9_ -]{0,%d}[A-Za-z0-9_])?" % (NAME_MAX - 2))


def brief(value) -> str:
    """Short one-line repr of a user value for an error message."""
    r = repr(value)
    return r if len(r) <= 40 else r[:37] + "..."


def _kind(value) -> str:
    names = {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "an array",
             dict: "a table"}
    return names.get(type(value), type(value).__name__)


def check_name(value, field: str) -> str:
    """``value`` if it is an admitted robot type or environment name (``_NAME``)."""
    if not (isinstance(value, str) and _NAME.fullmatch(value)):
        raise ConfigError(f"{field} must be a name of 1 to {NAME_MAX} characters (a letter, then letters, digits, "
                          f"'_', '-' or spaces, not ending in a space), got {brief(value)}")
    return value


def _keys(d, field: str, known, required=()) -> dict:
    """``d`` if it is a table whose keys are among ``known`` (any if None) and include
    ``required``."""
    top = field == "config"
    if not isinstance(d, dict):
        raise ConfigError(f"{field} must be a table, got {_kind(d)}")
    unknown = [k for k in d if known is not None and k not in known]
    if unknown:
        what = f"[{unknown[0]}]: unknown section" if top else f"{field}.{unknown[0]}: unknown key"
        raise ConfigError(f"{what} (known: {', '.join(known)})")
    missing = [k for k in required if k not in d]
    if missing:
        raise ConfigError(f"section [{missing[0]}] is missing" if top else f"{field}.{missing[0]} is missing")
    return d


def _number(x) -> bool:
    """A finite number (an int of any size is finite; math.isfinite would overflow)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and (isinstance(x, int) or math.isfinite(x))


def _integer(d: dict, key: str, field: str, lo: int, hi: int) -> None:
    v = d[key]
    if not (isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi):
        raise ConfigError(f"{field}.{key} must be an integer in [{lo}, {hi}], got {brief(v)}")


def _real(d: dict, key: str, field: str, lo: float, hi: float) -> None:
    """A finite number in (lo, hi]."""
    v = d[key]
    if not (_number(v) and lo < v <= hi):
        raise ConfigError(f"{field}.{key} must be a number in ({lo:g}, {hi:g}], got {brief(v)}")


BOX_MAX = 1e6  # largest magnitude of a box or volume bound (m, m/s)


def _range_list(value, n: int, field: str) -> None:
    if not (isinstance(value, list) and len(value) == n):
        raise ConfigError(f"{field}: expected {n} [lo, hi] pairs, got {brief(value)}")
    for r in value:
        if not (isinstance(r, list) and len(r) == 2 and all(_number(x) and abs(x) <= BOX_MAX for x in r)
                and r[0] < r[1]):
            raise ConfigError(f"{field}: expected [lo, hi] numbers of magnitude at most {BOX_MAX:g} with lo < hi, "
                              f"got {brief(r)}")


# parameters that must be > 0 for the controller (B0 and the motor model divide by them)
POSITIVE_VEHICLE_KEYS = ("mass_g", "max_thrust_g", "lambda", "diameter_m", "arm_length_m", "inertia_kgm2",
                         "thrust_to_torque_m")
# largest physical magnitude of each parameter (beyond: a typo or a corrupt file;
# float32 in the firmware would turn 1e308 into Inf)
VEHICLE_MAX = {"mass_g": 1e5, "max_thrust_g": 1e6, "diameter_m": 10.0, "lambda": 1e4, "psi1": 1e6, "psi2": 1e6,
               "psi3": 1e6, "arm_length_m": 10.0, "inertia_kgm2": 1e3, "thrust_to_torque_m": 1.0}
MODEL_MAX = {"hidden": 1024, "layers": 16, "phi_first": 1024, "width": 1024, "max_neighbors": 255}


def _check_vehicle(t: dict, field: str, required=REQUIRED_VEHICLE_KEYS) -> None:
    """Vehicle parameters of one robot type (or vehicle file) ``t``: the ``required``
    ones present, every one of VEHICLE_KEYS a finite number (or list of them), the
    physical ones > 0, none beyond VEHICLE_MAX."""
    for key in required:
        if key not in t:
            raise ConfigError(f"{field}.{key} is missing")
    for key, n in VEHICLE_KEYS.items():
        if key not in t:
            continue
        vals = t[key] if n else [t[key]]
        what = f"{n} finite numbers" if n else "a finite number"
        if not (isinstance(vals, list) and len(vals) == max(n, 1) and all(_number(x) for x in vals)):
            raise ConfigError(f"{field}.{key} must be {what}, got {brief(t[key])}")
        if key in POSITIVE_VEHICLE_KEYS and not all(x > 0 for x in vals):
            raise ConfigError(f"{field}.{key} must be positive, got {brief(t[key])}")
        if not all(abs(x) <= VEHICLE_MAX[key] for x in vals):
            raise ConfigError(f"{field}.{key} must be at most {VEHICLE_MAX[key]:g} in magnitude, got {brief(t[key])}")


def _validate(raw) -> None:
    """The one validator of a configuration, whatever it came from (a TOML file, a
    checkpoint's metadata, an export folder's ns2_config.toml): every section a table
    of known keys with values of the right type and range, names C-safe and distinct
    as C identifiers, boxes and volumes consistent.  Errors name the field."""
    _keys(raw, "config", SECTIONS, SECTIONS)
    m = _keys(raw["model"], "model", (*MODEL_MAX, "gamma", "history_ms"), (*MODEL_MAX, "gamma"))
    for key, most in MODEL_MAX.items():
        _integer(m, key, "model", 2 if key == "layers" else 1, most)
    _real(m, "gamma", "model", 0.0, 1e6)
    hist = m.get("history_ms", [])
    if not (isinstance(hist, list) and len(hist) <= HISTORY_MAX
            and all(isinstance(x, int) and not isinstance(x, bool) and 0 < x <= HISTORY_MAX_MS for x in hist)
            and hist == sorted(set(hist))):
        raise ConfigError(f"model.history_ms must be at most {HISTORY_MAX} increasing integers in (0, "
                          f"{HISTORY_MAX_MS}] ms, got {brief(hist)}")
    tr = _keys(raw["train"], "train", (*TRAIN_RANGES, "lr", "validation_fraction"),
               (*TRAIN_RANGES, "lr", "validation_fraction"))
    for key, (lo, hi) in TRAIN_RANGES.items():
        _integer(tr, key, "train", lo, hi)
    _real(tr, "lr", "train", 0.0, 10.0)
    _real(tr, "validation_fraction", "train", 0.0, 1.0)
    if tr["validation_fraction"] >= 1.0:
        raise ConfigError(f"train.validation_fraction must be below 1, got {brief(tr['validation_fraction'])}")
    types = raw["robot_types"]
    if not (isinstance(types, list) and types):
        raise ConfigError(f"robot_types must be a non-empty array of tables ([[robot_types]]), got {brief(types)}")
    for i, t in enumerate(types):
        _keys(t, f"robot_types[{i}]", ROBOT_TYPE_KEYS, ("name",))
        check_name(t["name"], f"robot_types[{i}].name")
        _check_vehicle(t, f"robot_types[{i}]")
        vf = t.get("vehicle_file", "")
        if not (isinstance(vf, str) and len(vf) <= 255 and vf.isprintable()):
            raise ConfigError(f"robot_types[{i}].vehicle_file must be a file name, got {brief(vf)}")
    env = _keys(raw["environment"], "environment", ("name", "pos_box", "vel_box"), ("name", "pos_box", "vel_box"))
    nb = _keys(raw["neighbors"], "neighbors", ("pos_box", "vel_box"), ("pos_box", "vel_box"))
    check_name(env["name"], "environment.name")
    names = [t["name"] for t in types] + [env["name"]]
    idents = [c_identifier(n) for n in names]
    if len(set(idents)) != len(idents):
        raise ConfigError(f"type names collide as C identifiers: {names}")
    for sec, d in (("environment", env), ("neighbors", nb)):
        _range_list(d["pos_box"], 3, f"{sec}.pos_box")
        _range_list(d["vel_box"], 3, f"{sec}.vel_box")
    vols = _keys(raw["interaction_volume"], "interaction_volume", None, ("default",))
    robot_names = names[:-1]
    for key, v in vols.items():
        field = f"interaction_volume.{key}"
        if key != "default":
            parts = key.split(".")
            if len(parts) != 2 or parts[0] not in robot_names or parts[1] not in robot_names:
                raise ConfigError(f"{field}: expected 'default' or '<robot type>.<robot type>' of {robot_names}")
        _keys(v, field, ("lo", "hi"), ("lo", "hi"))
        lo, hi = v["lo"], v["hi"]
        for k, x in (("lo", lo), ("hi", hi)):
            if not (isinstance(x, list) and len(x) == 3 and all(_number(a) for a in x)):
                raise ConfigError(f"{field}.{k} must be 3 finite numbers, got {brief(x)}")
        _range_list([[a, b] for a, b in zip(lo, hi)], 3, field)
        for d in range(3):
            blo, bhi = nb["pos_box"][d]
            if lo[d] < blo or hi[d] > bhi:
                raise ConfigError(f"{field} leaves neighbors.pos_box in axis {d}")
