"""The `ns2` command line end to end: gen-data -> train -> export, and its errors."""
import json
import subprocess
import sys


def ns2(*args):
    return subprocess.run([sys.executable, "-m", "ns2cli", *map(str, args)],
                          capture_output=True, text=True)


def test_gen_train_export(tmp_path):
    data = tmp_path / "d.npz"
    r = ns2("gen-data", "--samples-per-scenario", "100", "--out", data)
    assert r.returncode == 0, r.stderr
    ck = tmp_path / "m.pt"
    r = ns2("train", "--data", data, "--out", ck, "--epochs", "2", "--layers", "3", "--hidden", "10")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert set(report["mse_per_scenario"]) and report["validation_mse"] > 0
    assert "sample" in r.stderr  # progress bar
    r = ns2("export", ck, "--out", tmp_path / "gen")
    assert r.returncode == 0, r.stderr
    man = json.loads((tmp_path / "gen" / "ns2_model_manifest.json").read_text())
    assert man["dims"]["phi"] == [6, 25, 40, 10] and man["dims"]["rho"] == [10, 40, 40, 1]
    r = ns2("train", "--data", data, "--out", ck, "--epochs", "1", "--onboard", "--width", "20", "--quiet")
    assert r.returncode == 0, r.stderr
    r = ns2("export", ck, "--out", tmp_path / "gen")
    assert r.returncode == 0, r.stderr
    man = json.loads((tmp_path / "gen" / "ns2_model_manifest.json").read_text())
    assert man["dims"]["phi"] == [6, 16, 20, 20, 20] and man["dims"]["rho"] == [20, 20, 20, 20, 1]


def test_cli_errors(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"\x00" * 100)
    r = ns2("train", "--data", bad, "--out", tmp_path / "m.pt")
    assert r.returncode == 1 and "cannot read data set" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "m.pt").exists()
    cfg = tmp_path / "c.toml"
    cfg.write_text("[model\n")
    r = ns2("gen-data", "--config", cfg, "--out", tmp_path / "d.npz")
    assert r.returncode == 1 and "not valid TOML" in r.stderr
    r = ns2("gen-data", "--out", tmp_path / "missing" / "d.npz")
    assert r.returncode == 1 and "does not exist" in r.stderr
