"""The CI rule of tests/conftest.py: a test that needs a missing tool (here the
crazyflie-firmware: no CRAZYFLIE_BASE, no tarball, a git remote that does not answer) is
skipped locally and fails with CI=true."""
import os
import subprocess
import sys

from ns2host.cbuild import REPO


def _no_firmware(tmp_path) -> dict:
    env = dict(os.environ, NS2_SHARED_DIR=str(tmp_path / "no-shared"), NS2_BUILD_DIR=str(tmp_path / "build"),
               NS2_CRAZYFLIE_GIT=str(tmp_path / "no-remote"))  # offline, even where the network is not
    env.pop("CRAZYFLIE_BASE", None)
    return env


def _run(tmp_path, ci: bool):
    env = _no_firmware(tmp_path)
    env["CI"] = "true" if ci else "false"
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-rs",
                           "tests/test_app.py::test_final_config_has_the_oot_controller_and_no_battery_compensation"],
                          capture_output=True, text=True, cwd=REPO, env=env)


def test_missing_firmware_skips_locally_and_fails_on_ci(tmp_path):
    local, ci = _run(tmp_path, False), _run(tmp_path, True)
    assert local.returncode == 0 and "1 skipped" in local.stdout and "crazyflie-firmware missing" in local.stdout
    assert ci.returncode != 0 and "CI=true: crazyflie-firmware missing" in ci.stdout


def test_app_build_without_firmware_names_what_is_missing(tmp_path):
    env = _no_firmware(tmp_path)
    r = subprocess.run(["make", "-C", str(REPO / "firmware/app"), f"PYTHON={sys.executable}"], capture_output=True,
                       text=True, cwd=tmp_path, env=env)
    assert r.returncode != 0
    assert "crazyflie-firmware 2a18fc29 missing: set CRAZYFLIE_BASE=" in r.stderr
    assert "crazyflie-firmware-2a18fc29.tar.xz" in r.stderr and "let git fetch it" in r.stderr
    assert "no crazyflie-firmware" in r.stderr and not (tmp_path / "build").exists()
