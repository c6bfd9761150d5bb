"""Training data set: per robot-sample (robot type, neighbour set, label), CSR layout.

One sample is one robot at one time step (paper, "Data Collection"):

  robot_type[n]   int   index into Config.robot_types
  label_g[n]      f_a,z of that robot in grams
  scenario[n]     int   index into scenario_names (Table "data_collection")
  time_s[n]       s     time within the scenario's flight
  nbr_offsets     [N+1] neighbours of sample n are rows offsets[n]:offsets[n+1]
  nbr_type[m]     int   index into Config.neighbor_types (environment last)
  nbr_state[m]    6     x_ij = [p_j - p_i; v_j - v_i] (m, m/s, world frame);
                        the environment row is [-p_i; -v_i] (p_j = v_j = 0);
                        6 more per lag of the config's model.history_ms
                        (the same neighbour's x_ij that long ago)

Within a sample the neighbour rows are grouped by type in ascending type index,
so the environment row (always present) is the last one.  Saved as ``.npz``.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..fileio import file_mode
from ..errors import Ns2Error

FORMAT = "ns2codegen-dataset-v1"
# physical bounds of the stored values; beyond them a file is corrupt (a label of
# 3e38 g or a state of 1e30 m breaks the training's linear algebra)
MAX_ABS_LABEL_G = 1.0e4
MAX_ABS_STATE = 1.0e3   # m, m/s
MAX_ABS_TIME_S = 1.0e9


class DatasetError(Ns2Error, ValueError):
    """The data set file is malformed."""


@dataclass
class Dataset:
    robot_type: np.ndarray
    label_g: np.ndarray
    scenario: np.ndarray
    time_s: np.ndarray
    nbr_offsets: np.ndarray
    nbr_type: np.ndarray
    nbr_state: np.ndarray
    neighbor_types: list[str]
    scenario_names: list[str]
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.robot_type.shape[0])

    # ------------------------------------------------------------------
    def validated(self) -> "Dataset":
        n = len(self)
        for name in ("label_g", "scenario", "time_s"):
            if getattr(self, name).shape != (n,):
                raise DatasetError(f"{name} must have shape ({n},)")
        off = self.nbr_offsets
        if off.shape != (n + 1,) or off[0] != 0 or np.any(np.diff(off) < 0):
            raise DatasetError("nbr_offsets must be a non-decreasing CSR offset array starting at 0")
        m = int(off[-1])
        if (self.nbr_type.shape != (m,) or self.nbr_state.ndim != 2 or self.nbr_state.shape[0] != m
                or self.nbr_state.shape[1] < 6 or self.nbr_state.shape[1] % 6):
            raise DatasetError("nbr_type / nbr_state do not match nbr_offsets (rows of 6 values, or 6 per "
                               "history lag more)")
        nt = len(self.neighbor_types)
        if m and (self.nbr_type.min() < 0 or self.nbr_type.max() >= nt):
            raise DatasetError("nbr_type out of range")
        if n and (self.robot_type.min() < 0 or self.robot_type.max() >= nt - 1):
            raise DatasetError("robot_type out of range")
        if n and (self.scenario.min() < 0 or self.scenario.max() >= len(self.scenario_names)):
            raise DatasetError("scenario out of range")
        for name, bound, unit in (("label_g", MAX_ABS_LABEL_G, "g"), ("nbr_state", MAX_ABS_STATE, "m, m/s"),
                                  ("time_s", MAX_ABS_TIME_S, "s")):
            a = getattr(self, name)
            if not np.all(np.isfinite(a)):
                raise DatasetError(f"{name}: must be finite (has NaN or Inf)")
            if a.size and float(np.abs(a).max()) > bound:
                raise DatasetError(f"{name}: |value| {float(np.abs(a).max()):.3g} beyond the physical bound "
                                   f"{bound:g} {unit}")
        # every sample has exactly one environment row, and it is the last one
        env = nt - 1
        is_env = self.nbr_type == env
        if n and (np.any(np.diff(off) < 1) or not np.all(is_env[off[1:] - 1])
                  or int(is_env.sum()) != n):
            raise DatasetError("every sample needs exactly one environment neighbour, listed last")
        return self

    def content_hash(self) -> str:
        h = hashlib.sha256()
        for a in (self.robot_type, self.label_g, self.scenario, self.time_s,
                  self.nbr_offsets, self.nbr_type, self.nbr_state):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(json.dumps([self.neighbor_types, self.scenario_names]).encode())
        return h.hexdigest()

    def subset(self, mask: np.ndarray) -> "Dataset":
        idx = np.flatnonzero(mask)
        counts = np.diff(self.nbr_offsets)[idx]
        offsets = np.zeros(len(idx) + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        rows = np.repeat(self.nbr_offsets[idx] - offsets[:-1], counts) + np.arange(offsets[-1])
        return Dataset(self.robot_type[idx], self.label_g[idx], self.scenario[idx], self.time_s[idx],
                       offsets, self.nbr_type[rows], self.nbr_state[rows],
                       self.neighbor_types, self.scenario_names, dict(self.extra))

    @staticmethod
    def concat(parts: list["Dataset"]) -> "Dataset":
        """One data set from several with the same neighbour types; scenarios are
        merged by name and times shifted so that flights follow each other."""
        if not parts:
            raise DatasetError("nothing to concatenate")
        types = parts[0].neighbor_types
        if any(p.neighbor_types != types for p in parts):
            raise DatasetError("data sets with different neighbour types")
        names: list[str] = []
        for p in parts:
            names += [n for n in p.scenario_names if n not in names]
        offsets, scen, times, shift = [np.zeros(1, np.int64)], [], [], 0.0
        for p in parts:
            offsets.append(p.nbr_offsets[1:] + offsets[-1][-1])
            scen.append(np.array([names.index(n) for n in p.scenario_names], np.int64)[p.scenario])
            times.append(p.time_s + shift)
            shift += float(p.time_s.max() + 1.0) if len(p) else 0.0
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
        return Dataset(cat("robot_type"), cat("label_g"), np.concatenate(scen), np.concatenate(times),
                       np.concatenate(offsets), cat("nbr_type"), cat("nbr_state"), types, names,
                       {"parts": [p.extra for p in parts]}).validated()

    # ------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        path = Path(path)
        meta = json.dumps({"format": FORMAT, "neighbor_types": self.neighbor_types,
                           "scenario_names": self.scenario_names, "extra": self.extra})
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp.npz")
        os.close(fd)
        os.chmod(tmp, file_mode())
        try:
            np.savez_compressed(tmp, meta=np.array(meta), robot_type=self.robot_type, label_g=self.label_g,
                                scenario=self.scenario, time_s=self.time_s, nbr_offsets=self.nbr_offsets,
                                nbr_type=self.nbr_type, nbr_state=self.nbr_state)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @staticmethod
    def load(path: str | Path, neighbor_types: list[str] | None = None) -> "Dataset":
        """The data set of ``path``; it must have samples and, when given, exactly these
        neighbour types (those of the config it is used with)."""
        try:
            with np.load(path, allow_pickle=False) as z:
                try:
                    meta = json.loads(str(z["meta"]))
                except json.JSONDecodeError as e:
                    raise DatasetError(f"meta: not JSON ({e})") from None
                if not isinstance(meta, dict) or meta.get("format") != FORMAT:
                    raise DatasetError(f"meta: not an {FORMAT} file")
                names, scen = meta.get("neighbor_types"), meta.get("scenario_names")
                if not (isinstance(names, list) and len(names) >= 2 and all(isinstance(n, str) for n in names)):
                    raise DatasetError(f"meta.neighbor_types: must be a list of >= 2 names, got {names!r}")
                if not (isinstance(scen, list) and all(isinstance(n, str) for n in scen)):
                    raise DatasetError(f"meta.scenario_names: must be a list of names, got {scen!r}")
                arrays = {}
                for key, dtype in (("robot_type", np.int64), ("label_g", np.float32), ("scenario", np.int64),
                                   ("time_s", np.float64), ("nbr_offsets", np.int64), ("nbr_type", np.int64),
                                   ("nbr_state", np.float32)):
                    a = z[key]
                    if a.dtype.kind not in "iuf" or (dtype is np.int64 and a.dtype.kind == "f"):
                        raise DatasetError(f"{key}: must be {'integer' if dtype is np.int64 else 'numeric'}, "
                                           f"got {a.dtype}")
                    with np.errstate(over="ignore", invalid="ignore"):
                        arrays[key] = a.astype(dtype)
                ds = Dataset(**arrays, neighbor_types=names, scenario_names=scen,
                             extra=meta.get("extra", {})).validated()
        except DatasetError as e:
            raise DatasetError(f"data set {path}: {e}") from None
        except Exception as e:  # zip/npz/json/key errors: one clear message
            raise DatasetError(f"cannot read data set {path}: {type(e).__name__}: {e}") from None
        if len(ds) == 0:
            raise DatasetError(f"data set {path}: robot_type: no samples")
        if neighbor_types is not None and ds.neighbor_types != list(neighbor_types):
            raise DatasetError(f"data set {path}: meta.neighbor_types {ds.neighbor_types} differ from the "
                               f"config's {list(neighbor_types)}")
        return ds


def scenario_name(robot_types: list[str], receiver: str, others: list[str]) -> str:
    """Table "data_collection" naming: "S", "L->S", "{S,L}->S" (first letters when
    they are unique among the robot types, full names otherwise)."""
    short = [n[0].upper() for n in robot_types]
    short = dict(zip(robot_types, short if len(set(short)) == len(short) else robot_types))
    others = sorted(others, key=robot_types.index)
    if not others:
        return short[receiver]
    if len(others) == 1:
        return f"{short[others[0]]}->{short[receiver]}"
    return "{" + ",".join(short[o] for o in others) + "}->" + short[receiver]


def split_by_pieces(ds: Dataset, pieces: int = 50, val_fraction: float = 0.2, seed: int = 0) -> np.ndarray:
    """Boolean validation mask: each scenario's samples, in time order, cut into
    ``pieces`` contiguous pieces of equal size (the paper's "equally split the total
    trajectory into 50 shorter pieces"; counting samples rather than seconds keeps
    pieces meaningful when a scenario's flights are not back to back), and
    ``val_fraction`` of the pieces (seeded) held out."""
    rng = np.random.default_rng(seed)
    val = np.zeros(len(ds), dtype=bool)
    n_val = max(1, int(round(pieces * val_fraction)))
    for s in range(len(ds.scenario_names)):
        idx = np.flatnonzero(ds.scenario == s)
        if idx.size == 0:
            continue
        idx = idx[np.argsort(ds.time_s[idx], kind="stable")]
        piece = np.arange(idx.size) * pieces // idx.size
        held = rng.choice(pieces, size=n_val, replace=False)
        val[idx[np.isin(piece, held)]] = True
    return val
