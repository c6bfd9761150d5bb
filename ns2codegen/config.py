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
    """Sanitize ``name`` into a lower-case C identifier fragment."""
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

    def phi_dims(self) -> list[int]:
        """6 -> phi_first -> width x (L-2) -> H  (paper: 6-25-40-40-H for L = 4)."""
        m = self.model
        return [6, m["phi_first"]] + [m["width"]] * (m["layers"] - 2) + [m["hidden"]]

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
        raw = copy.deepcopy(self.raw)
        for path in paths:
            veh = load_vehicle_file(path)
            entry = next((t for t in raw["robot_types"] if t["name"] == veh["name"]), None)
            if entry is None:
                raise ConfigError(f"vehicle file {path}: robot type {veh['name']!r} is not in the config "
                                  f"{[t['name'] for t in raw['robot_types']]}")
            entry.update({k: v for k, v in veh.items() if k != "name"}, vehicle_file=Path(path).name)
            try:
                _check_vehicle(entry)
            except ConfigError as e:
                raise ConfigError(f"vehicle file {path}: {e}") from None
        return Config.from_dict(raw)

    # --- construction --------------------------------------------------------
    @staticmethod
    def from_dict(raw: dict) -> "Config":
        raw = copy.deepcopy(raw)
        _validate(raw)
        return Config(raw)

    @staticmethod
    def load(path: str | Path | None = None) -> "Config":
        path = Path(path) if path is not None else DEFAULT_CONFIG
        raw = read_toml(path, "config file")
        try:
            return Config.from_dict(raw)
        except ConfigError as e:
            raise ConfigError(f"config file {path}: {e}") from None
        except (TypeError, AttributeError, KeyError) as e:  # a value of the wrong kind deep inside
            raise ConfigError(f"config file {path}: malformed ({type(e).__name__}: {e})") from None


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
    for key, value in veh.items():
        if key == "name":
            continue
        if key not in VEHICLE_KEYS:
            raise ConfigError(f"vehicle file {path}: unknown parameter {key!r} (known: {sorted(VEHICLE_KEYS)})")
        n = VEHICLE_KEYS[key]
        vals = value if n else [value]
        if not (isinstance(vals, list) and len(vals) == max(n, 1)
                and all(isinstance(x, (int, float)) and math.isfinite(x) for x in vals)):
            raise ConfigError(f"vehicle file {path}: {key} must be " + (f"{n} finite numbers" if n else "a finite number"))
    return veh


def dump_toml(data: dict, comment: str = "") -> str:
    """TOML text of plain data: numbers, strings, booleans, lists of them, tables and
    arrays of tables whose values are those or lists of inline tables; ``comment``
    lines go first."""
    def key(k: str) -> str:
        return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)

    def val(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            if not math.isfinite(v):
                raise ValueError(f"cannot write the non-finite number {v} to TOML")
            return repr(v)
        if isinstance(v, str):
            return json.dumps(v)
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


def _range_list(value, n: int, what: str) -> None:
    if not (isinstance(value, list) and len(value) == n):
        raise ConfigError(f"{what}: expected {n} [lo, hi] pairs")
    for r in value:
        if not (isinstance(r, list) and len(r) == 2 and all(isinstance(x, (int, float)) for x in r)):
            raise ConfigError(f"{what}: expected [lo, hi] numbers, got {r!r}")
        if not (math.isfinite(r[0]) and math.isfinite(r[1]) and r[0] < r[1]):
            raise ConfigError(f"{what}: need finite lo < hi, got {r!r}")


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


# parameters that must be > 0 for the controller (B0 and the motor model divide by them)
POSITIVE_VEHICLE_KEYS = ("mass_g", "max_thrust_g", "lambda", "diameter_m", "arm_length_m", "inertia_kgm2",
                         "thrust_to_torque_m")
# largest physical magnitude of each parameter (beyond: a typo or a corrupt file;
# float32 in the firmware would turn 1e308 into Inf)
VEHICLE_MAX = {"mass_g": 1e5, "max_thrust_g": 1e6, "diameter_m": 10.0, "lambda": 1e4, "psi1": 1e6, "psi2": 1e6,
               "psi3": 1e6, "arm_length_m": 10.0, "inertia_kgm2": 1e3, "thrust_to_torque_m": 1.0}
MODEL_MAX = {"hidden": 1024, "layers": 16, "phi_first": 1024, "width": 1024, "max_neighbors": 255}


def _check_vehicle(t: dict) -> None:
    """Vehicle parameters of one robot type: required ones present, every one of
    VEHICLE_KEYS a finite number (or list of them), the physical ones > 0."""
    name = t["name"]
    for key in ("mass_g", "max_thrust_g", "lambda"):
        if key not in t:
            raise ConfigError(f"robot type {name}: {key} is missing")
    for key, n in VEHICLE_KEYS.items():
        if key not in t:
            continue
        vals = t[key] if n else [t[key]]
        what = f"{n} finite numbers" if n else "a finite number"
        if not (isinstance(vals, list) and len(vals) == max(n, 1) and all(_number(x) for x in vals)):
            raise ConfigError(f"robot type {name}: {key} must be {what}, got {t[key]!r}")
        if key in POSITIVE_VEHICLE_KEYS and not all(x > 0 for x in vals):
            raise ConfigError(f"robot type {name}: {key} must be positive, got {t[key]!r}")
        if not all(abs(x) <= VEHICLE_MAX[key] for x in vals):
            raise ConfigError(f"robot type {name}: {key} must be at most {VEHICLE_MAX[key]:g} in magnitude, "
                              f"got {t[key]!r}")


def _validate(raw: dict) -> None:
    for sec in ("model", "train", "robot_types", "environment", "neighbors", "interaction_volume"):
        if sec not in raw:
            raise ConfigError(f"config is missing section [{sec}]")
    m = raw["model"]
    for key, most in MODEL_MAX.items():
        if not isinstance(m.get(key), int) or isinstance(m[key], bool) or not 1 <= m[key] <= most:
            raise ConfigError(f"model.{key} must be an integer in [1, {most}], got {m.get(key)!r}")
    if m["layers"] < 2:
        raise ConfigError("model.layers must be >= 2")
    if not (_number(m.get("gamma")) and 0 < m["gamma"] <= 1e6):
        raise ConfigError(f"model.gamma must be a number in (0, 1e6], got {m.get('gamma')!r}")
    types = raw["robot_types"]
    if not isinstance(types, list) or not types:
        raise ConfigError("need at least one [[robot_types]] entry")
    names = [t.get("name") for t in types] + [raw["environment"].get("name")]
    if not all(isinstance(n, str) and n for n in names):
        raise ConfigError("every robot type and the environment need a non-empty name")
    idents = [c_identifier(n) for n in names]
    if len(set(idents)) != len(idents):
        raise ConfigError(f"type names collide as C identifiers: {names}")
    for t in types:
        _check_vehicle(t)
    env, nb = raw["environment"], raw["neighbors"]
    _range_list(env.get("pos_box"), 3, "environment.pos_box")
    _range_list(env.get("vel_box"), 3, "environment.vel_box")
    _range_list(nb.get("pos_box"), 3, "neighbors.pos_box")
    _range_list(nb.get("vel_box"), 3, "neighbors.vel_box")
    vols = raw["interaction_volume"]
    if "default" not in vols:
        raise ConfigError("interaction_volume needs a 'default' cuboid")
    robot_names = [t["name"] for t in types]
    for key, v in vols.items():
        if key != "default":
            parts = key.split(".")
            if len(parts) != 2 or parts[0] not in robot_names or parts[1] not in robot_names:
                raise ConfigError(f"interaction_volume.{key}: expected '<robot type>.<robot type>'")
        lo, hi = v.get("lo"), v.get("hi")
        _range_list([[a, b] for a, b in zip(lo or [], hi or [])], 3, f"interaction_volume.{key}")
        for d in range(3):
            blo, bhi = nb["pos_box"][d]
            if lo[d] < blo or hi[d] > bhi:
                raise ConfigError(f"interaction_volume.{key} leaves neighbors.pos_box in axis {d}")
