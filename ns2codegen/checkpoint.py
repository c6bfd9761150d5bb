"""Checkpoints: weights plus the metadata the exporter and the C need.

A checkpoint is a ``torch.save`` dict, loaded with ``weights_only=True``:
  format, version, state_dict (float32 tensors), meta (JSON-able):
  config (the whole validated config: types, vehicles, dims, volumes, boxes),
  phi_dims, rho_dims, gamma, normalization, data_hash, seed, report.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
from pathlib import Path

import torch

from .config import Config, ConfigError
from .fileio import atomic_write_bytes
from .model import HeteroDeepSet
from .errors import Ns2Error

FORMAT = "ns2codegen-checkpoint"
VERSION = 1

# Inputs and outputs are used in physical units: no input or output scaling.
NORMALIZATION = {"input": "none: x_ij in m and m/s (world frame)", "output": "none: f_a,z in grams"}


class CheckpointError(Ns2Error, ValueError):
    """The checkpoint cannot be used (corrupt, truncated, inconsistent, non-finite)."""


def save_checkpoint(path: str | Path, model: HeteroDeepSet, cfg: Config, meta: dict) -> None:
    meta = dict(meta)
    meta.update(config=cfg.raw, phi_dims=cfg.phi_dims(), rho_dims=cfg.rho_dims(),
                gamma=float(cfg.model["gamma"]), normalization=NORMALIZATION)
    state = {k: v.detach().to(torch.float32).contiguous().clone() for k, v in model.state_dict().items()}
    buf = io.BytesIO()
    torch.save({"format": FORMAT, "version": VERSION, "state_dict": state,
                "meta_json": json.dumps(meta, sort_keys=True)}, buf)
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


def load_checkpoint(path: str | Path) -> Checkpoint:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # truncated zip, garbage bytes, pickle errors...
        raise CheckpointError(f"checkpoint {path} is corrupt or truncated: {e}") from e
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not an ns2codegen checkpoint")
    if obj.get("version") != VERSION:
        raise CheckpointError(f"{path}: unsupported checkpoint version {obj.get('version')!r}")
    try:
        meta = json.loads(obj["meta_json"])
        cfg = Config.from_dict(meta["config"])
    except (KeyError, TypeError, json.JSONDecodeError, ConfigError) as e:
        raise CheckpointError(f"{path}: bad metadata: {e}") from e
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
    return Checkpoint(state, meta, cfg)
