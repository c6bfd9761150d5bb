"""The `ns2` command line end to end: gen-data -> train -> export, its conventions
(help on every option, --json, progress on a terminal, the export folder's config)
and its errors (one line, exit 1, no traceback)."""
import fcntl
import json
import os
import pty
import struct
import subprocess
import sys
import termios
import threading

import click
import pytest


def ns2(*args, **kw):
    return subprocess.run([sys.executable, "-m", "ns2cli", *map(str, args)], capture_output=True, text=True, **kw)


def test_gen_train_export(tmp_path):
    from ns2codegen.config import Config
    from ns2codegen.export import export_config

    data = tmp_path / "d.npz"
    r = ns2("gen-data", "--samples-per-scenario", "100", "--out", data)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"wrote {data}: 1200 samples")           # human output by default
    ck = tmp_path / "m.pt"
    r = ns2("train", "--data", data, "--out", ck, "--epochs", "2", "--layers", "3", "--hidden", "10", "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert set(report["mse_per_scenario"]) and report["validation_mse"] > 0
    assert r.stderr == ""      # no progress bar when stderr is not a terminal
    r = ns2("export", ck, "--out", tmp_path / "gen")
    assert r.returncode == 0, r.stderr
    man = json.loads((tmp_path / "gen" / "ns2_model_manifest.json").read_text())
    assert man["dims"]["phi"] == [6, 25, 40, 10] and man["dims"]["rho"] == [10, 40, 40, 1]
    # the export folder carries the config it was made with (the --layers/--hidden overrides included)
    assert man["config_file"] == "ns2_config.toml"
    cfg = export_config(tmp_path / "gen")
    assert cfg.model["layers"] == 3 and cfg.model["hidden"] == 10
    assert cfg.raw == {**Config.load().raw, "model": {**Config.load().raw["model"], "layers": 3, "hidden": 10}}
    r = ns2("train", "--data", data, "--out", ck, "--epochs", "1", "--onboard", "--width", "20", "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"wrote {ck}: validation MSE")
    r = ns2("export", ck, "--out", tmp_path / "gen", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["model_hash"] == json.loads(
        (tmp_path / "gen" / "ns2_model_manifest.json").read_text())["model_hash"]
    man = json.loads((tmp_path / "gen" / "ns2_model_manifest.json").read_text())
    assert man["dims"]["phi"] == [6, 16, 20, 20, 20] and man["dims"]["rho"] == [20, 20, 20, 20, 1]


def test_progress_bar_on_a_terminal_and_quiet(tmp_path):
    """On a terminal `train` draws a tqdm bar on stderr; --quiet turns it off."""
    data = tmp_path / "d.npz"
    assert ns2("gen-data", "--samples-per-scenario", "50", "--out", data).returncode == 0

    def stderr_on_tty(*extra):
        master, slave = pty.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))   # a 120-column terminal
        chunks = []

        def read():
            while True:
                try:
                    b = os.read(master, 4096)
                except OSError:
                    return
                if not b:
                    return
                chunks.append(b)

        t = threading.Thread(target=read, daemon=True)
        t.start()
        p = subprocess.run([sys.executable, "-m", "ns2cli", "train", "--data", str(data), "--out",
                            str(tmp_path / "m.pt"), "--epochs", "1", "--layers", "2", *extra],
                           stdout=subprocess.PIPE, stderr=slave, text=True)
        os.close(slave)
        t.join(5)
        os.close(master)
        assert p.returncode == 0
        return b"".join(chunks).decode(errors="replace")

    assert "sample" in stderr_on_tty() and "train" in stderr_on_tty()
    assert stderr_on_tty("--quiet") == ""


def _commands(group=None, prefix=()):
    from ns2cli import main

    group = group or main
    for name, cmd in group.commands.items():
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, prefix + (name,))
        else:
            yield prefix + (name,), cmd


def test_every_option_has_help():
    from ns2cli import main

    missing = [f"{' '.join(path)} {opt.opts[0]}" for path, cmd in _commands() for opt in cmd.params
               if isinstance(opt, click.Option) and not (opt.help or "").strip()]
    missing += [f"ns2 {opt.opts[0]}" for opt in main.params if isinstance(opt, click.Option) and not opt.help]
    assert not missing, missing
    assert all((cmd.help or "").strip() for _, cmd in _commands())
    # and --help shows it: every option with its text
    for path, cmd in _commands():
        r = ns2(*path, "--help")
        assert r.returncode == 0, r.stderr
        text = " ".join(r.stdout.split())
        for opt in cmd.params:
            if isinstance(opt, click.Option):
                assert opt.opts[-1] in text and " ".join(opt.help.split())[:30] in text, (path, opt.opts)


def _missing_input_calls(tmp_path):
    """Every command with an input file or folder that does not exist."""
    nope = tmp_path / "nope"
    return {
        ("gen-data",): ["--config", nope / "c.toml", "--out", tmp_path / "d.npz"],
        ("train",): ["--data", nope / "d.npz", "--out", tmp_path / "m.pt"],
        ("export",): [nope / "m.pt", "--out", tmp_path / "gen"],
        ("sysid",): ["--type", "small", "--static", nope / "s.csv", "--out", tmp_path / "v.toml"],
        ("logs-to-data",): [nope, "--out", tmp_path / "d.npz"],
        ("hil",): ["--qemu", "--gen", nope],
        ("sim", "collect"): ["--gen", nope, "--out", tmp_path / "d.npz"],
        ("sim", "swaps"): ["--gen", nope, "--out", tmp_path / "swaps"],
        ("sim", "rings"): ["--gen", nope, "--out", tmp_path / "rings"],
        ("sim", "calibrate"): ["--data-dir", nope, "--out", tmp_path / "cal"],
        ("sim", "adapt"): ["--gen", nope, "--out", tmp_path / "adapt"],
        ("plan",): ["--checkpoint", nope / "m.pt", "--out", tmp_path / "plan"],
        ("real", "data"): ["--shared", nope, "--unpack-dir", tmp_path / "u", "--out", tmp_path / "real"],
        ("real", "check-c"): ["--gen", nope, "--checkpoint", nope / "m.pt", "--data-dir", nope],
        ("real", "report"): ["--dir", nope, "--checkpoint", nope / "m.pt", "--unpack-dir", nope],
        ("real", "import-authors"): [nope, "--out", tmp_path / "authors.pt"],
        ("real", "authors-faz"): [nope / "authors.pt", "--data", nope, "--out", tmp_path / "faz.json"],
        ("real", "score"): ["--checkpoint", nope / "m.pt", "--data-dir", nope],
        ("real", "blind"): ["--dir", nope, "--out", tmp_path / "blind.json"],
        ("real", "memory"): ["--now", nope / "a.json", "--past", nope / "b.json", "--out", tmp_path / "m.json"],
        ("real", "adapt"): ["--dir", nope, "--gen", nope, "--out", tmp_path / "adapt.json"],
        ("results",): ["--root", nope],
        ("swarm-params",): [nope, nope / "crazyflies.yaml"],
        ("fly",): [nope, nope / "crazyflies.yaml", "--plan", nope, "--log", tmp_path / "f.jsonl"],
        ("flash",): [nope / "cf2.bin", "--uri", "radio://0/80/2M/E7E7E7E701"],
    }


def test_every_command_with_a_missing_input_says_so_in_one_line(tmp_path):
    calls = _missing_input_calls(tmp_path)
    assert set(calls) == {path for path, _ in _commands()}, "a new command needs a case here"
    calls[("plan", "problem")] = ["plan", "--problem", tmp_path / "nope" / "p.json", "--baseline", "--out",
                                  tmp_path / "plan"]
    for path, args in calls.items():
        argv = args if path == ("plan", "problem") else [*path, *args]
        r = ns2(*argv, cwd=tmp_path)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1 and lines[0].startswith("Error: "), (argv, r.stderr)
        assert "nope" in lines[0] and "Traceback" not in r.stderr, (argv, r.stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == []       # nothing written


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


def test_missing_extra_names_it(monkeypatch):
    """Without an optional dependency a command says which extra to install."""
    from click.testing import CliRunner

    from ns2cli import main

    monkeypatch.setitem(sys.modules, "scipy", None)          # import scipy -> ModuleNotFoundError
    monkeypatch.setitem(sys.modules, "scipy.optimize", None)
    for name in [m for m in sys.modules if m.startswith(("ns2plan", "ns2exp"))]:
        monkeypatch.delitem(sys.modules, name)
    r = CliRunner().invoke(main, ["plan", "--checkpoint", "m.pt", "--out", "/nonexistent/plan"])
    assert r.exit_code == 1 and "scipy is not installed" in r.output, r.output
    assert "pip install 'ns2codegen[plan]'" in r.output and not isinstance(r.exception, ImportError), r.output


if __name__ == "__main__":
    pytest.main([__file__])


def test_real_check_c_refuses_queries_without_the_models_lags(history, cfg, tmp_path):
    """ns2 real check-c of a network with wake memory on a query file made without the
    lags (a data folder of before): one line naming the query file and the field."""
    from ns2codegen.queries import random_queries
    from ns2exp.real import save_queries

    save_queries(tmp_path / "heldout_queries.npz", random_queries(cfg, 10, seed=0))
    r = ns2("real", "check-c", "--gen", history.gen_dir, "--checkpoint", history.checkpoint,
            "--data-dir", tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert f"{tmp_path / 'heldout_queries.npz'}: model.history_ms [50, 100, 200] but the queries have 0" in lines[0]
