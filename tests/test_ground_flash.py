"""`ns2 flash`: one robot after the other through cflib's bootloader, progress, and the
failed robots named with the reason; the image checked first."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

import cfrobot  # the tests' cflib link driver
from ns2cli import main
from ns2ground import flash

SWARM = """\
robots:
  cf1: {enabled: true, uri: radio://0/80/2M/E7E7E7E701, initial_position: [0, 0, 0], type: cf21}
  cf2: {enabled: false, uri: radio://0/80/2M/E7E7E7E702, initial_position: [0, 1, 0], type: cf21}
  cf3: {enabled: true, uri: radio://0/80/2M/E7E7E7E703, initial_position: [1, 0, 0], type: cf21}
  cf4: {enabled: true, uri: radio://0/80/2M/E7E7E7E704, initial_position: [1, 1, 0], type: cf21}
"""


class Bootloader:
    """Stands for cflib's Bootloader (no radio here); records what it was asked."""
    calls: list = []

    def __init__(self, uri):
        self.uri = uri

    def flash_full(self, cf, filename, warm, targets, progress_cb=None):
        Bootloader.calls.append((self.uri, filename, warm, targets))
        if self.uri.endswith("03"):
            raise Exception("Could not connect to bootloader")
        for pct in (0, 50, 100) if progress_cb else ():
            progress_cb("Writing", pct)

    def close(self):
        Bootloader.calls.append((self.uri, "closed"))


@pytest.fixture
def files(tmp_path):
    (tmp_path / "crazyflies.yaml").write_text(SWARM)
    (tmp_path / "cf2.bin").write_bytes(bytes(300_000))
    return tmp_path


def test_flash_every_enabled_robot_in_turn_and_name_the_failures(files, monkeypatch):
    monkeypatch.setattr(flash, "_bootloader", Bootloader)
    Bootloader.calls = []
    r = CliRunner().invoke(main, ["flash", str(files / "cf2.bin"), "--swarm", str(files / "crazyflies.yaml")])
    assert r.exit_code == 1
    assert r.output.strip().splitlines()[-1] == \
        "Error: 1 of 3 robots not flashed: cf3: Could not connect to bootloader"
    assert "cf1: flashed" in r.output and "cf4: flashed" in r.output and "cf2" not in r.output
    flashed = [c for c in Bootloader.calls if c[1] != "closed"]
    assert [c[0][-2:] for c in flashed] == ["01", "03", "04"]            # one after the other, cf3 did not stop cf4
    assert all(c[1] == str(files / "cf2.bin") and c[2] is True for c in flashed)
    from cflib.bootloader import Target
    assert all(c[3] == [Target("cf2", "stm32", "fw", [], [])] for c in flashed)   # the STM32 firmware only
    assert len([c for c in Bootloader.calls if c[1] == "closed"]) == 3


def test_progress_is_per_robot(files):
    seen = []
    res = flash.flash(files / "cf2.bin", {"cf1": "radio://0/80/2M/E7E7E7E701", "cf4": "radio://0/80/2M/E7E7E7E704"},
                      lambda *a: seen.append(a), bootloader=Bootloader)
    assert res == {"cf1": None, "cf4": None}
    assert seen == [(n, "Writing", p) for n in ("cf1", "cf4") for p in (0, 50, 100)]


def test_flash_one_robot_json(files, monkeypatch):
    monkeypatch.setattr(flash, "_bootloader", Bootloader)
    r = CliRunner().invoke(main, ["flash", str(files / "cf2.bin"), "--uri", "radio://0/80/2M/E7E7E7E701", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["robots"] == {"radio://0/80/2M/E7E7E7E701": None}


def test_a_robot_that_does_not_answer_fails_through_cflib(files):
    """cflib's own Bootloader, with no robot behind the link: named, with cflib's reason."""
    cfrobot.install({})
    res = flash.flash(files / "cf2.bin", {"cf9": "radio://0/80/2M/E7E7E7E709"})
    assert res == {"cf9": "no radio link to radio://0/80/2M/E7E7E7E709 (Crazyradio plugged in? robot on? "
                          "address right?)"}


@pytest.mark.parametrize("args, message", [
    (["missing.bin", "--uri", "radio://0/80/2M/E7E7E7E701"], "missing.bin: no firmware image"),
    (["small.bin", "--uri", "radio://0/80/2M/E7E7E7E701"], "small.bin: not a cf2 firmware image"),
    (["cf2.bin", "--uri", "usb://0"], "--uri usb://0: not a radio uri"),
    (["cf2.bin"], "give --uri or --swarm"),
])
def test_bad_flash_arguments(files, monkeypatch, args, message):
    monkeypatch.chdir(files)
    (files / "small.bin").write_bytes(b"\0" * 100)
    monkeypatch.setattr(flash, "_bootloader", Bootloader)
    Bootloader.calls = []
    r = CliRunner().invoke(main, ["flash", *args])
    assert r.exit_code != 0 and message in r.output, r.output
    assert not Bootloader.calls


def test_make_flash_runs_ns2_flash(tmp_path):
    import subprocess

    repo = Path(__file__).resolve().parent.parent
    r = subprocess.run(["make", "-n", "-C", str(repo), "flash", "PYTHON=python", "SWARM=crazyflies.yaml"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "python -m ns2cli flash build/app/cf2.bin --swarm crazyflies.yaml" in r.stdout


def test_flash_through_cflibs_bootloader_packets(files, monkeypatch):
    """cflib's own Bootloader and Cloader, their packets through the tests' link driver to
    robots that answer as the nRF51 and the STM32 bootloader do (tests/cfrobot.py): each
    robot warm-booted into its bootloader, the image written into its flash from the
    firmware's first page, reset to the firmware; a robot whose flash write fails is
    named with cflib's reason, and the next one is flashed."""
    import time
    import types

    import cflib.bootloader.cloader as cloader
    import numpy as np

    # the waits for a real robot to reboot (0.5 s, 1 + 5 s): no robot reboots here
    monkeypatch.setattr(cloader, "time", types.SimpleNamespace(time=time.time, sleep=lambda s: None))
    image = np.random.default_rng(0).bytes(70_000)
    (files / "cf2.bin").write_bytes(image)
    robots = {n: cfrobot.Robot(None, n) for n in ("cf1", "cf3", "cf4")}
    robots["cf3"].flash_error = 5
    cfrobot.install({f"radio://0/80/2M/E7E7E7E70{n[-1]}": rb for n, rb in robots.items()})
    r = CliRunner().invoke(main, ["flash", str(files / "cf2.bin"), "--swarm", str(files / "crazyflies.yaml"),
                                  "--json"])
    assert r.exit_code == 1, r.output
    assert json.loads(r.stdout)["robots"] == {
        "cf1": None, "cf3": "Error during flash operation (code 5)", "cf4": None}
    start = cfrobot.BL_INFO[cfrobot.STM32][0] * cfrobot.BL_INFO[cfrobot.STM32][3]
    for name, rb in robots.items():
        assert rb.boots == ["bootloader", "firmware"] if name != "cf3" else rb.boots == ["bootloader"]
        assert not rb.in_bootloader or name == "cf3"
        written = bytes(rb.flash[start:start + len(image)])
        assert (written == image) == (name != "cf3")
        end = start + -(-len(image) // 1024) * 1024    # written page by page
        assert set(rb.flash[:start]) == {0xFF} and set(rb.flash[end:]) == {0xFF}   # nothing outside the image
