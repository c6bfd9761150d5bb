"""The model that flies is the model exported (docs/flying.md, "Safety checks").

Every generated header carries ``NS2_MODEL_ID``: ``0x`` and the first 15 hex digits
of the model hash (sha256 of weights and config, ``Checkpoint.model_hash``; written
by ns2codegen/export.py).  The app exposes its low 32 bits as the read-only
parameter ``ns2.modelId``; the ground side reads it from every robot before
anything else and refuses to fly a robot whose value differs from the export's."""
from __future__ import annotations

import json
from pathlib import Path

from ns2codegen.errors import Ns2Error
from ns2codegen.export import MANIFEST

PARAM = "ns2.modelId"


class FingerprintError(Ns2Error, RuntimeError):
    """A robot flies another model than the export, or no ns2 app at all."""


def model_id(model_hash: str) -> int:
    """``ns2.modelId`` of a model: the low 32 bits of NS2_MODEL_ID = int(hash[:15], 16)."""
    return int(model_hash[:15], 16) & 0xFFFF_FFFF


def export_id(export_dir) -> tuple[int, str]:
    """(``ns2.modelId``, model hash) of an export folder, from its manifest."""
    path = Path(export_dir) / MANIFEST
    try:
        h = json.loads(path.read_text())["model_hash"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise FingerprintError(f"{path}: model_hash: cannot read the export's manifest ({e})") from e
    if not (isinstance(h, str) and len(h) == 64 and all(c in "0123456789abcdef" for c in h)):
        raise FingerprintError(f"{path}: model_hash: not a sha256 hex digest")
    return model_id(h), h


def check(robot: str, value: int | None, expected: int, model_hash: str) -> None:
    """One line naming the robot when its firmware is not the export's."""
    if value is None:
        raise FingerprintError(f"{robot}: no parameter {PARAM}: the ns2 app is not on this robot "
                               f"(ns2 flash, docs/flying.md)")
    if int(value) != expected:
        raise FingerprintError(f"{robot}: flies model 0x{int(value):08x}, the export is 0x{expected:08x} "
                               f"({model_hash[:16]}): flash the export's build (ns2 flash) or name its export")
