"""Checkpoints: weights plus the metadata the exporter and the C need.

A checkpoint is a ``torch.save`` dict (a zip archive), loaded with ``weights_only=True``:
  format, version, model_hash, state_dict (float32 tensors), meta_json (JSON text):
  config (the whole validated config: types, vehicles, dims, volumes, boxes),
  phi_dims, rho_dims, gamma, normalization, data_hash, seed, report (without its timing,
  TIMING_KEYS: the same data, config and seed give the same bytes).

Integrity (docs/inputs.md): ``model_hash`` is ``Checkpoint.model_hash()`` (sha256 over
the weights and the config), written at save; every load checks the archive's CRC-32s,
then validates the config and the weights, then recomputes the hash and refuses the
file if it differs.  The export's NS2_MODEL_ID and manifest hash are this hash.
Version 1 checkpoints (written before the record existed) load with a warning.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import warnings
import zipfile
from pathlib import Path

import torch

from .config import Config, ConfigError
from .fileio import atomic_write_bytes
from .model import HeteroDeepSet
from .errors import Ns2Error, Ns2Warning

FORMAT = "ns2codegen-checkpoint"
VERSION = 2          # 2: carries model_hash; 1: without it (loads with a warning)

# Inputs and outputs are used in physical units: no input or output scaling.
NORMALIZATION = {"input": "none: x_ij in m and m/s (world frame)", "output": "none: f_a,z in grams"}


class CheckpointError(Ns2Error, ValueError):
    """The checkpoint cannot be used (corrupt, truncated, inconsistent, non-finite)."""


# a training report's timing: how fast this machine was, not what was trained (kept out of
# the file, so a checkpoint's bytes are a function of its data, config and seed alone)
TIMING_KEYS = ("train_seconds", "samples_per_second")


def save_checkpoint(path: str | Path, model: HeteroDeepSet, cfg: Config, meta: dict) -> None:
    meta = dict(meta)
    if isinstance(meta.get("report"), dict):
        meta["report"] = {k: v for k, v in meta["report"].items() if k not in TIMING_KEYS}
    meta.update(config=cfg.raw, phi_dims=cfg.phi_dims(), rho_dims=cfg.rho_dims(),
                gamma=float(cfg.model["gamma"]), normalization=NORMALIZATION)
    state = {k: v.detach().to(torch.float32).contiguous().clone() for k, v in model.state_dict().items()}
    buf = io.BytesIO()
    torch.save({"format": FORMAT, "version": VERSION, "model_hash": Checkpoint(state, meta, cfg).model_hash(),
                "state_dict": state, "meta_json": json.dumps(meta, sort_keys=True)}, buf)
    atomic_write_bytes(Path(path), buf.getvalue())


class Checkpoint:
    """A loaded, validated checkpoint."""

    def __init__(self, state_dict: dict, meta: dict, cfg: Config):
        self.state_dict = state_dict
        self.meta = meta
        self.cfg = cfg

    def model(self) -> HeteroDeepSet:
        m = HeteroDeepSet(self.cfg)
        m.load_state_dict(self.state_dict)
        return m.eval()

    def net_weights(self, kind: str, index: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """[(W [out, in], b [out])] of phi/rho net ``index``."""
        n = len(self.cfg.phi_dims() if kind == "phi" else self.cfg.rho_dims()) - 1
        return [(self.state_dict[f"{kind}.{index}.layers.{l}.weight"],
                 self.state_dict[f"{kind}.{index}.layers.{l}.bias"]) for l in range(n)]

    def model_hash(self) -> str:
        """sha256 over the float32 weights (in key order) and the config."""
        h = hashlib.sha256()
        for k in sorted(self.state_dict):
            h.update(k.encode())
            h.update(self.state_dict[k].numpy().tobytes())
        h.update(self.cfg.to_json().encode())
        return h.hexdigest()


class LegacyCheckpointWarning(Ns2Warning):
    """A checkpoint without an integrity record (version 1)."""


def _check_archive(path: Path) -> None:
    """The zip archive of ``path`` is complete and every member matches its CRC-32
    (torch.load itself does not check them)."""
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
    except zipfile.BadZipFile:
        raise CheckpointError(f"checkpoint {path} is corrupt or truncated: not a complete zip archive") from None
    except (OSError, EOFError, ValueError, NotImplementedError, RuntimeError) as e:
        raise CheckpointError(f"checkpoint {path} is corrupt or truncated: its archive cannot be read "
                              f"({type(e).__name__})") from None
    if bad is not None:
        raise CheckpointError(f"checkpoint {path} is corrupt: archive member {bad[:60]!r} fails its CRC-32 check")


def _torch_load(path: Path) -> dict:
    """``torch.load`` of a checked archive; its errors summarized in one line."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - torch raises anything from pickle, zip and storage code
        if "weights_only" in str(e) or type(e).__name__ == "UnpicklingError":
            raise CheckpointError(f"checkpoint {path} holds objects other than tensors and plain data: "
                                  "not an ns2codegen checkpoint (refused without running its code)") from None
        raise CheckpointError(f"checkpoint {path} is corrupt or truncated: torch cannot read it "
                              f"({type(e).__name__})") from None


def _no_constant(name: str):
    raise ValueError(f"{name} is not a finite number")


def load_checkpoint(path: str | Path) -> Checkpoint:
    """The checkpoint of ``path``, checked: archive CRCs, format, config (the one
    config validator), weights (names, shapes, dtype, finite, magnitude), and the
    recorded model hash against the recomputed one."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    _check_archive(path)
    obj = _torch_load(path)
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise CheckpointError(f"checkpoint {path} is not an ns2codegen checkpoint (no format {FORMAT!r})")
    version = obj.get("version")
    if type(version) is not int or version not in (1, VERSION):
        raise CheckpointError(f"checkpoint {path}: unsupported version {str(obj.get('version'))[:20]!r} "
                              f"(this ns2codegen reads 1 and {VERSION})")
    recorded = obj.get("model_hash")
    if version == VERSION and not (isinstance(recorded, str) and len(recorded) == 64):
        raise CheckpointError(f"checkpoint {path}: model_hash is missing or malformed")
    try:
        meta = json.loads(obj["meta_json"], parse_constant=_no_constant)
    except (KeyError, TypeError, ValueError):
        raise CheckpointError(f"checkpoint {path}: meta_json is missing or not JSON of finite numbers") from None
    if not isinstance(meta, dict) or "config" not in meta:
        raise CheckpointError(f"checkpoint {path}: meta_json has no config")
    if not isinstance(meta.get("report", {}), dict):
        raise CheckpointError(f"checkpoint {path}: meta_json report must be a table")
    try:
        cfg = Config.from_dict(meta["config"], f"checkpoint {path}: config")
    except ConfigError as e:
        raise CheckpointError(str(e)) from None
    state = obj.get("state_dict")
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: no state_dict")
    expected = HeteroDeepSet(cfg).state_dict()
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    if missing or extra:
        raise CheckpointError(f"{path}: state_dict does not match the config "
                              f"(missing {missing[:4]}, unexpected {extra[:4]})")
    for k, ref in expected.items():
        t = state[k]
        if not isinstance(t, torch.Tensor) or tuple(t.shape) != tuple(ref.shape):
            raise CheckpointError(f"{path}: {k} has shape {tuple(getattr(t, 'shape', ()))}, "
                                  f"expected {tuple(ref.shape)}")
        if t.dtype != torch.float32:
            raise CheckpointError(f"{path}: {k} is {t.dtype}, expected float32")
        if not bool(torch.isfinite(t).all()):
            raise CheckpointError(f"{path}: {k} contains NaN or Inf")
        if float(t.abs().max()) > 1e30 or math.isnan(float(t.abs().max())):
            raise CheckpointError(f"{path}: {k} has absurd magnitude")
    ck = Checkpoint(state, meta, cfg)
    if recorded is None:
        warnings.warn(f"checkpoint {path} has no integrity record (version 1): its archive CRCs were checked, "
                      "its model hash could not be; save it again (docs/inputs.md)", LegacyCheckpointWarning,
                      stacklevel=2)
    elif ck.model_hash() != recorded:
        raise CheckpointError(f"checkpoint {path}: the weights and config do not match its recorded model_hash "
                              f"{recorded[:16]}... (modified or corrupted after it was saved)")
    return ck
