"""Bitcraze's crazyflie-firmware, the real one, for builds and host compiles.

``firmware_dir()`` returns the tree at the pinned commit, the first of:
  1. ``CRAZYFLIE_BASE`` (env): an existing checkout;
  2. ``build/crazyflie-firmware``, unpacked or fetched before;
  3. the pinned, trimmed tarball in ``../shared/crazyflie-firmware/`` beside the
     checkout (see its README), unpacked once into ``build/crazyflie-firmware``;
  4. a git fetch of the pinned commit from bitcraze's repository (``NS2_CRAZYFLIE_GIT``
     overrides the URL) into ``build/crazyflie-firmware``, with the submodules the cf2
     build needs, when the network allows;
and when all fail, a one-line error naming the three ways to provide it.  Everything
that compiles firmware code (the app build, the host build of ``kalman_core`` and the
stock controllers, their Cortex-M4 counts) goes through here, so there is one place
that knows where the firmware is.
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
COMMIT_FULL = "2a18fc299d7b48cf094d26c38a79f33dec64b5d7"  # ../shared/crazyflie-firmware/README.md
TARBALL_NAME = f"crazyflie-firmware-{COMMIT}.tar.xz"
GIT_URL = "https://github.com/bitcraze/crazyflie-firmware.git"
SUBMODULES = ("vendor/CMSIS", "vendor/FreeRTOS", "vendor/libdw1000")  # what the cf2 build compiles
MARKER = ".ns2-unpacked"  # written last: the tree under build/ is complete


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


def git_url() -> str:
    return os.environ.get("NS2_CRAZYFLIE_GIT") or GIT_URL


_fetch_failed: dict[tuple, str] = {}  # one failed fetch per URL and folder is not retried


def have_firmware() -> bool:
    """Whether ``firmware_dir()`` gives a tree (it may fetch it)."""
    try:
        firmware_dir()
        return True
    except FirmwareMissing:
        return False


def firmware_dir() -> Path:
    """The crazyflie-firmware tree (module docstring: the four places, in order)."""
    base = os.environ.get("CRAZYFLIE_BASE")
    if base:
        p = Path(base).resolve()
        if not (p / "src" / "modules").is_dir():
            raise FirmwareMissing(f"CRAZYFLIE_BASE={base}: not a crazyflie-firmware tree (no src/modules)")
        return p
    dest = BUILD / "crazyflie-firmware"
    if (dest / MARKER).is_file():
        return dest
    if tarball().is_file():
        return _install(dest, _unpack)
    key = (git_url(), str(dest))
    if key not in _fetch_failed:
        try:
            return _install(dest, _fetch)
        except FirmwareMissing as e:
            _fetch_failed[key] = str(e)
    raise FirmwareMissing(
        f"crazyflie-firmware {COMMIT} missing: set CRAZYFLIE_BASE=<a checkout at {COMMIT}>, or put "
        f"{tarball()} (../shared beside the checkout), or let git fetch it ({_fetch_failed[key]})")


def _install(dest: Path, make) -> Path:
    """``make(tmp)`` builds the tree in a temporary folder beside ``dest``, which is
    then moved into place with its marker: an interrupted run leaves nothing half-made,
    and of concurrent installers (parallel test workers) the first complete tree stays."""
    made = not BUILD.exists()
    BUILD.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".cf-", dir=BUILD))
    try:
        root = make(tmp)
        (root / MARKER).write_text(COMMIT + "\n")
        if (dest / MARKER).is_file():       # another process installed it meanwhile: keep theirs
            return dest
        if dest.exists():
            shutil.rmtree(dest)
        try:
            root.rename(dest)
        except OSError:
            if not (dest / MARKER).is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if made and not any(BUILD.iterdir()):
            BUILD.rmdir()
    return dest


def _unpack(tmp: Path) -> Path:
    subprocess.run(["tar", "-xJf", str(tarball()), "-C", str(tmp)], check=True)
    (root,) = [p for p in tmp.iterdir() if p.is_dir()]
    return root


def _git(*args: str, cwd: Path) -> bool:
    env = {**os.environ, "GIT_TERMINAL_PROMPT": "0"}  # never wait for credentials
    return subprocess.run(["git", *args], cwd=cwd, env=env, capture_output=True, text=True).returncode == 0


def _fetch(tmp: Path) -> Path:
    """The pinned commit (shallow if the server allows fetching it by hash, else the
    whole history) and the submodules of SUBMODULES that its .gitmodules lists."""
    if shutil.which("git") is None:
        raise FirmwareMissing("git not installed")
    root = tmp / "crazyflie-firmware"
    root.mkdir()
    ok = _git("init", "-q", cwd=root) and _git("remote", "add", "origin", git_url(), cwd=root)
    got = ok and (_git("fetch", "-q", "--depth", "1", "origin", COMMIT_FULL, cwd=root)
                  or _git("fetch", "-q", "origin", cwd=root))
    if not (got and _git("-c", "advice.detachedHead=false", "checkout", "-q", COMMIT_FULL, cwd=root)):
        raise FirmwareMissing(f"git could not fetch commit {COMMIT} from {git_url()}: offline? NS2_CRAZYFLIE_GIT sets the URL")
    listed = subprocess.run(["git", "config", "-f", ".gitmodules", "--get-regexp", r"\.path$"], cwd=root,
                            capture_output=True, text=True).stdout.split()[1::2]
    subs = [m for m in SUBMODULES if m in listed]
    if subs and not (_git("submodule", "update", "-q", "--init", "--depth", "1", "--", *subs, cwd=root)
                     or _git("submodule", "update", "-q", "--init", "--", *subs, cwd=root)):
        raise FirmwareMissing(f"git could not fetch the submodules {', '.join(subs)} of {git_url()}")
    return root


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
