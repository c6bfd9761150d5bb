"""The finished units of a long experiment (a trial, a replay, a training), each kept
as its own small JSON file the moment it finishes, so that a run cut short (or
continued another day, by someone else from the committed files) redoes only what
is missing.  A unit's file is named by a key over what its result depends on: the
experiment, its VERSION (an explicit number the experiment bumps when the meaning
of its results changes; never a hash of the source files), the content hash of its
inputs (checkpoint, data), and the unit's own case, seed and parameters."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

from .fileio import atomic_write_bytes


def file_hash(path) -> str:
    """sha256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _canon(value) -> str:
    """A stable text of a key's part: JSON where it can be (sorted keys), else repr."""
    try:
        return json.dumps(value, sort_keys=True, default=repr)
    except (TypeError, ValueError):
        return repr(value)


class ResultStore:
    """The units of ``experiment`` (its ``version``) on inputs of content hash
    ``inputs`` (one string, or several hashed together) kept in ``folder``: one
    ``<kind>_<key>.json`` per unit, written atomically (a file is there complete or
    not at all)."""

    def __init__(self, folder, experiment: str, version: int, inputs=()):
        self.folder = Path(folder)
        self.experiment, self.version = experiment, int(version)
        self.inputs = json.loads(_canon(inputs))
        self.base = hashlib.sha256(_canon([experiment, self.version, inputs]).encode()).hexdigest()

    def key(self, *unit) -> str:
        """The key (20 hex) of a unit: its case, seed, parameters... after the store's base."""
        return hashlib.sha256(_canon([self.base, [_canon(u) for u in unit]]).encode()).hexdigest()[:20]

    def path(self, kind: str, *unit, suffix: str = ".json") -> Path:
        return self.folder / f"{kind}_{self.key(*unit)}{suffix}"

    def get(self, kind: str, *unit):
        """The stored value of a unit, or None."""
        p = self.path(kind, *unit)
        return json.loads(p.read_text())["result"] if p.is_file() else None

    def put(self, kind: str, value, *unit) -> None:
        """Keep a finished unit (with what it was and its inputs, for a reader of the file)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        doc = {"experiment": self.experiment, "version": self.version, "inputs": self.inputs, "kind": kind,
               "unit": json.loads(_canon(list(unit))), "result": value}
        atomic_write_bytes(self.path(kind, *unit), (json.dumps(doc, default=float) + "\n").encode())

    def pending(self, kind: str, units: list, log=print) -> list:
        """The units of ``units`` (each a tuple of key parts) not kept yet; says how many
        are done and how many are left."""
        todo = [u for u in units if not self.path(kind, *u).is_file()]
        self.report(kind, len(units), len(todo), log)
        return todo

    def report(self, what: str, total: int, left: int, log=print) -> None:
        """Say how much of a run is done ("N of M done, K left")."""
        if log is not None:
            log(f"{self.experiment} {what}: {total - left} of {total} done, {left} left ({self.folder})")
