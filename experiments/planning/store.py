"""The finished work of a planning experiment kept in its output folder, so that a
run cut short goes on where it stopped (TrialStore, on ns2codegen.results)."""
from __future__ import annotations

import pickle
from pathlib import Path

from ns2codegen.fileio import atomic_write_bytes
from ns2codegen.results import ResultStore, file_hash


RESUME_DIR = "resume"     # planning_experiments' finished work, in its output folder (TrialStore)
# the meaning of a kept trial, margin or example: bump it when a change to the planner, the
# simulator, the flown C or the trial's record changes what a trial of the same inputs gives
VERSION = 1


def runs_folder(out_dir, runs_dir=None) -> Path:
    """Where a run keeps its finished work (trials, margin, the plan-data rounds' models in
    ``models/``): ``runs_dir``, or by default ``out_dir``/RESUME_DIR."""
    return Path(runs_dir) if runs_dir is not None else Path(out_dir) / RESUME_DIR


class TrialStore(ResultStore):
    """planning_experiments' finished work kept in ``folder`` so that a run cut short
    goes on where it stopped: the margin (``margin_<key>.json``), every trial's record
    (``trial_<key>.json``) and the plan and flight of each case's example trial
    (``example_<key>.pkl``, for the figures and the Crazyflie files; in ``examples``,
    default ``folder``: they are not small JSON).  A key is a hash
    of everything the result depends on: the checkpoint's bytes, VERSION, the case,
    seed, margin and parameters; anything else changed, nothing is reused."""

    def __init__(self, folder, checkpoint, *inputs, examples=None):
        ck = file_hash(checkpoint) if checkpoint is not None else "BL"
        super().__init__(folder, "planning", VERSION, [ck, *map(repr, inputs)])
        self.examples = Path(examples) if examples is not None else self.folder

    def _example(self, key) -> Path:
        return self.examples / self.path("example", *key, suffix=".pkl").name

    def has_example(self, *key) -> bool:
        return self._example(key).is_file()

    def get_example(self, *key):
        p = self._example(key)
        return pickle.loads(p.read_bytes()) if p.is_file() else None

    def put_example(self, value, *key) -> None:
        self.examples.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self._example(key), pickle.dumps(value))
