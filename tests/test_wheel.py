"""The installable distribution: the built wheel carries the templates and the default
config, declares only the core's dependencies (the heavy parts are extras), and, in a
fresh virtual environment, `ns2 gen-data`, `ns2 train` and `ns2 export` work from an
empty folder outside the checkout.  The host side says clearly that it needs a
checkout.  (The venv borrows torch and numpy from the running interpreter's
site-packages, whatever it is: a virtualenv, a conda env or a system install, so the test
downloads nothing heavy; it checks that the package itself comes from the wheel.)"""
from __future__ import annotations

import json
import os
import re
import site
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CORE = {"torch", "numpy", "jinja2", "click", "tqdm"}


def _run(cmd, cwd, **kw):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, env=env, **kw)


def borrowed_site_dirs() -> list[str]:
    """The running interpreter's site directories (``venv --system-site-packages`` would
    give the base interpreter's, without the packages of an outer virtualenv)."""
    dirs = site.getsitepackages() + ([site.getusersitepackages()] if site.ENABLE_USER_SITE else [])
    return [d for d in dict.fromkeys(dirs) if Path(d).is_dir()]


def test_wheel_installs_and_runs_the_core_pipeline_outside_the_checkout(tmp_path):
    dist = tmp_path / "dist"
    r = _run([sys.executable, "-m", "pip", "wheel", REPO, "--no-deps", "-q", "-w", dist], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (whl,) = dist.glob("ns2codegen-*.whl")
    with zipfile.ZipFile(whl) as z:
        names = set(z.namelist())
        meta = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    templates = {p.name for p in (REPO / "templates").glob("*.j2")}  # the checkout's top-level templates/
    assert len(templates) == 5
    assert {f"ns2codegen/templates/{t}" for t in templates} <= names and "ns2codegen/default.toml" in names
    params = {*(f"ns2host/sim/params/{p.name}" for p in (REPO / "host" / "sim" / "params").glob("*.toml")),
              *(f"ns2paper/params/{p.name}" for p in (REPO / "paper" / "params").glob("*.toml"))}
    assert len(params) == 3 and params <= names    # the simulator's parameter files and the paper's
    requires = re.findall(r"^Requires-Dist: ([A-Za-z0-9_.-]+)(.*)$", meta, re.M)
    core = {name.lower() for name, rest in requires if "extra ==" not in rest}
    assert core == CORE, core                                   # nothing heavy without an extra
    extras = set(re.findall(r"^Provides-Extra: (\S+)$", meta, re.M))
    assert {"sim", "plan", "target", "sysid", "test", "bench", "all"} <= extras

    venv = tmp_path / "venv"
    assert _run([sys.executable, "-m", "venv", venv], cwd=tmp_path).returncode == 0
    py, ns2 = venv / "bin" / "python", venv / "bin" / "ns2"
    r = _run([py, "-c", "import site; print(site.getsitepackages()[0])"], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    # a .pth line only extends sys.path: the outer site's own .pth files (an editable
    # install of this checkout among them) are not run, so ns2codegen must come from the wheel
    (Path(r.stdout.strip()) / "borrowed-site.pth").write_text("".join(d + "\n" for d in borrowed_site_dirs()))
    r = _run([py, "-m", "pip", "install", "--no-deps", "--no-index", "--ignore-installed", "-q", whl], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    work = tmp_path / "work"                 # an empty folder outside the checkout
    work.mkdir()
    r = _run([py, "-c", "import ns2codegen, ns2cli; print(ns2codegen.__file__); print(ns2cli.__file__)"], cwd=work)
    assert r.returncode == 0, r.stderr
    for f in r.stdout.split():
        assert Path(f).resolve().is_relative_to(venv.resolve()), f    # the wheel's, not the checkout's

    r = _run([ns2, "gen-data", "--samples-per-scenario", "50", "--out", "d.npz"], cwd=work)
    assert r.returncode == 0, r.stderr
    r = _run([ns2, "train", "--data", "d.npz", "--out", "m.pt", "--epochs", "1", "--layers", "2", "--hidden", "4",
              "--json"], cwd=work)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["validation_mse"] > 0
    r = _run([ns2, "export", "m.pt", "--out", "gen"], cwd=work)
    assert r.returncode == 0, r.stderr
    gen = work / "gen"
    assert {"ns2_model_config.h", "ns2_model_float.h", "ns2_model_fixed.h", "ns2_vehicles.h",
            "ns2_model_manifest.json", "ns2_config.toml"} <= {p.name for p in gen.iterdir()}
    assert "NS2_HIDDEN 4" in " ".join((gen / "ns2_model_config.h").read_text().split())
    # the host side compiles the checkout's firmware C: installed alone it says so in one line
    r = _run([ns2, "sim", "collect", "--gen", "gen", "--out", "s.npz"], cwd=work)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "source checkout" in lines[0], r.stderr
    assert sorted(p.name for p in work.iterdir()) == ["d.npz", "gen", "m.pt"]
