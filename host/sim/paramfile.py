"""The simulator's parameter files (host/sim/params/*.toml): numbers that were fitted to
or copied from somewhere are data, each with its unit and its source, and each file
says what made it (the commit and the command).

A file holds an ``[origin]`` table (``commit``, ``command``; optionally ``date``,
``report``, ``repository``) and one table per parameter::

    [turbulence_ratio]
    value = 0.025                      # a number, three numbers, a string, or a table of
    unit = "1 (per unit |f_a,z|)"      # them by robot type (or by the authors' type name)
    source = "fit_turbulence: ..."

The Python side (``Param``: unit, kind, sign) says what each file must hold; the unit
in the file must be that unit, so a value in other units cannot slip in.  A bad file
raises ``ParamsError`` (an ``Ns2Error``: one line naming the file and the field)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ns2codegen.config import dump_toml, read_toml
from ns2codegen.errors import Ns2Error

PARAMS_DIR = Path(__file__).resolve().parent / "params"   # package data (pyproject.toml)
ORIGIN_KEYS = ("commit", "command")                        # required in [origin]; every origin value is a string


class ParamsError(Ns2Error, ValueError):
    """A parameter file is missing, malformed or holds a value of the wrong kind."""


@dataclass(frozen=True)
class Param:
    """What one parameter of a file must be: ``kind`` "number", "vector3" (three
    numbers) or "string"; ``keyed``: a table of such values by robot type (or type
    name) instead of one; ``nonneg``: no number below 0."""
    unit: str
    source: str
    kind: str = "number"
    keyed: bool = False
    nonneg: bool = False


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _check_one(x, p: Param, where: str) -> None:
    if p.kind == "string":
        if not isinstance(x, str):
            raise ParamsError(f"{where}: a string, got {x!r}")
        return
    items = x if p.kind == "vector3" else [x]
    if p.kind == "vector3" and not (isinstance(x, list) and len(x) == 3):
        raise ParamsError(f"{where}: three numbers, got {x!r}")
    for v in items:
        if not _is_number(v):
            raise ParamsError(f"{where}: a finite number, got {v!r}")
        if p.nonneg and v < 0:
            raise ParamsError(f"{where}: at least 0, got {v!r}")


def check_value(value, p: Param, where: str) -> None:
    """A ParamsError naming ``where`` unless ``value`` is of ``p``'s kind."""
    if not p.keyed:
        _check_one(value, p, where)
        return
    if not isinstance(value, dict) or not value:
        raise ParamsError(f"{where}: a table of values by robot type, got {value!r}")
    for k, x in value.items():
        _check_one(x, p, f"{where}.{k}")


def load_params(path, schema: dict[str, Param]) -> tuple[dict, dict]:
    """(values by parameter name, the [origin] table) of the parameter file ``path``,
    every parameter of ``schema`` present with its unit and nothing else."""
    raw = read_toml(path, "parameter file", ParamsError)
    where = f"parameter file {path}"
    origin = raw.get("origin")
    if not isinstance(origin, dict):
        raise ParamsError(f"{where}: origin: a table with {list(ORIGIN_KEYS)} (what made the file)")
    for k in ORIGIN_KEYS:
        if k not in origin:
            raise ParamsError(f"{where}: origin.{k}: missing")
    for k, v in origin.items():
        if not isinstance(v, str):
            raise ParamsError(f"{where}: origin.{k}: a string, got {v!r}")
    unknown = sorted(set(raw) - set(schema) - {"origin"})
    if unknown:
        raise ParamsError(f"{where}: {unknown[0]}: not a parameter of this file (known: {sorted(schema)})")
    values = {}
    for name, p in schema.items():
        t = raw.get(name)
        if not isinstance(t, dict):
            raise ParamsError(f"{where}: {name}: missing (a table with value, unit, source)")
        extra = sorted(set(t) - {"value", "unit", "source"})
        if extra:
            raise ParamsError(f"{where}: {name}.{extra[0]}: unknown key (value, unit, source)")
        if t.get("unit") != p.unit:
            raise ParamsError(f"{where}: {name}.unit: {p.unit!r} expected, got {t.get('unit')!r}")
        if not isinstance(t.get("source", ""), str):
            raise ParamsError(f"{where}: {name}.source: a string, got {t['source']!r}")
        if "value" not in t:
            raise ParamsError(f"{where}: {name}.value: missing")
        check_value(t["value"], p, f"{where}: {name}.value")
        values[name] = t["value"]
    return values, dict(origin)


def dump_params(values: dict, schema: dict[str, Param], origin: dict, comment: str = "") -> str:
    """The TOML text of a parameter file (load_params' inverse): ``origin`` first, then
    every parameter of ``schema`` in its order with its unit and source."""
    for k in ORIGIN_KEYS:
        if not isinstance(origin.get(k), str):
            raise ValueError(f"origin.{k}: a string, got {origin.get(k)!r}")
    for name, p in schema.items():
        check_value(values[name], p, name)
    data = {"origin": dict(origin)}
    data.update({name: {"value": values[name], "unit": p.unit, "source": p.source} for name, p in schema.items()})
    return dump_toml(data, comment)
