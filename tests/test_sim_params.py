"""The simulator's parameter files (host/sim/params/*.toml, host/sim/paramfile.py) and the
paper's (paper/params/*.toml, paper/gains.py): the
shipped files are the numbers the code held before they became data, to the bit; a
calibrate run's files load back as what it fitted; a bad file is one line naming the
file and the field."""
from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import pytest

from ns2host.sim.paramfile import ParamsError, load_params
from ns2host.sim.roughness import ROUGH_FILE, ROUGH_PARAMS, Roughness, dump_roughness, load_roughness
from ns2paper.gains import (AUTHORS_GAINS, AUTHORS_GAINS_FILE, AUTHORS_ROBOT_TYPE, AUTHORS_TYPE, READ_LAW,
                            READ_LAW_FILE, dump_read_law, load_authors_gains, load_read_law)

# The dataclass defaults of host/sim/roughness.py and the constants of host/sim/vehicle.py
# at 0281169, the last commit that kept them in the code (make calibrate at a8cacab), less
# the wakes' moments (moment_gain 4.715, moment_turbulence_ratio 0.0: off, deleted after 96ed0bd).
FORMER_ROUGHNESS = {
    "vibration_acc_g": {"small": 0.0613, "large": 0.0882}, "vibration_gyro_dps": {"small": 2.28, "large": 6.594},
    "turbulence_ratio": 0.025, "turbulence_tau_s": 0.002, "thrust_sd": 0.0158, "battery_start_V": 3.552,
    "battery_sag_V_per_min": 0.1063, "wake_sigma0_scale": 0.848, "wake_spread_scale": 0.474,
    "lateral_k_xy": {"small": -0.053, "large": -0.176}, "hover_motor_noise": {"small": 0.0274, "large": 0.04613},
    "enabled": ("vibration", "turbulence", "thrust", "battery", "wake", "lateral")}
FORMER_READ_LAW = {"small": {"kp": 8.9309, "kd": 2.8506, "ki": 0.4604, "k_fa": 0.3729, "mass_kg": 0.033207},
                   "large": {"kp": 7.9323, "kd": 2.5174, "ki": 0.5582, "k_fa": 0.8295, "mass_kg": 0.06533}}
FORMER_AUTHORS_GAINS = {
    "CF21SingleMarker": {"mass_kg": 0.034, "kp": [20.0, 20.0, 10.0], "kd": [10.0, 10.0, 5.0],
                         "ki": [3.0, 3.0, 3.0], "i_max": 2.0,
                         "att": {"Lq": [20.0, 20.0, 8.0], "Kw": [0.002, 0.002, 0.001], "Gw": [0.002, 0.002, 0.004],
                                 "Kwd": [8e-5, 8e-5, 2e-5], "int_w_max": 2.0}},
    "parrotFrameCF21SingleMarker": {"mass_kg": 0.067, "kp": [20.0, 20.0, 10.0], "kd": [10.0, 10.0, 5.0],
                                    "ki": [3.0, 3.0, 3.0], "i_max": 2.0,
                                    "att": {"Lq": [20.0, 20.0, 8.0], "Kw": [0.009, 0.009, 0.004],
                                            "Gw": [0.005, 0.005, 0.005], "Kwd": [2e-4, 2e-4, 0.0], "int_w_max": 2.0}},
    "parrotFrameSingleMarker": {"mass_kg": 0.067, "kp": [40.0, 40.0, 30.0], "kd": [20.0, 20.0, 15.0],
                                "ki": [3.0, 3.0, 3.0], "i_max": 2.0,
                                "att": {"Lq": [12.0, 12.0, 8.0], "Kw": [0.006, 0.006, 0.004],
                                        "Gw": [0.005, 0.005, 0.005], "Kwd": [1e-4, 1e-4, 0.0], "int_w_max": 2.0}},
}


def _exact(x) -> str:
    """JSON text without sorting: equal only with the same keys in the same order, the
    same types (2.0 is not 2) and the same doubles (repr)."""
    return json.dumps(x)


def test_the_shipped_files_are_the_former_defaults_to_the_bit():
    assert _exact(asdict(Roughness())) == _exact({**FORMER_ROUGHNESS, "enabled": list(FORMER_ROUGHNESS["enabled"])})
    assert Roughness() == Roughness(**FORMER_ROUGHNESS)
    assert load_roughness(ROUGH_FILE) == Roughness()
    assert _exact(READ_LAW) == _exact(FORMER_READ_LAW)
    assert _exact(AUTHORS_GAINS) == _exact(FORMER_AUTHORS_GAINS)
    assert AUTHORS_TYPE == {"small": "CF21SingleMarker", "large": "parrotFrameCF21SingleMarker"}
    assert AUTHORS_ROBOT_TYPE == {"cf100": "parrotFrameSingleMarker"}
    # each file says what made it
    for path in (ROUGH_FILE, READ_LAW_FILE, AUTHORS_GAINS_FILE):
        _, origin = load_params(path, _schema(path))
        assert origin["commit"] and origin["command"], path
    # a fresh copy of a table per Roughness: one instance's edit is not another's default
    r = Roughness()
    r.lateral_k_xy["small"] = 9.0
    assert Roughness().lateral_k_xy["small"] == -0.053


def _schema(path: Path) -> dict:
    from ns2paper.gains import AUTHORS_PARAMS, READ_LAW_PARAMS
    return {ROUGH_FILE: ROUGH_PARAMS, READ_LAW_FILE: READ_LAW_PARAMS, AUTHORS_GAINS_FILE: AUTHORS_PARAMS}[path]


def test_a_calibrate_run_writes_parameter_files_that_load_back(tmp_path, monkeypatch):
    """ns2exp.calibrate.calibrate with a fit (the fit and the replays stubbed: only the
    writing is under test) writes rough.toml and read_law.toml beside its report; they
    load back as exactly what it fitted, with the command and the commit; a run without
    a fit (--no-refit) leaves no parameter file of an earlier run beside its report."""
    import ns2exp.calibrate as cal

    fitted = replace(Roughness(), turbulence_ratio=0.1 + 0.2, lateral_k_xy={"small": -1e-17, "large": 0.3},
                     wake_spread_scale=1 / 3, hover_motor_noise={"small": 0.02, "large": 0.05})
    law = {ty: {**zl, "kp": zl["kp"] * 1.1, "k_fa": 2 / 3} for ty, zl in READ_LAW.items()}
    monkeypatch.setattr(cal, "fit", lambda *a, **k: (fitted, {"real": {}}))
    monkeypatch.setattr(cal, "fit_read_law", lambda *a, **k: (law, []))
    monkeypatch.setattr(cal, "compare", lambda *a, **k: {})
    monkeypatch.setattr(cal, "paper_l2s", lambda *a, **k: {})
    monkeypatch.setattr(cal, "markdown", lambda res: "# report\n")
    monkeypatch.setattr(cal, "source_commit", lambda repo=None: "abc1234")
    out = tmp_path / "cal"
    cal.calibrate(None, None, [], {}, {}, out, command="ns2 sim calibrate --out cal")
    assert sorted(p.name for p in out.iterdir()) == ["calibration.json", "calibration.md", "read_law.toml",
                                                      "rough.toml"]
    assert load_roughness(out / "rough.toml") == fitted
    assert _exact(load_read_law(out / "read_law.toml")) == _exact(law)
    for shipped in (ROUGH_FILE, READ_LAW_FILE):
        _, origin = load_params(out / shipped.name, _schema(shipped))
        assert origin["commit"] == "abc1234" and origin["command"] == "ns2 sim calibrate --out cal"
        assert "calibration.md" in origin["report"]
    assert json.loads((out / "calibration.json").read_text())["roughness"]["wake_spread_scale"] == 1 / 3
    cal.calibrate(None, None, [], {}, {}, out, rough=Roughness())
    assert sorted(p.name for p in out.iterdir()) == ["calibration.json", "calibration.md"]


def test_the_shipped_files_are_what_the_writers_write():
    """The files in host/sim/params/ and paper/params/ have the writers' form: a calibrate run's file can
    replace them line for line (units and sources included)."""
    _, origin = load_params(ROUGH_FILE, ROUGH_PARAMS)
    assert dump_roughness(Roughness(), origin).splitlines()[2:] == ROUGH_FILE.read_text().splitlines()[2:]
    _, origin = load_params(READ_LAW_FILE, _schema(READ_LAW_FILE))
    assert dump_read_law(READ_LAW, origin).splitlines()[2:] == READ_LAW_FILE.read_text().splitlines()[2:]


def _edited(tmp_path, src: Path, old: str, new: str) -> Path:
    text = src.read_text()
    assert old in text, old
    out = tmp_path / src.name
    out.write_text(text.replace(old, new, 1))
    return out


BAD = [  # (file, text replaced, replacement, what the error must name)
    (ROUGH_FILE, 'value = 0.025\nunit = "1 (force sd per unit |f_a,z|)"', 'value = 0.025\nunit = "%"',
     "turbulence_ratio.unit"),
    (ROUGH_FILE, "value = 0.025\n", 'value = "0.025"\n', "turbulence_ratio.value"),
    (ROUGH_FILE, "value = 0.848\n", "value = -0.848\n", "wake_sigma0_scale.value"),
    # a file of before the wakes' moments were deleted (96ed0bd) is refused, not read in part
    (ROUGH_FILE, "[hover_motor_noise]", '[moment_gain]\nvalue = 4.715\nunit = "1"\nsource = "fit_moment"\n\n'
     "[hover_motor_noise]", "moment_gain"),
    (ROUGH_FILE, "value = {small = 0.0613, large = 0.0882}", "value = {small = 0.0613, large = nan}",
     "vibration_acc_g.value.large"),
    (ROUGH_FILE, "[thrust_sd]\nvalue = 0.0158\n", "[thrust_sd]\n", "thrust_sd.value"),
    (ROUGH_FILE, "[thrust_sd]", "[thrust_scatter]", "thrust_scatter"),
    (ROUGH_FILE, 'commit = "a8cacab"\n', "", "origin.commit"),
    (ROUGH_FILE, "[turbulence_ratio]\nvalue", "[turbulence_ratio]\nvalu = 1\nvalue", "turbulence_ratio.valu"),
    (ROUGH_FILE, "value = 0.025\n", "value = 0.025\nvalue = 0.03\n", "not valid TOML"),
    (READ_LAW_FILE, "value = {small = 0.3729, large = 0.8295}", "value = {small = 0.3729}", "k_fa.value"),
    (AUTHORS_GAINS_FILE, "[20.0, 20.0, 8.0], parrotFrameCF21", "[20.0, 20.0], parrotFrameCF21",
     "Lq.value.CF21SingleMarker"),
    (AUTHORS_GAINS_FILE, '{cf100 = "parrotFrameSingleMarker"}', '{cf100 = "parrotFrame"}',
     "type_of_robot.value.cf100"),
]


@pytest.mark.parametrize("src, old, new, field", BAD, ids=[b[3] for b in BAD])
def test_a_bad_parameter_file_is_one_line_naming_the_file_and_field(tmp_path, src, old, new, field):
    path = _edited(tmp_path, src, old, new)
    load = {ROUGH_FILE: load_roughness, READ_LAW_FILE: load_read_law, AUTHORS_GAINS_FILE: load_authors_gains}[src]
    with pytest.raises(ParamsError) as e:
        load(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg and field in msg, msg
    with pytest.raises(ParamsError, match=f"parameter file not found: {tmp_path / 'none.toml'}"):
        load(tmp_path / "none.toml")


def test_a_bad_parameter_file_stops_the_command_with_one_line(tmp_path):
    """Through the `ns2` command: the shipped file broken in a copy of the package's
    params folder (the simulator's modules read PARAMS_DIR at import) is one line on
    stderr naming the file and the field, exit status 1."""
    import subprocess
    import sys

    bad = _edited(tmp_path, ROUGH_FILE, "value = 0.025\n", 'value = "a lot"\n')
    for f in (AUTHORS_GAINS_FILE, READ_LAW_FILE):
        (tmp_path / f.name).write_text(f.read_text())
    code = ("import sys; from pathlib import Path; import ns2host.sim.paramfile as p; "
            f"p.PARAMS_DIR = Path({str(tmp_path)!r}); from ns2cli import main; "
            "sys.argv = ['ns2', 'sim', 'calibrate', '--no-refit', '--data-dir', sys.argv[1]]; main()")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "nodata")], capture_output=True, text=True)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(bad) in lines[0] and "turbulence_ratio.value" in lines[0], r.stderr
