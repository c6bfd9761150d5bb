"""Bitcraze's crazyflie-firmware, the real one, for builds and host compiles.

The pinned, trimmed tarball lives in ``../shared/crazyflie-firmware/`` beside the
checkout (see its README).  ``firmware_dir()`` unpacks it once under
``build/crazyflie-firmware`` and returns that tree; ``CRAZYFLIE_BASE`` (env) points at
another checkout instead.  Everything that compiles firmware code (the app build, the
host build of ``kalman_core`` and the stock controllers, their Cortex-M4 counts) goes
through here, so there is one place that knows where the firmware is.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from ns2codegen.errors import Ns2Error

# the source checkout and its build folder (stdlib only: the app Makefile runs this file)
REPO = Path(__file__).resolve().parent.parent
BUILD = Path(os.environ.get("NS2_BUILD_DIR", REPO / "build"))
COMMIT = "2a18fc29"
TARBALL_NAME = f"crazyflie-firmware-{COMMIT}.tar.xz"


def _shared() -> Path:
    """``$NS2_SHARED_DIR``, else the nearest ``shared/`` folder beside the checkout or one of
    its parents (a git worktree sits deeper than a clone)."""
    env = os.environ.get("NS2_SHARED_DIR")
    if env:
        return Path(env)
    for up in REPO.parents:
        if (up / "shared" / "crazyflie-firmware").is_dir():
            return up / "shared"
    return REPO.parent / "shared"


SHARED = _shared()


class FirmwareMissing(Ns2Error, RuntimeError):
    """The crazyflie-firmware tree or its tarball is not where it should be."""


def tarball() -> Path:
    return SHARED / "crazyflie-firmware" / TARBALL_NAME


def have_firmware() -> bool:
    base = os.environ.get("CRAZYFLIE_BASE")
    return Path(base).is_dir() if base else tarball().is_file() or (BUILD / "crazyflie-firmware").is_dir()


def firmware_dir() -> Path:
    """The crazyflie-firmware tree: ``$CRAZYFLIE_BASE`` or the unpacked shared tarball."""
    base = os.environ.get("CRAZYFLIE_BASE")
    if base:
        p = Path(base).resolve()
        if not (p / "src" / "modules").is_dir():
            raise FirmwareMissing(f"CRAZYFLIE_BASE={base}: not a crazyflie-firmware tree (no src/modules)")
        return p
    dest = BUILD / "crazyflie-firmware"
    if (dest / ".ns2-unpacked").is_file():
        return dest
    tb = tarball()
    if not tb.is_file():
        raise FirmwareMissing(f"{tb}: crazyflie-firmware tarball missing (set CRAZYFLIE_BASE or put ../shared beside the checkout)")
    BUILD.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".cf-unpack-", dir=BUILD))
    try:
        subprocess.run(["tar", "-xJf", str(tb), "-C", str(tmp)], check=True)
        (root,) = [p for p in tmp.iterdir() if p.is_dir()]
        (root / ".ns2-unpacked").write_text(COMMIT + "\n")
        if dest.exists():
            shutil.rmtree(dest)
        root.rename(dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def extract_function(path: Path, name: str) -> str:
    """The C source text of the function ``name`` (its definition) in ``path``."""
    text = path.read_text()
    m = re.search(r"^[A-Za-z_][\w \*]*\b" + re.escape(name) + r"\s*\([^;{]*\)\s*\{", text, re.M)
    if m is None:
        raise FirmwareMissing(f"{path}: no definition of {name}")
    depth, i = 0, m.end() - 1
    while True:
        depth += {"{": 1, "}": -1}.get(text[i], 0)
        i += 1
        if depth == 0:
            return text[m.start():i] + "\n"


if __name__ == "__main__":  # the app Makefile asks here where the firmware is (stdlib only)
    try:
        print(firmware_dir())
    except FirmwareMissing as e:
        raise SystemExit(str(e))
