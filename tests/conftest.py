"""Shared fixtures: a small model trained on the analytic downwash data, exported
and built for the host once per test session."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from ns2codegen.checkpoint import load_checkpoint, save_checkpoint
from ns2codegen.config import ONBOARD_WIDTHS, Config
from ns2codegen.data.analytic import downwash_dataset
from ns2codegen.export import export
from ns2codegen.quantize import ExportModel, from_checkpoint
from ns2codegen.train import train


@dataclass
class Exported:
    cfg: Config
    checkpoint: Path
    gen_dir: Path
    model: object          # trained torch HeteroDeepSet
    em: ExportModel        # exported tables (float + fixed)
    manifest: dict
    report: dict

    def cmodel(self):
        from ns2host.cbuild import CModel

        return CModel(self.gen_dir)


def train_and_export(cfg: Config, root: Path, samples: int = 1500, epochs: int = 8, seed: int = 0) -> Exported:
    root.mkdir(parents=True, exist_ok=True)
    ds = downwash_dataset(cfg, samples, seed=seed)
    model, report = train(cfg, ds, epochs=epochs, seed=seed)
    ck = root / "model.pt"
    save_checkpoint(ck, model, cfg, {"seed": seed, "data_hash": ds.content_hash(), "report": report})
    man = export(ck, root / "gen")
    return Exported(cfg, ck, root / "gen", model, from_checkpoint(load_checkpoint(ck)), man, report)


@pytest.fixture(scope="session")
def cfg() -> Config:
    return Config.load()


@pytest.fixture(scope="session")
def exported(tmp_path_factory, cfg) -> Exported:
    return train_and_export(cfg, tmp_path_factory.mktemp("default"))


@pytest.fixture(scope="session")
def onboard(tmp_path_factory, cfg) -> Exported:
    """The one-tick on-board variant of the network (narrower intermediate layers)."""
    return train_and_export(cfg.with_overrides(**ONBOARD_WIDTHS), tmp_path_factory.mktemp("onboard"),
                            samples=500, epochs=2)
