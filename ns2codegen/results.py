"""The finished units of a long experiment (a trial, a replay, a training), each kept
as its own small JSON file the moment it finishes, so that a run cut short (or
continued another day, by someone else from the committed files) redoes only what
is missing.  A unit's file is named by a key over what its result depends on: the
experiment, its VERSION (an explicit number the experiment bumps when the meaning
of its results changes; never a hash of the source files), the content hash of its
inputs (checkpoint, data), and the unit's own case, seed and parameters.

Every experiment's top-level result (``stamp``) also names the commit and the command
that made it, so that ``make results`` can say where each table's numbers come from."""
from __future__ import annotations

import datetime
import hashlib
import json
import shlex
import subprocess
import sys
from pathlib import Path

from .fileio import atomic_write_bytes


def file_hash(path) -> str:
    """sha256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


REPO = Path(__file__).resolve().parent.parent


def commit(repo=REPO) -> str:
    """The checkout's HEAD (short: 7 hex), + "-dirty" if a tracked file differs from it;
    "unknown" outside a git checkout (an installed package) or without git: the
    ``commit`` of every file a run writes."""
    def git(*args):
        return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=60)
    try:
        head = git("rev-parse", "--short=7", "--verify", "HEAD")
        if head.returncode != 0 or not (Path(repo) / ".git").exists():
            return "unknown"
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head.stdout.strip() + ("-dirty" if dirty.returncode != 0 or dirty.stdout.strip() else "")


def command_line(argv=None, prog: str | None = None) -> str:
    """The command line as typed: ``ns2 ...`` for the CLI (``python -m ns2cli`` or the
    ``ns2`` script), a script by its path in the checkout, arguments shell-quoted; ``prog``
    names a module run as ``python -m ...`` (its argparse ``prog``), whose argv[0] is a file."""
    argv = list(sys.argv if argv is None else argv)
    if prog is not None:
        return " ".join([prog, *(shlex.quote(a) for a in argv[1:])])
    prog = Path(argv[0]) if argv and argv[0] else Path("python")
    if prog.name == "ns2" or (prog.name == "__main__.py" and prog.parent.name in ("cli", "ns2cli")):
        name = "ns2"
    else:
        try:
            name = prog.resolve().relative_to(REPO).as_posix()
        except ValueError:
            name = prog.name
    return " ".join([name, *(shlex.quote(a) for a in argv[1:])])


def provenance(command: str | None = None) -> dict:
    """What made a result: {"commit", "command", "date" (UTC, ISO 8601)}."""
    date = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()
    return {"commit": commit(), "command": command_line() if command is None else command, "date": date}


def stamp(doc: dict, command: str | None = None) -> dict:
    """``doc`` (an experiment's top-level result) with its ``provenance`` (key
    "provenance"); the numbers untouched."""
    if not isinstance(doc, dict):
        raise TypeError(f"a result to stamp is a JSON object, not {type(doc).__name__}")
    return dict(doc, provenance=provenance(command))


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
