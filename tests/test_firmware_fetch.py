"""Where the crazyflie-firmware comes from (ns2host.crazyflie.firmware_dir): an existing
checkout (CRAZYFLIE_BASE), the ../shared tarball, or a git fetch of the pinned commit with
the submodules the cf2 build needs; when all fail, one line naming the three ways.  The
fetch is tested against local git repositories standing in for bitcraze's (no internet
here): a firmware repository with a commit after the pinned one and two submodules, of
which the build needs one."""
import os
import subprocess
import sys

import pytest

from ns2host import crazyflie

GIT_ENV = {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t",
           # git refuses file:// submodules unless told (CVE-2022-39253); a local test only
           "GIT_CONFIG_COUNT": "1", "GIT_CONFIG_KEY_0": "protocol.file.allow", "GIT_CONFIG_VALUE_0": "always"}


def git(*args, cwd):
    r = subprocess.run(["git", *map(str, args)], cwd=cwd, capture_output=True, text=True,
                       env={**os.environ, **GIT_ENV})
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def commit_all(repo, msg):
    git("add", "-A", cwd=repo)
    git("commit", "-q", "-m", msg, cwd=repo)
    return git("rev-parse", "HEAD", cwd=repo)


@pytest.fixture
def remote(tmp_path):
    """(url, pinned commit): a firmware repository whose pinned commit has
    src/modules/stabilizer.c = "pinned", a needed submodule (vendor/FreeRTOS) and one the
    build does not need (vendor/unity); the branch has moved on after it."""
    sub = tmp_path / "kernel"
    sub.mkdir()
    git("init", "-q", cwd=sub)
    (sub / "tasks.c").write_text("kernel\n")
    commit_all(sub, "kernel")
    fw = tmp_path / "crazyflie-firmware"
    (fw / "src" / "modules").mkdir(parents=True)
    git("init", "-q", cwd=fw)
    (fw / "src" / "modules" / "stabilizer.c").write_text("pinned\n")
    git("submodule", "add", "-q", sub, "vendor/FreeRTOS", cwd=fw)
    git("submodule", "add", "-q", sub, "vendor/unity", cwd=fw)
    pinned = commit_all(fw, "pinned")
    (fw / "src" / "modules" / "stabilizer.c").write_text("later\n")
    commit_all(fw, "later")
    return str(fw), pinned


@pytest.fixture
def nowhere(tmp_path, monkeypatch):
    """No CRAZYFLIE_BASE, no ../shared, an empty build folder, the git env of the test."""
    monkeypatch.delenv("CRAZYFLIE_BASE", raising=False)
    monkeypatch.setattr(crazyflie, "SHARED", tmp_path / "no-shared")
    monkeypatch.setattr(crazyflie, "BUILD", tmp_path / "build")
    monkeypatch.setattr(crazyflie, "_fetch_failed", {})
    for k, v in GIT_ENV.items():
        monkeypatch.setenv(k, v)
    return tmp_path / "build"


def test_fetches_the_pinned_commit_with_the_needed_submodules(remote, nowhere, monkeypatch, tmp_path):
    url, pinned = remote
    monkeypatch.setenv("NS2_CRAZYFLIE_GIT", url)
    monkeypatch.setattr(crazyflie, "COMMIT_FULL", pinned)
    assert crazyflie.have_firmware()
    fw = crazyflie.firmware_dir()
    assert fw == nowhere / "crazyflie-firmware" and (fw / crazyflie.MARKER).is_file()
    assert git("rev-parse", "HEAD", cwd=fw) == pinned
    assert (fw / "src/modules/stabilizer.c").read_text() == "pinned\n"  # the pin, not the branch tip
    assert (fw / "vendor/FreeRTOS/tasks.c").read_text() == "kernel\n"   # a submodule the build needs
    assert not any((fw / "vendor/unity").iterdir())                     # one it does not: not fetched
    assert sorted(p.name for p in nowhere.iterdir()) == ["crazyflie-firmware"]  # no temporary left
    os.rename(url, tmp_path / "gone")  # fetched once: later calls need no network
    assert crazyflie.firmware_dir() == fw


def test_crazyflie_base_comes_first_and_is_checked(nowhere, monkeypatch, tmp_path):
    tree = tmp_path / "my-firmware"
    (tree / "src" / "modules").mkdir(parents=True)
    monkeypatch.setenv("CRAZYFLIE_BASE", str(tree))
    monkeypatch.setenv("NS2_CRAZYFLIE_GIT", str(tmp_path / "none"))
    assert crazyflie.firmware_dir() == tree
    monkeypatch.setenv("CRAZYFLIE_BASE", str(tmp_path))
    with pytest.raises(crazyflie.FirmwareMissing, match="CRAZYFLIE_BASE=.*no src/modules"):
        crazyflie.firmware_dir()
    assert not nowhere.exists()


def test_when_all_fail_one_line_names_the_three_ways(nowhere, tmp_path, monkeypatch):
    monkeypatch.setenv("NS2_CRAZYFLIE_GIT", str(tmp_path / "no-such-repo"))
    assert not crazyflie.have_firmware()
    with pytest.raises(crazyflie.FirmwareMissing) as e:
        crazyflie.firmware_dir()
    msg = str(e.value)
    assert "CRAZYFLIE_BASE=" in msg and str(crazyflie.tarball()) in msg and "git" in msg and "\n" not in msg
    assert not nowhere.exists()  # nothing written, not even the build folder
    # the app Makefile's question, from the command line: one line, exit status 1
    env = {**os.environ, "NS2_SHARED_DIR": str(tmp_path / "no-shared"), "NS2_BUILD_DIR": str(nowhere)}
    r = subprocess.run([sys.executable, "-m", "ns2host.crazyflie"], capture_output=True, text=True, env=env)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1 and "CRAZYFLIE_BASE" in r.stderr
