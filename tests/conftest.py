"""Shared fixtures: a small model trained on the analytic downwash data, exported
and built for the host once per test session."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from ns2codegen.checkpoint import load_checkpoint, save_checkpoint
from ns2codegen.config import ONBOARD_WIDTHS, Config
from ns2codegen.data.analytic import downwash_dataset
from ns2codegen.export import export
from ns2codegen.quantize import ExportModel, from_checkpoint
from ns2codegen.train import train


# Tools the tests need (``needs``): missing ones skip those tests, or fail them with CI=true.
ARM, QEMU, FIRMWARE = "arm-none-eabi-gcc", "qemu-system-arm", "crazyflie-firmware"
REAL_DATA = "neural-swarm-data"   # the paper's authors' flight logs in ../shared
CI = os.environ.get("CI", "").lower() == "true"


def _have(tool: str) -> bool:
    from ns2host import crazyflie, target

    return {ARM: target.have_toolchain, QEMU: target.have_qemu, FIRMWARE: crazyflie.have_firmware,
            REAL_DATA: lambda: all((crazyflie.SHARED / "neural-swarm-data" / t).is_file() for t in REAL_TARBALLS)}[tool]()


REAL_TARBALLS = ("neural-swarm-2019-12.tar.xz", "neural-swarm-2020-06-16-swaps.tar.xz",
                 "neural-swarm-2020-06-16-randomwalks-1.tar.xz",
                 "neural-swarm-2020-06-16-randomwalks-2.tar.xz")


def real_logs(tarball: str, members: list[str]) -> Path:
    """A folder holding ``members`` (paths inside ``tarball`` of ../shared/neural-swarm-data),
    extracted once into a cache under build/ (the data are never committed).  Concurrent
    test workers race safely: each extracts into its own folder, the first rename wins."""
    import hashlib
    import shutil
    import tarfile
    import tempfile

    from ns2host import crazyflie

    src = crazyflie.SHARED / "neural-swarm-data" / tarball
    key = hashlib.sha256(f"{tarball}:{src.stat().st_size}:{sorted(members)}".encode()).hexdigest()[:16]
    root = Path(__file__).resolve().parents[1] / "build" / "test-real" / key
    if not (root / ".done").is_file():
        root.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key}-", dir=root.parent))
        with tarfile.open(src) as tar:
            tar.extractall(tmp, members=[tar.getmember(m) for m in members], filter="data")
        (tmp / ".done").write_text("")
        if root.exists() and not (root / ".done").is_file():
            shutil.rmtree(root, ignore_errors=True)       # a half-made folder of an older layout
        try:
            tmp.rename(root)
        except OSError:                                    # another worker's folder is in place
            shutil.rmtree(tmp, ignore_errors=True)
    return root


def needs(*tools: str):
    """Mark a test (or ``pytestmark`` a module) as needing these tools."""
    return pytest.mark.needs(*tools)


def pytest_configure(config):
    config.addinivalue_line("markers", "needs(*tools): skipped without the tools, failed with CI=true")


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Before any fixture: a missing tool skips the test, or fails it with CI=true."""
    for mark in item.iter_markers("needs"):
        missing = [t for t in mark.args if not _have(t)]
        if missing:
            msg = f"{', '.join(missing)} missing (scripts/install-deps.sh; ../shared beside the checkout)"
            if CI:
                pytest.fail(f"CI=true: {msg}", pytrace=False)
            pytest.skip(msg)


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
    ds = downwash_dataset(cfg.with_overrides(history_ms=[]) if cfg.history_ms else cfg, samples, seed=seed)
    if cfg.history_ms:  # a stationary past: every row's present state again at each lag
        ds.nbr_state = np.tile(ds.nbr_state, (1, 1 + len(cfg.history_ms)))
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


HISTORY_MS = [50, 100, 200]   # the wake memory of docs/real-flights.md section 10


@pytest.fixture(scope="session")
def history(tmp_path_factory, cfg) -> Exported:
    """A small network with wake memory (model.history_ms): phi sees x_ij now and 50,
    100 and 200 ms ago (24 inputs), trained briefly on the analytic data with a
    stationary past."""
    return train_and_export(cfg.with_overrides(history_ms=HISTORY_MS), tmp_path_factory.mktemp("history"),
                            samples=500, epochs=2)


@pytest.fixture(scope="session")
def onboard(tmp_path_factory, cfg) -> Exported:
    """The one-tick on-board variant of the network (narrower intermediate layers)."""
    return train_and_export(cfg.with_overrides(**ONBOARD_WIDTHS), tmp_path_factory.mktemp("onboard"),
                            samples=500, epochs=2)


class SmallCtl:
    """The host build and one controller of the small robot as the app initialises it
    (``ctrl[0]`` owns the vehicle and gains); ``fresh()`` a new ns2_ctrl_t from them
    (``**gains``: fields to replace), ``hover()`` a state and setpoint at rest at 1 m."""

    def __init__(self, cfg, exported):
        from ns2codegen.vehicle import vehicle

        self.c = exported.cmodel()
        self.ffi, self.lib = self.c.ffi, self.c.lib
        self.ctrl = self.c.controller([vehicle(cfg, "small")])

    def fresh(self, veh=None, **gains):
        ffi = self.ffi
        g = ffi.new("ns2_gains_t *", self.ctrl[0].g)
        for k, v in gains.items():
            setattr(g, k, v)
        x = ffi.new("ns2_ctrl_t *")
        self.lib.ns2_ctrl_init(x, veh if veh is not None else ffi.new("ns2_vehicle_t *", self.ctrl[0].veh), g)
        return x

    def hover(self):
        st, sp = self.ffi.new("ns2_ctrl_state_t *"), self.ffi.new("ns2_setpoint_t *")
        st.q, st.p, sp.p = [1, 0, 0, 0], [0, 0, 1], [0, 0, 1]
        return st, sp


@pytest.fixture(scope="module")
def small_ctl(cfg, exported) -> SmallCtl:
    return SmallCtl(cfg, exported)
