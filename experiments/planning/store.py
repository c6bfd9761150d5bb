"""The finished work of a planning experiment kept in its output folder, so that a
run cut short goes on where it stopped (TrialStore), keyed by the code it ran."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ns2codegen.fileio import atomic_write_bytes


RESUME_DIR = "resume"     # planning_experiments' finished work, in its output folder (TrialStore)
# the sources a trial's outcome depends on (planner, experiments, simulator, the C it flies), relative to the
# repository: a change to any of them starts a resumed run afresh
CODE_GLOBS = ("planner/*.py", "experiments/*.py", "experiments/planning/*.py", "host/*.py", "host/sim/*.py", "host/*.c",
              "host/*.h", "firmware/src/*.c", "firmware/include/*.h", "ns2codegen/*.py", "ns2codegen/data/*.py", "templates/*")


def code_tag(root: Path | None = None) -> str:
    """sha256 (16 hex) over the sources of CODE_GLOBS under ``root`` (this repository)."""
    root = Path(__file__).resolve().parents[2] if root is None else Path(root)
    h = hashlib.sha256()
    for pattern in CODE_GLOBS:
        for f in sorted(root.glob(pattern)):
            if f.is_file():
                h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


class TrialStore:
    """planning_experiments' finished work kept in ``folder`` so that a run cut short
    goes on where it stopped: the margin (``margin_<key>.json``), every trial's record
    (``trial_<key>.json``) and the plan and flight of each case's example trial
    (``example_<key>.pkl``, for the figures and the Crazyflie files).  A key is a hash
    of everything the result depends on: the checkpoint's bytes, the code (code_tag),
    the case, seed, margin and parameters; anything else changed, nothing is reused."""

    def __init__(self, folder, checkpoint, *inputs):
        self.folder = Path(folder)
        h = hashlib.sha256(Path(checkpoint).read_bytes() if checkpoint is not None else b"BL")
        h.update(json.dumps([code_tag(), *map(repr, inputs)]).encode())
        self.base = h.hexdigest()

    def _path(self, kind: str, suffix: str, *key) -> Path:
        tag = hashlib.sha256(json.dumps([self.base, *map(repr, key)]).encode()).hexdigest()[:20]
        return self.folder / f"{kind}_{tag}{suffix}"

    def get(self, kind: str, *key):
        """The stored JSON value of ``kind`` and ``key``, or None."""
        p = self._path(kind, ".json", *key)
        return json.loads(p.read_text()) if p.is_file() else None

    def put(self, kind: str, value, *key) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self._path(kind, ".json", *key), (json.dumps(value, default=float) + "\n").encode())

    def get_example(self, *key):
        import pickle

        p = self._path("example", ".pkl", *key)
        return pickle.loads(p.read_bytes()) if p.is_file() else None

    def put_example(self, value, *key) -> None:
        import pickle

        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self._path("example", ".pkl", *key), pickle.dumps(value))
