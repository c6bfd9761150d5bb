"""Hostile input files to every loader and every `ns2` command (issue 17: D4, D6, D7,
D8 and the property that any bad input gives ONE line naming the file and the field,
a non-zero exit, and leaves what was there before intact).

Property tests use hypothesis with derandomize=True (a fixed seed: they cannot
flake) and a bounded number of examples; each mutates one field of a valid file
into a hostile value and runs the command in-process."""
import copy
import json
import math
import shutil
import struct
import subprocess
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from ns2cli import main
from ns2codegen.checkpoint import CheckpointError, LegacyCheckpointWarning, load_checkpoint, save_checkpoint
from ns2codegen.config import NAME_MAX, Config, ConfigError, check_name, dump_toml
from ns2codegen.export import CONFIG_FILE, export_config
from ns2codegen.logs.manifest import ManifestError, load_manifest
from ns2codegen.data.analytic import downwash_dataset
from ns2codegen.logs.align import PWM_FULL, VARIABLES
from ns2codegen.logs.usdlog import UsdLogWriter

FAST = settings(derandomize=True, max_examples=25, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# values that are never a valid number of the physical kind asked for
HOSTILE = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 3e38, -1.0, 0.0, True, False,
                           "fast", "", None, [], {}, [1.0], {"x": 1}])
SENTINEL = b"what was there before\n"


def run(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_refused(r, path, field=None, out=None):
    """Exit 1, exactly one line `Error: ...` naming the file (and the field), no
    traceback, and the output left as it was."""
    assert r.exit_code == 1, (r.exit_code, r.output, r.exception)
    assert isinstance(r.exception, SystemExit), repr(r.exception)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), r.stderr
    assert str(path) in lines[0] or Path(path).name in lines[0], lines[0]
    if field is not None:
        assert field in lines[0], (field, lines[0])
    if out is not None:
        assert out.read_bytes() == SENTINEL
        assert sorted(p.name for p in out.parent.iterdir()) == sorted(
            p.name for p in out.parent.iterdir() if not p.name.startswith("."))  # no temporary files


def _toml(raw) -> str:
    """TOML of plain data including the non-finite numbers dump_toml refuses."""
    def fix(v):
        if isinstance(v, float) and not math.isfinite(v):
            return f"__{v}__"
        if isinstance(v, list):
            return [fix(x) for x in v]
        if isinstance(v, dict):
            return {k: fix(x) for k, x in v.items() if x is not None}
        return v
    text = dump_toml(fix(raw))
    return text.replace('"__nan__"', "nan").replace('"__inf__"', "inf").replace('"__-inf__"', "-inf")


# ------------------------------------------------------------------ config files
CONFIG_FIELDS = [("robot_types", 0, "mass_g"), ("robot_types", 0, "arm_length_m"), ("robot_types", 1, "inertia_kgm2"),
                 ("robot_types", 0, "psi2"), ("robot_types", 1, "lambda"), ("robot_types", 0, "thrust_to_torque_m"),
                 ("robot_types", 1, "max_thrust_g"), ("model", "hidden"), ("model", "layers"), ("model", "gamma"),
                 ("model", "max_neighbors"), ("robot_types", 0, "diameter_m")]


def _set(raw, path, value):
    d = raw
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value


@FAST
@given(field=st.sampled_from(CONFIG_FIELDS), value=HOSTILE)
def test_config_file_property(cfg, field, value):
    """gen-data --config with one hostile field."""
    if value is None:
        value = "fast"
    raw = copy.deepcopy(cfg.raw)
    _set(raw, field, value)
    with tempfile.TemporaryDirectory() as d:
        f, out = Path(d) / "c.toml", Path(d) / "data.npz"
        f.write_text(_toml(raw))
        out.write_bytes(SENTINEL)
        r = run(["gen-data", "--config", f, "--samples-per-scenario", "1", "--out", out])
        assert_refused(r, f, field[-1], out)


def test_d4_vehicle_parameters_that_break_the_controller_are_refused(exported, tmp_path):
    """D4: arm_length_m = 0, inertia = 0 and psi2 = NaN in a checkpoint's config."""
    out = tmp_path / "gen"
    out.mkdir()
    (out / "ns2_model_config.h").write_bytes(SENTINEL)
    for key, value in (("arm_length_m", 0), ("inertia_kgm2", [0, 0, 0]), ("psi2", [math.nan] * 5)):
        obj = torch.load(exported.checkpoint, weights_only=True)
        meta = json.loads(obj["meta_json"])
        meta["config"]["robot_types"][0][key] = value
        obj["meta_json"] = json.dumps(meta)
        ck = tmp_path / f"{key}.pt"
        torch.save(obj, ck)
        r = run(["export", ck, "--out", out])
        assert_refused(r, ck, key)
        assert (out / "ns2_model_config.h").read_bytes() == SENTINEL
    vf = tmp_path / "v.toml"   # and through a vehicle file
    vf.write_text('[vehicle]\nname = "small"\narm_length_m = 0.0\n')
    r = run(["logs-to-data", tmp_path, "--vehicle", vf, "--out", tmp_path / "d.npz"])
    assert_refused(r, vf, "arm_length_m")


@FAST
@given(value=HOSTILE, key=st.sampled_from(["lambda", "mass_g", "psi1", "inertia_kgm2", "arm_length_m"]))
def test_vehicle_file_property(value, key):
    with tempfile.TemporaryDirectory() as d:
        vf, out = Path(d) / "v.toml", Path(d) / "d.npz"
        vf.write_text(_toml({"vehicle": {"name": "small", key: value}}) if value is not None else
                      "[vehicle]\nname = 'small'\n" + f"{key} = 'x'\n")
        out.write_bytes(SENTINEL)
        r = run(["train", "--data", out, "--vehicle", vf, "--out", Path(d) / "m.pt"])
        assert_refused(r, vf, key)
        assert out.read_bytes() == SENTINEL and not (Path(d) / "m.pt").exists()


# ------------------------------------------------------------------ data sets (train)
@pytest.fixture(scope="module")
def small_data(cfg, tmp_path_factory):
    p = tmp_path_factory.mktemp("data") / "d.npz"
    downwash_dataset(cfg, 40, seed=0).save(p)
    return p


def _npz_with(src: Path, dst: Path, key: str, fn) -> None:
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[key] = fn(arrays[key])
    np.savez(dst, **arrays)


def _meta(fn):
    def f(a):
        m = json.loads(str(a))
        fn(m)
        return np.array(json.dumps(m))
    return f


DATA_MUTATIONS = {
    "label_g": [lambda a: np.full_like(a, 3e38), lambda a: np.where(np.arange(a.size) == 3, np.nan, a),
                lambda a: a[:-1], lambda a: a.astype("U8")],
    "nbr_state": [lambda a: np.full_like(a, 1e30), lambda a: np.where(a == a, np.inf, a), lambda a: a[:, :5]],
    "time_s": [lambda a: np.where(np.arange(a.size) == 0, np.nan, a), lambda a: a[:0]],
    "robot_type": [lambda a: a + 7, lambda a: a.astype(float) + 0.5],
    "nbr_offsets": [lambda a: a[::-1], lambda a: a + 1],
    "meta": [_meta(lambda m: m.update(neighbor_types=["small", "giant", "env"])),
             _meta(lambda m: m.update(format="v0")), _meta(lambda m: m.update(neighbor_types=3)),
             lambda a: np.array("not json")],
}


@FAST
@given(key=st.sampled_from(sorted(DATA_MUTATIONS)), k=st.integers(0, 3))
def test_data_set_property(small_data, key, k):
    """D7: train on a data set with one hostile array (labels 3e38, states 1e30, NaN
    time, mismatched neighbour types, 0 samples ...)."""
    fn = DATA_MUTATIONS[key][k % len(DATA_MUTATIONS[key])]
    with tempfile.TemporaryDirectory() as d:
        bad, out = Path(d) / "bad.npz", Path(d) / "m.pt"
        _npz_with(small_data, bad, key, fn)
        out.write_bytes(SENTINEL)
        r = run(["train", "--data", bad, "--out", out, "--epochs", "1", "--quiet"])
        assert_refused(r, bad, key, out)


def test_d7_zero_samples_and_types(cfg, small_data, tmp_path):
    for key, fn, field in (("robot_type", lambda a: a[:0], "no samples"),
                           ("meta", _meta(lambda m: m.update(neighbor_types=["a", "b", "c"])), "neighbor_types"),
                           ("label_g", lambda a: np.full_like(a, 3e38), "label_g"),
                           ("nbr_state", lambda a: np.full_like(a, 1e30), "nbr_state"),
                           ("time_s", lambda a: np.full_like(a, np.nan), "time_s")):
        bad = tmp_path / f"{key}.npz"
        if key == "robot_type":   # a consistent 0-sample set
            with np.load(small_data) as z:
                arrays = {k: z[k] for k in z.files}
            for k in ("robot_type", "label_g", "scenario", "time_s", "nbr_type"):
                arrays[k] = arrays[k][:0]
            arrays["nbr_offsets"], arrays["nbr_state"] = arrays["nbr_offsets"][:1], arrays["nbr_state"][:0]
            np.savez(bad, **arrays)
        else:
            _npz_with(small_data, bad, key, fn)
        r = run(["train", "--data", bad, "--out", tmp_path / "m.pt", "--epochs", "1", "--quiet"])
        assert_refused(r, bad, field)
        assert not (tmp_path / "m.pt").exists()


# ------------------------------------------------------------------ checkpoints (export)
@FAST
@given(what=st.sampled_from(["weight", "config", "bytes"]), value=HOSTILE, k=st.integers(0, 10 ** 6))
def test_checkpoint_property(exported, what, value, k):
    obj = torch.load(exported.checkpoint, weights_only=True)
    with tempfile.TemporaryDirectory() as d:
        ck, out = Path(d) / "bad.pt", Path(d) / "gen"
        out.mkdir()
        (out / "ns2_model_float.h").write_bytes(SENTINEL)
        if what == "weight":
            name = sorted(obj["state_dict"])[k % len(obj["state_dict"])]
            t = obj["state_dict"][name]
            v = value if isinstance(value, float) and (not math.isfinite(value) or abs(value) > 1e30) else math.nan
            v = math.copysign(math.inf, v) if math.isfinite(v) and abs(v) > 3.4e38 else v   # float32
            t.view(-1)[k % t.numel()] = v
            torch.save(obj, ck)
        elif what == "config":
            meta = json.loads(obj["meta_json"])
            key = ["mass_g", "lambda", "arm_length_m", "psi1", "thrust_to_torque_m"][k % 5]
            meta["config"]["robot_types"][k % 2][key] = value
            obj["meta_json"] = json.dumps(meta)
            torch.save(obj, ck)
        else:
            data = bytearray(exported.checkpoint.read_bytes())
            data[k % len(data)] ^= 0xFF
            ck.write_bytes(bytes(data[: len(data) - 1 - k % 500] if k % 2 else data))   # and cut, or not
        r = run(["export", ck, "--out", out])
        if r.exit_code == 0:   # a byte no reader uses (a header's time stamp ...): the same model
            assert what == "bytes" and k % 2 == 0
            assert json.loads((out / "ns2_model_manifest.json").read_text())["model_hash"] == \
                exported.manifest["model_hash"]
            return
        assert_refused(r, ck)
        assert (out / "ns2_model_float.h").read_bytes() == SENTINEL and len(list(out.iterdir())) == 1


# ------------------------------------------------------------------ problem files (plan)
PROBLEM = {"robots": [{"type": "small", "start": [0, -0.4, 1.0], "goal": [0, 0.4, 1.0]}], "axes": "yz",
           "limits": {"v_max": 1.0}}
PROBLEM_FIELDS = {"type": ("robots", 0, "type"), "start": ("robots", 0, "start"), "axes": ("axes",),
                  "v_max": ("limits", "v_max"), "u_max": ("limits", "u_max"), "pos_lo": ("limits", "pos_lo"),
                  "fa_substeps": ("limits", "fa_substeps"), "fa_max_g": ("limits", "fa_max_g"),
                  "robots": ("robots",), "qq": ("limits", "qq")}


@FAST
@given(field=st.sampled_from(sorted(PROBLEM_FIELDS)), value=HOSTILE)
def test_problem_file_property(field, value):
    """D8: plan --problem with one hostile field (robot type "giant" or 3, v_max
    "fast", 1e308 or true, a bad axes ...): refused before any planning."""
    if field in ("type", "axes") and value in ("fast",):
        value = "giant"
    prob = copy.deepcopy(PROBLEM)
    _set(prob, PROBLEM_FIELDS[field], value)
    with tempfile.TemporaryDirectory() as d:
        f, out = Path(d) / "p.json", Path(d) / "out"
        f.write_text(json.dumps(prob))
        out.mkdir()
        (out / "plan.json").write_bytes(SENTINEL)
        r = run(["plan", "--problem", f, "--baseline", "--out", out])
        assert_refused(r, f, field, out / "plan.json")


@pytest.mark.parametrize("field,value", [("type", "giant"), ("type", 3), ("v_max", "fast"), ("v_max", 1e308),
                                         ("v_max", True), ("axes", "qq")])
def test_d8_smallest_triggers(tmp_path, field, value):
    prob = copy.deepcopy(PROBLEM)
    _set(prob, PROBLEM_FIELDS[field], value)
    f = tmp_path / "p.json"
    f.write_text(json.dumps(prob))
    r = run(["plan", "--problem", f, "--baseline", "--out", tmp_path / "out"])
    assert_refused(r, f, field)


# ------------------------------------------------------------------ uSD logs (logs-to-data)
def _robot_log(t, z, q=(1.0, 0, 0, 0), vbat=3.9, sync_us=None) -> bytes:
    w = UsdLogWriter()
    names = [n for k in VARIABLES for n in VARIABLES[k]]
    ff = w.declare(0xFFFF, "fixedFrequency", [(n, "I" if n.startswith("motor") else "f") for n in names])
    n = len(t)
    p = np.stack([np.zeros(n), np.zeros(n), z], 1)
    cols = np.concatenate([p, np.zeros((n, 3)), np.tile(q, (n, 1)), np.full((n, 4), 0.6 * PWM_FULL),
                           np.full((n, 1), vbat)], 1)
    w.add_many(ff, np.round(t * 1e6), cols)
    w.add(w.declare(5, "ns2Sync", [("seq", "I")]), sync_us if sync_us is not None else int(t[0] * 1e6), [0])
    return w.encode()


@pytest.fixture(scope="module")
def log_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    t = np.arange(0.0, 3.0, 0.01)
    (root / "a.usd").write_bytes(_robot_log(t, 1.0 + 0.1 * np.sin(t)))
    (root / "flights.toml").write_text('rate_hz = 100\n[[flight]]\nname = "hover"\n'
                                       'robots = [{file = "a.usd", type = "small"}]\n')
    r = run(["logs-to-data", root, "--out", root / "ok.npz"])
    assert r.exit_code == 0, r.output   # the unmutated folder is valid
    return root


def _copy_folder(src: Path, dst: Path) -> None:
    for p in src.iterdir():
        if p.suffix in (".usd", ".toml"):
            (dst / p.name).write_bytes(p.read_bytes())


@FAST
@given(value=HOSTILE)
def test_flights_toml_rate_property(log_folder, value):
    """D6: rate_hz = 1e9, nan, "fast", <= 0 ... in flights.toml."""
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        _copy_folder(log_folder, d)
        text = (d / "flights.toml").read_text().replace("rate_hz = 100", _toml({"rate_hz": value}).strip()
                                                         if value is not None else "rate_hz = 1e9")
        (d / "flights.toml").write_text(text)
        out = d / "out.npz"
        out.write_bytes(SENTINEL)
        r = run(["logs-to-data", d, "--out", out])
        assert_refused(r, "flights.toml", "rate_hz", out)


@FAST
@given(k=st.integers(0, 10 ** 6), bit=st.integers(0, 7), truncated=st.booleans())
def test_bit_flipped_log_property(log_folder, k, bit, truncated):
    """D6: a complete log with one flipped bit is refused, with or without
    --allow-truncated (a truncated log stays usable with it)."""
    data = bytearray((log_folder / "a.usd").read_bytes())
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        _copy_folder(log_folder, d)
        i = 200 + k % (len(data) - 200)   # in the entries or the CRC
        data[i] ^= 1 << bit
        (d / "a.usd").write_bytes(bytes(data))
        out = d / "out.npz"
        out.write_bytes(SENTINEL)
        r = run(["logs-to-data", d, "--out", out, *(["--allow-truncated"] if truncated else [])])
        assert_refused(r, "a.usd", None, out)


@pytest.mark.parametrize("case", ["z", "quaternion", "vbat", "timestamp"])
def test_d6_absurd_values_in_a_valid_log_are_refused(tmp_path, case):
    t = np.arange(0.0, 3.0, 0.01)
    z = 1.0 + 0.1 * np.sin(t)
    kw = {}
    if case == "z":
        z = np.where(np.arange(len(t)) == 100, 3e38, z)
    elif case == "quaternion":
        kw["q"] = (0.0, 0.0, 0.0, 0.0)
    elif case == "vbat":
        kw["vbat"] = 0.0
    else:
        t = t.copy()
        t[-1] = 2.0 ** 62 * 1e-6   # a valid CRC over an absurd timestamp (2^62 us)
    (tmp_path / "a.usd").write_bytes(_robot_log(t, z, **kw))
    (tmp_path / "flights.toml").write_text('[[flight]]\nrobots = [{file = "a.usd", type = "small"}]\n')
    r = run(["logs-to-data", tmp_path, "--out", tmp_path / "d.npz"])
    assert_refused(r, "a.usd" if case != "timestamp" else "flights.toml", None)
    assert not (tmp_path / "d.npz").exists()


def test_truncated_log_is_still_usable(log_folder, tmp_path):
    _copy_folder(log_folder, tmp_path)
    data = (tmp_path / "a.usd").read_bytes()
    (tmp_path / "a.usd").write_bytes(data[:-37])   # power loss: no CRC, the last entry cut
    r = run(["logs-to-data", tmp_path, "--out", tmp_path / "d.npz", "--allow-truncated"])
    assert r.exit_code == 0, r.output


# ------------------------------------------------------------------ load-cell CSV (sysid)
@FAST
@given(col=st.sampled_from(["pwm", "vbat_V", "force_g"]), value=st.sampled_from(
    ["nan", "inf", "-inf", "1e308", "abc", "", "1e30", "0x10", "1,2"]), row=st.integers(0, 39))
def test_sysid_csv_property(col, value, row):
    rng = np.random.default_rng(0)
    p = rng.uniform(0.1, 1.0, 40)
    V = rng.uniform(3.5, 4.1, 40)
    f = 4 * (10 + 30 * p)
    rows = [{"pwm": f"{a:.4f}", "vbat_V": f"{b:.3f}", "force_g": f"{c:.3f}"} for a, b, c in zip(p, V, f)]
    rows[row][col] = value
    with tempfile.TemporaryDirectory() as d:
        csv_, out = Path(d) / "static.csv", Path(d) / "small.toml"
        csv_.write_text("pwm,vbat_V,force_g\n" + "".join(f"{r['pwm']},{r['vbat_V']},{r['force_g']}\n" for r in rows))
        out.write_bytes(SENTINEL)
        r = run(["sysid", "--type", "small", "--static", csv_, "--out", out])
        assert_refused(r, csv_, col, out)


# ------------------------------------------------------------------ export folders (hil, sim)
@pytest.mark.parametrize("cmd", [["sim", "swaps", "--out", "{d}/o"], ["sim", "rings", "--out", "{d}/o"],
                                 ["sim", "collect", "--seconds-per-team", "1", "--out", "{d}/o.npz"],
                                 ["hil", "--port", "/dev/null"]])
def test_missing_or_mixed_export_folder(exported, onboard, tmp_path, cmd):
    gen = tmp_path / "gen"
    gen.mkdir()
    for name in ("ns2_model_config.h", "ns2_model_fixed.h", "ns2_vehicles.h", "ns2_model_manifest.json"):
        (gen / name).write_bytes((exported.gen_dir / name).read_bytes())
    (gen / "ns2_model_float.h").write_bytes((onboard.gen_dir / "ns2_model_float.h").read_bytes())
    args = [a.format(d=tmp_path) for a in cmd] + ["--gen", gen]
    r = run(args)
    assert_refused(r, gen)
    r = run([a.format(d=tmp_path) for a in cmd] + ["--gen", tmp_path / "nothing"])
    assert_refused(r, tmp_path / "nothing")


# ================================================================== issue 28
# The six cases that got through, as regression tests, and a hypothesis strategy per
# file kind (configs through their three ways in, checkpoints, flight manifests).

INJECTION = "env */ int injected = 1; /*"


def _tamper_checkpoint(src: Path, dst: Path, fn) -> Path:
    """``src`` loaded, ``fn(obj, meta)`` applied, saved again under ``dst`` (as an
    attacker or a hand edit would: a valid archive, new CRCs)."""
    obj = torch.load(src, weights_only=True)
    meta = json.loads(obj["meta_json"])
    fn(obj, meta)
    obj["meta_json"] = json.dumps(meta)
    torch.save(obj, dst)
    return dst


def _replace_section(raw, path, value):
    """``raw`` with the value at ``path`` (keys and list indices) replaced."""
    raw = copy.deepcopy(raw)
    _set(raw, path, value)
    return raw


# -- 1. names become C code; 2. a name ending in '*'
@pytest.mark.parametrize("path,name", [(("environment", "name"), INJECTION), (("robot_types", 0, "name"), INJECTION),
                                       (("robot_types", 1, "name"), "large*"), (("environment", "name"), "a\\"),
                                       (("robot_types", 0, "name"), "sm??/all"), (("robot_types", 0, "name"), "a.b"),
                                       (("robot_types", 0, "name"), "x" * (NAME_MAX + 1))])
def test_28_1_2_names_refused_on_every_way_in(cfg, exported, tmp_path, path, name):
    raw = _replace_section(cfg.raw, path, name)
    raw["interaction_volume"] = {"default": raw["interaction_volume"]["default"]}
    field = ".".join(path[:1]) + (f"[{path[1]}]" if len(path) == 3 else "") + ".name"
    # a --config TOML (gen-data, train, ...)
    toml_file = tmp_path / "c.toml"
    toml_file.write_text(dump_toml(raw))
    r = run(["gen-data", "--config", toml_file, "--samples-per-scenario", "1", "--out", tmp_path / "d.npz"])
    assert_refused(r, toml_file, field)
    # a checkpoint's metadata (export, plan)
    ck = _tamper_checkpoint(exported.checkpoint, tmp_path / "m.pt", lambda o, m: m.update(config=raw))
    out = tmp_path / "gen"
    out.mkdir()
    (out / "ns2_model_config.h").write_bytes(SENTINEL)
    assert_refused(run(["export", ck, "--out", out]), ck, field, out / "ns2_model_config.h")
    (tmp_path / "p.json").write_text(json.dumps(PROBLEM))
    assert_refused(run(["plan", "--checkpoint", ck, "--problem", tmp_path / "p.json", "--out", tmp_path / "o"]),
                   ck, field)
    # an export folder's ns2_config.toml (sim, hil)
    gen = tmp_path / "gen2"
    shutil.copytree(exported.gen_dir, gen)
    (gen / CONFIG_FILE).write_text(dump_toml(raw))
    assert_refused(run(["hil", "--port", "/dev/null", "--gen", gen]), gen / CONFIG_FILE, field)
    assert not (tmp_path / "d.npz").exists() and not (tmp_path / "o").exists()


@settings(derandomize=True, max_examples=300, deadline=None, database=None)
@given(name=st.text(min_size=0, max_size=NAME_MAX + 4) | st.from_regex(r"[A-Za-z][A-Za-z0-9_ \-*/\\?.]{0,33}",
                                                                         fullmatch=True))
def test_28_admitted_names_are_inert_in_c(name):
    """Every admitted name is at most NAME_MAX characters that can neither end nor
    open a C comment, splice a line, form a trigraph nor break a TOML/JSON string."""
    try:
        check_name(name, "robot_types[0].name")
    except ConfigError as e:
        assert str(e).startswith("robot_types[0].name must be") and "\n" not in str(e)
        return
    assert 1 <= len(name) <= NAME_MAX and name.isascii() and name[0].isalpha() and not name.endswith(" ")
    assert not set(name) - set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_- ")


WORST_NAMES = ["A- -_ -- __  - -_- ---  _ -  -Z9",   # the longest, of every admitted character but letters
               "int", "Static"]                       # C keywords (robot types); the environment gets "Float"


def test_28_templates_with_the_worst_admitted_names_compile_with_werror(cfg, tmp_path):
    """Every template rendered with the worst names the validator admits (the longest,
    runs of '-', ' ' and '_', C keywords, capitals) gives headers that compile alone and
    together, and the whole library against them, with the strict flags (-Werror)."""
    from ns2host.cbuild import HOST_SOURCES, REPO, compile_objects, flags, host_cc
    from conftest import train_and_export

    assert len(WORST_NAMES[0]) == NAME_MAX
    raw = copy.deepcopy(cfg.raw)
    raw["robot_types"] = [dict(raw["robot_types"][i % 2], name=n) for i, n in enumerate(WORST_NAMES)]
    raw["environment"]["name"] = "Float"
    raw["interaction_volume"] = {"default": raw["interaction_volume"]["default"],
                                 f"{WORST_NAMES[0]}.int": raw["interaction_volume"]["large.small"]}
    worst = Config.from_dict(raw)
    ex = train_and_export(worst, tmp_path, samples=60, epochs=1)
    texts = {h: (ex.gen_dir / h).read_text() for h in ("ns2_model_config.h", "ns2_model_float.h",
                                                         "ns2_model_fixed.h", "ns2_vehicles.h")}
    assert f"/* robot {WORST_NAMES[0]} */" in texts["ns2_model_config.h"]
    assert "#define NS2_TYPE_A_Z9 0" in texts["ns2_model_config.h"]
    assert "#define NS2_TYPE_INT_ 1" in texts["ns2_model_config.h"]
    assert "#define NS2_TYPE_FLOAT_ 3" in texts["ns2_model_config.h"]
    assert f"/* {WORST_NAMES[0]} */ \\" in texts["ns2_vehicles.h"]
    f = flags()
    src = tmp_path / "all.c"
    src.write_text("".join(f'#include "{h}"\n' for h in texts) + "int main(void) { return NS2_TYPE_STATIC_ - 2; }\n")
    for h in [*texts, None]:
        one = tmp_path / "one.c"
        one.write_text(f'#include "{h}"\nint main(void) {{ return 0; }}\n' if h else src.read_text())
        r = subprocess.run([host_cc(), *f["NS2_STD_FLAGS"], *f["NS2_WARN_FLAGS"], "-I", str(ex.gen_dir),
                            *[f"-I{REPO / i}" for i in f["NS2_INCLUDES"]], "-c", str(one), "-o",
                            str(tmp_path / "one.o")], capture_output=True, text=True)
        assert r.returncode == 0, (h, r.stderr)
    objs = tmp_path / "objs"
    objs.mkdir()
    assert len(compile_objects(ex.gen_dir, objs, host_cc(), [], f)) == len(f["NS2_SOURCES"]) + len(HOST_SOURCES)


# -- 3. checkpoints verified
def _data_spans(path: Path) -> list[tuple[str, int, int]]:
    """(member, first byte, end) of the stored data of every tensor in the archive."""
    data = path.read_bytes()
    spans = []
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            if "/data/" in info.filename and info.compress_size:
                o = info.header_offset
                start = o + 30 + struct.unpack("<H", data[o + 26:o + 28])[0] + struct.unpack("<H", data[o + 28:o + 30])[0]
                spans.append((info.filename, start, start + info.compress_size))
    return spans


@settings(derandomize=True, max_examples=25, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(k=st.integers(0, 10 ** 9), bit=st.integers(0, 7))
def test_28_3_a_flipped_weight_bit_is_refused(exported, k, bit):
    """Any single-bit flip inside a weight tensor's stored bytes: the export is refused
    (the archive's CRC-32), where before 23 of 25 exported a different model."""
    spans = _data_spans(exported.checkpoint)
    name, a, b = spans[k % len(spans)]
    data = bytearray(exported.checkpoint.read_bytes())
    data[a + (k // len(spans)) % (b - a)] ^= 1 << bit
    with tempfile.TemporaryDirectory() as d:
        ck, out = Path(d) / "flipped.pt", Path(d) / "gen"
        ck.write_bytes(bytes(data))
        r = run(["export", ck, "--out", out])
        assert_refused(r, ck, "CRC-32")
        assert not out.exists()


@pytest.mark.parametrize("change", ["one ulp of a weight", "a vehicle parameter", "the recorded hash"])
def test_28_3_a_resaved_checkpoint_must_match_its_hash(exported, tmp_path, change):
    """Edited and saved again (a valid archive with fresh CRCs): the recomputed model
    hash differs from the recorded one."""
    def fn(obj, meta):
        if change == "one ulp of a weight":
            t = obj["state_dict"]["rho.0.layers.1.weight"]
            t.view(-1)[7] = torch.nextafter(t.view(-1)[7], torch.tensor(math.inf))
        elif change == "a vehicle parameter":
            meta["config"]["robot_types"][0]["mass_g"] += 1.0
        else:
            obj["model_hash"] = "0" * 64
    ck = _tamper_checkpoint(exported.checkpoint, tmp_path / "edited.pt", fn)
    assert_refused(run(["export", ck, "--out", tmp_path / "gen"]), ck, "model_hash")
    (tmp_path / "p.json").write_text(json.dumps(PROBLEM))
    assert_refused(run(["plan", "--checkpoint", ck, "--problem", tmp_path / "p.json", "--baseline",
                        "--out", tmp_path / "o"]), ck, "model_hash")
    with pytest.raises(CheckpointError, match="model_hash"):
        load_checkpoint(ck)


def test_28_3_the_record_is_the_export_hash_and_old_checkpoints_warn(exported, tmp_path):
    """The recorded hash is the one the export's manifest and NS2_MODEL_ID derive
    from; a version 1 checkpoint (no record) exports the same model with one warning."""
    obj = torch.load(exported.checkpoint, weights_only=True)
    assert obj["version"] == 2 and obj["model_hash"] == exported.manifest["model_hash"]
    assert f"#define NS2_MODEL_ID 0x{obj['model_hash'][:15]}" in (exported.gen_dir / "ns2_model_config.h").read_text()
    del obj["model_hash"]
    obj["version"] = 1
    old = tmp_path / "v1.pt"
    torch.save(obj, old)
    with pytest.warns(LegacyCheckpointWarning, match="no integrity record"):
        load_checkpoint(old)
    r = run(["export", old, "--out", tmp_path / "gen", "--json"])
    assert r.exit_code == 0, r.output
    warning, = r.stderr.strip().splitlines()
    assert warning.startswith("Warning: checkpoint ") and str(old) in warning and "save it again" in warning
    assert json.loads(r.stdout)["model_hash"] == exported.manifest["model_hash"]
    for bad in (0, 3, True, "2"):   # versions this ns2codegen does not read
        obj["version"] = bad
        torch.save(obj, old)
        assert_refused(run(["export", old, "--out", tmp_path / "gen"]), old, "version")


# -- 4. config sections of the wrong type
WRONG_TYPES = [(("robot_types", 0), "small", "robot_types[0]"), (("environment",), "env", "environment"),
               (("model",), [1, 2], "model"), (("neighbors",), 3, "neighbors"),
               (("interaction_volume", "default"), 3, "interaction_volume.default"),
               (("robot_types",), {"name": "small"}, "robot_types"), (("train",), "fast", "train"),
               (("robot_types", 0, "mas_g"), 34.0, "mas_g"), (("model", "widht"), 40, "widht"),
               (("sim",), {"dt": 0.01}, "[sim]")]


@pytest.mark.parametrize("path,value,field", WRONG_TYPES, ids=[w[2] for w in WRONG_TYPES])
def test_28_4_6_wrong_section_types_and_unknown_keys_name_the_field(cfg, exported, tmp_path, path, value, field):
    """A section of the wrong type (and a key the config does not know: a typo such as
    mas_g) is refused naming file and field, in a checkpoint (export, plan) as in a TOML."""
    raw = _replace_section(cfg.raw, path, value)
    ck = _tamper_checkpoint(exported.checkpoint, tmp_path / "m.pt", lambda o, m: m.update(config=raw))
    r = run(["export", ck, "--out", tmp_path / "gen"])
    assert_refused(r, ck, field)
    assert "Error(" not in r.stderr and "malformed" not in r.stderr
    (tmp_path / "p.json").write_text(json.dumps(PROBLEM))
    assert_refused(run(["plan", "--checkpoint", ck, "--problem", tmp_path / "p.json", "--out", tmp_path / "o"]),
                   ck, field)
    toml_file = tmp_path / "c.toml"
    toml_file.write_text(_toml(raw))
    r = run(["gen-data", "--config", toml_file, "--samples-per-scenario", "1", "--out", tmp_path / "d.npz"])
    assert_refused(r, toml_file, field)
    assert "Error(" not in r.stderr and "malformed" not in r.stderr
    if field in ("mas_g", "widht", "[sim]"):
        assert "known: " in r.stderr


# -- 6. refusals name the file; torch's errors in our words
def test_28_6_export_refusals_name_the_checkpoint(exported, cfg, tmp_path):
    heavy = copy.deepcopy(cfg.raw)
    heavy["robot_types"][0]["mass_g"] = 1e5   # fa_max 30 kg: beyond any int16 output range
    ck = tmp_path / "heavy.pt"
    save_checkpoint(ck, exported.model, Config.from_dict(heavy), {"seed": 0})
    assert_refused(run(["export", ck, "--out", tmp_path / "gen"]), ck, "fa_max")
    big = copy.deepcopy(exported.model)
    with torch.no_grad():
        for p in big.parameters():
            p.mul_(1e8)           # finite weights whose activations exceed the float limit
    ck = tmp_path / "big.pt"
    save_checkpoint(ck, big, cfg, {"seed": 0})
    assert_refused(run(["export", ck, "--out", tmp_path / "gen"]), ck, "float activations")


def test_28_6_torch_errors_are_summarized(exported, tmp_path):
    import argparse

    data = exported.checkpoint.read_bytes()
    pickled = tmp_path / "object.pt"
    torch.save({"format": "ns2codegen-checkpoint", "x": argparse.Namespace(a=1)}, pickled)
    cases = {"truncated.pt": data[:len(data) // 2], "garbage.pt": bytes(range(256)) * 8, "empty.pt": b"",
             "one_byte_short.pt": data[:-1]}
    for name, blob in cases.items():
        (tmp_path / name).write_bytes(blob)
    for ck in [tmp_path / n for n in cases] + [pickled]:
        r = run(["export", ck, "--out", tmp_path / "gen"])
        assert_refused(r, ck)
        line = r.stderr.strip()
        assert len(line) < 250 and "weights_only" not in line and not line.endswith(":"), line
        assert ("corrupt or truncated" in line) if ck != pickled else ("not an ns2codegen checkpoint" in line)


# -- 5. flight manifests
def _manifest_folder(log_folder: Path, d: Path, text: str) -> Path:
    """``d/m`` with ``a.usd`` and ``flights.toml`` = ``text``; ``d/a.usd`` outside it."""
    m = d / "m"
    m.mkdir()
    (m / "a.usd").write_bytes((log_folder / "a.usd").read_bytes())
    (d / "a.usd").write_bytes((log_folder / "a.usd").read_bytes())
    (m / "flights.toml").write_text(text)
    return m


@pytest.mark.parametrize("robots,field", [
    ("flight = [1, 2]", "flight[0]"),
    ('[[flight]]\nrobots = [{file = "a.usd", type = "small"}, {file = "./a.usd", type = "large"}]', "robots[1].file"),
    ('[[flight]]\nrobots = [{file = "../a.usd", type = "small"}]', "outside"),
    ('[[flight]]\nrobots = [{file = "sub/../../a.usd", type = "small"}]', "outside"),
    ('[[flight]]\nrobots = [{file = "ABS", type = "small"}]', "outside"),
    ('[[flight]]\nrobots = [{file = "link.usd", type = "small"}]', "outside"),
    ('[[flight]]\nrobots = [{file = "a.usd", typ = "small"}]', "robots[0].typ"),
    ('[[flight]]\nnmae = "x"\nrobots = [{file = "a.usd", type = "small"}]', "flight[0].nmae"),
    ('[[flight]]\nrobots = "a.usd"', "flight[0].robots"),
    ('[[flight]]\nrobots = [[1]]', "robots[0]"),
    ('rate = 100\n[[flight]]\nrobots = [{file = "a.usd", type = "small"}]', "rate"),
    ('flight = "hover"', "flight"), ('[flight]\nrobots = []', "flight"),
    ('ground_plane_m = 0.05\n[[flight]]\nrobots = [{file = "a.usd", type = "small"}]', "ground_plane_m"),
    ('[ground_plane_m]\nsmall = nan\n[[flight]]\nrobots = [{file = "a.usd", type = "small"}]', "ground_plane_m.small"),
    ('[[flight]]\nrobots = [{file = "a.usd", type = "small", label = "no"}]', "robots[0].label"),
    ('[[flight]]\nrobots = [{file = "a.usd", type = "small", id = "cf1"}, {file = "b.usd", type = "small", id = "cf1"}]',
     "cf1")])
def test_28_5_flight_manifest_structure(log_folder, tmp_path, robots, field):
    """flight = [1, 2], one log named for two robots of a flight, paths out of the
    folder ('..', absolute, a link), unknown keys: one line naming flights.toml and the
    field, nothing written.  --allow-outside-paths reads a log outside."""
    m = _manifest_folder(log_folder, tmp_path, robots.replace("ABS", str(tmp_path / "a.usd")))
    (m / "link.usd").symlink_to(tmp_path / "a.usd")
    out = tmp_path / "d.npz"
    out.write_bytes(SENTINEL)
    r = run(["logs-to-data", m, "--out", out])
    assert_refused(r, m / "flights.toml", field, out)
    if field == "outside":
        r = run(["logs-to-data", m, "--out", tmp_path / "ok.npz", "--allow-outside-paths"])
        assert r.exit_code == 0, r.output


_ANY = st.one_of(st.booleans(), st.integers(-5, 2000), st.floats(), st.text(max_size=8),
                 st.lists(st.integers(0, 3), max_size=2), st.dictionaries(st.sampled_from(["file", "type", "x"]),
                                                                           st.text(max_size=4), max_size=2))
_FILES = st.sampled_from(["a.usd", "./a.usd", "../a.usd", "ABS", "sub/../a.usd", "sub/../../a.usd", "link.usd", "",
                          "b.usd", "a\u0000.usd", "a\n.usd"])
_ROBOT = st.fixed_dictionaries({"file": _FILES, "type": st.sampled_from(["small", "large", "", "giant"])},
                               optional={"x": st.integers(0, 1)}) | _ANY
_FLIGHT = st.fixed_dictionaries({"robots": st.lists(_ROBOT, max_size=3) | _ANY},
                                optional={"name": st.text(max_size=5) | _ANY, "extra": st.integers(0, 1)}) | _ANY
_NEAR_VALID = st.fixed_dictionaries(   # mostly well formed: one flaw at most, often none
    {"flight": st.lists(st.fixed_dictionaries(
        {"robots": st.lists(st.fixed_dictionaries({"file": st.sampled_from(["a.usd", "sub/../a.usd", "b.usd",
                                                                            "../a.usd", "link.usd"]),
                                                   "type": st.just("small")}), min_size=1, max_size=2)},
        optional={"name": st.text(max_size=5)}), min_size=1, max_size=2)},
    optional={"rate_hz": st.sampled_from([100, 50.5, 1000, 0, 1e9])})
MANIFESTS = _NEAR_VALID | st.fixed_dictionaries({}, optional={
    "rate_hz": st.floats() | st.integers(-10, 2000) | _ANY, "flight": st.lists(_FLIGHT, min_size=0, max_size=3) | _ANY,
    "flights": st.integers(0, 1)})


@settings(derandomize=True, max_examples=300, deadline=None, database=None)
@given(man=MANIFESTS)
def test_28_5_manifest_property(man):
    """load_manifest on any structure: a ManifestError of one line naming flights.toml,
    or a manifest whose every flight has robots, one file each, all inside the folder."""
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        m = d / "m"
        (m / "sub").mkdir(parents=True)
        (m / "link.usd").symlink_to(d / "a.usd")
        text = _toml(man).replace('"ABS"', json.dumps(str(d / "a.usd")))
        (m / "flights.toml").write_text(text)
        try:
            got = load_manifest(m)
        except ManifestError as e:
            msg = str(e)
            assert str(m / "flights.toml") in msg and "\n" not in msg and len(msg) < 400, msg
            event("manifest refused")
            return
        event("manifest accepted")
        assert 0 < got["rate_hz"] <= 1000 and got["flight"]
        for fl in got["flight"]:
            paths = [r["path"] for r in fl["robots"]]
            assert paths and len(set(paths)) == len(paths)
            assert all(p.is_relative_to(m.resolve()) for p in paths)


# -- a config through its three ways in: a --config TOML, a checkpoint, an export folder
def _paths(d, prefix=()) -> list[tuple]:
    out = [prefix] if prefix else []
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    for k, v in items:
        out += _paths(v, prefix + (k,))
    return out


_VALUES = st.one_of(st.booleans(), st.integers(-2 ** 63, 2 ** 63 - 1), st.floats(), st.text(max_size=12),
                    st.sampled_from([INJECTION, "small*", "a.b", "x" * 40, "", "Small", "env", "large", "a\\"]),
                    st.lists(st.floats(-5, 5), max_size=4), st.lists(st.lists(st.integers(-3, 3), max_size=3),
                                                                     max_size=3),
                    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
                    st.just({"lo": [0, 0, 0], "hi": [1, 1, 1]}), st.just([]), st.just({}))


@st.composite
def mutated_configs(draw, raw):
    """The default config with one to three fields replaced, removed or added."""
    raw = copy.deepcopy(raw)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_paths(raw) or [("model",)]))
        parent = raw
        for k in path[:-1]:
            parent = parent[k]
        op = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if op == "replace":
            parent[path[-1]] = draw(_VALUES)
        elif op == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(["mas_g", "extra", "Name", "name", "default"]))] = draw(_VALUES)
    return raw


@settings(derandomize=True, max_examples=60, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_28_config_property_on_every_way_in(cfg, exported, data):
    """A structurally mutated config: the TOML and the export folder's ns2_config.toml
    give a Config or a one-line ConfigError naming the file; a checkpoint carrying it
    is refused naming the checkpoint (a valid change no longer matches its model_hash)."""
    raw = data.draw(mutated_configs(cfg.raw))
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        text = _toml(raw)
        (d / CONFIG_FILE).write_text(text)
        for load, path in ((Config.load, d / CONFIG_FILE), (export_config, d)):
            try:
                got = load(path)
            except ConfigError as e:
                msg = str(e)
                assert msg.startswith(f"config file {d / CONFIG_FILE}: ") and "\n" not in msg, msg
                assert len(msg) < 400 and "Error(" not in msg, msg
                event("config refused")
                continue
            event("config accepted")
            for n in got.neighbor_types:
                check_name(n, "name")
            got.phi_dims(), got.rho_dims()
            [got.volume(r, t) for r in range(got.num_robot_types) for t in range(got.num_robot_types)]
            [got.input_box(t) for t in range(len(got.neighbor_types))]
        ck = _tamper_checkpoint(exported.checkpoint, d / "m.pt", lambda o, m: m.update(config=raw))
        try:
            load_checkpoint(ck)
        except CheckpointError as e:
            msg = str(e)
            assert str(ck) in msg and "\n" not in msg and len(msg) < 400, msg
        else:   # only a mutation that changed nothing keeps the recorded hash
            assert Config.from_dict(raw).to_json() == cfg.to_json()


# ================================================================== issue 56
# The swarm file (ns2ground/swarm.py) and the radio log (ns2codegen/logs/radiolog.py):
# any bytes, any encoding, any nesting give a checked result or one line naming the file.

SWARM_FILE = """\
# a lab's swarm (Crazyswarm2 layout)
robots:
  cf1:
    enabled: true
    uri: radio://0/80/2M/E7E7E7E701
    initial_position: [0.0, -0.5, 0.0]
    type: cf21
    firmware_params:
      ns2gain: {Lpx: 9.5}
  cf40:
    uri: radio://0/80/2M/E7E7E7E728
    initial_position: [0.0, 0.5, 0.0]
    type: big
  cf255:
    enabled: false
    uri: radio://0/90/2M/E7E7E7E7FF
    type: big
robot_types:
  cf21: {ns2_type: small}
  big: {ns2_type: large}
all:
  firmware_params: {stabilizer: {controller: 5}}
"""
ENCODINGS = st.sampled_from(["utf-8", "utf-8-sig", "utf-16", "utf-16-le", "utf-16-be", "utf-32", "latin-1",
                             "cp1252"])
# text pieces a mutation splices in: YAML structure, hostile scalars, nesting, odd characters
_PIECES = st.one_of(
    st.sampled_from(["", "\n", ": ", "- ", "[", "]", "{", "}", "&a ", "*a", "!!python/object:os.system ", "? ",
                     "'", '"', "\\", "\t", "\x00", "\x85", "\u2028", "\ufeff", "\udcff", "é", "\u202e",
                     "1" + "0" * 400, "1e999", ".nan", "-.inf", "0x1F", "E7E7E7E700", "E7E7E7E7FF", "radio://0/126/2M/",
                     "robots:", "type: big", "ns2_type: small", "uri: usb://0", "enabled: maybe", "cf1:", "cf40:"]),
    st.integers(1, 300).map(lambda n: "[" * n + "]" * n),
    st.sampled_from([30, 40, 100_000]).map(lambda n: "[" * n),
    st.sampled_from([30, 40, 100_000]).map(lambda n: "{a: " * n + "1" + "}" * n),
    st.sampled_from([30, 40, 300]).map(lambda n: "".join(" " * i + "k:\n" for i in range(n))),
    st.text(max_size=12))


@st.composite
def lab_swarms(draw):
    """A well-formed swarm file of a lab's own numbering: up to 20 robots, any radio ids
    (0 and 255 among them; now and then a duplicate), mostly valid types, channels and
    positions, enabled or not."""
    n = draw(st.integers(1, 20))
    ids = draw(st.lists(st.sampled_from([0, 255, 31, 32, 40]) | st.integers(0, 255), min_size=n, max_size=n,
                        unique=draw(st.integers(0, 3)) > 0))
    robots = []
    alias = draw(st.sampled_from(["", "", "fp", "ns2"]))   # firmware_params (or its ns2 group) shared by an alias
    for k, rid in enumerate(ids):
        channel = draw(st.sampled_from([80] * 8 + [0, 125, 126]))
        typ = draw(st.sampled_from(["cf21"] * 6 + ["big"] * 6 + ["small", "large", "huge"]))
        x = draw(st.floats(-5.0, 5.0) | st.sampled_from([1e3, -1e3, 1001.0]))
        fp = {"": "", "fp": "    firmware_params: " + ("&fp {stabilizer: {controller: 5}}" if k == 0 else "*fp"),
              "ns2": "    firmware_params: {ns2: " + ("&n {enable: 1}" if k == 0 else "*n") + "}"}[alias]
        robots.append(f"  cf{k}:\n    enabled: {draw(st.sampled_from(['true'] * 3 + ['false']))}\n"
                      f"    uri: radio://0/{channel}/2M/E7E7E7E7{rid:02X}\n"
                      f"    initial_position: [{x}, 0.0, 0.0]\n    type: {typ}\n" + (fp + "\n" if fp else ""))
    return ("robots:\n" + "".join(robots) + "robot_types:\n  cf21: {ns2_type: small}\n  big: {ns2_type: large}\n"
            ).encode()


@st.composite
def swarm_files(draw):
    """Bytes of a swarm file: the valid one mutated (pieces spliced in or cut out), in any
    encoding, with bytes flipped or cut; a well-formed one of any numbering; or any
    bytes at all."""
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return draw(st.binary(max_size=600))
    if kind <= 3:
        return draw(lab_swarms())
    text = SWARM_FILE
    for _ in range(draw(st.integers(0, 3))):
        i = draw(st.integers(0, len(text)))
        j = min(len(text), i + draw(st.integers(0, 12)))
        text = text[:i] + draw(_PIECES) + text[j:]
    data = _encode(text, draw(ENCODINGS))
    for _ in range(draw(st.integers(0, 2))):
        if data and draw(st.booleans()):
            k = draw(st.integers(0, len(data) - 1))
            data = data[:k] + bytes([data[k] ^ draw(st.integers(1, 255))]) + data[k + 1:]
    if data and draw(st.integers(0, 4)) == 0:
        data = data[:draw(st.integers(0, len(data)))]
    return data


def _encode(text: str, enc: str) -> bytes:
    try:
        return text.encode(enc)
    except UnicodeEncodeError:
        return text.encode("utf-8", "surrogatepass")


@settings(derandomize=True, max_examples=300, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_56_swarm_file_property(cfg, data):
    """ns2ground.swarm.load (ns2 swarm-params, ns2 fly) and read_robots (ns2 flash --swarm)
    on any bytes: a SwarmFileError of one line naming the file, or a swarm whose every
    robot holds the loader's guarantees; then the app's parameters, written back with
    the round trip, load again to the same robots and the same type table."""
    from ns2ground import swarm as sw

    raw = data.draw(swarm_files())
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "crazyflies.yaml"
        f.write_bytes(raw)
        try:
            robots = sw.read_robots(f)
        except sw.SwarmFileError as e:
            msg = str(e)
            assert msg.startswith(f"{f}: ") and "\n" not in msg and len(msg) < 500, msg
            robots = None
        try:
            s = sw.load(f, cfg)
        except sw.SwarmFileError as e:
            msg = str(e)
            assert msg.startswith(f"{f}: ") and "\n" not in msg and len(msg) < 500, msg
            event("swarm file refused")
            return
        event("swarm file accepted")
        assert robots == ({r.name: r.uri for r in s.enabled} or None)   # flash refuses a swarm with none enabled
        ids = [r.radio_id for r in s.robots]
        assert len(set(ids)) == len(ids) and all(0 <= i <= 255 for i in ids)
        assert 0 not in [r.radio_id for r in s.enabled] or len(s.enabled) == 1
        for r in s.robots:
            assert sw.NAME.fullmatch(r.name) and sw.URI.fullmatch(r.uri) and r.ns2_type in cfg.robot_types
            assert all(math.isfinite(x) and abs(x) <= sw.POSITION_MAX_M for x in r.initial_position)
        try:
            table = [sw.params(s, cfg, r)["ns2type"] for r in s.robots]
        except sw.SwarmFileError as e:   # a user's gain that is not one
            assert str(e).startswith(f"{f}: robots.") and "ns2gain" in str(e)
            return
        for r in s.robots:
            t = cfg.robot_types.index(r.ns2_type)
            assert all((tb[f"t{r.radio_id // 16}"] >> (2 * (r.radio_id % 16))) & 3 == t for tb in table)
        out = Path(d) / "out.yaml"
        s2 = sw.write_params(f, cfg, out)
        assert f.read_bytes() == raw
        assert [(r.name, r.uri, r.ns2_type) for r in s2.robots] == [(r.name, r.uri, r.ns2_type) for r in s.robots]
        assert all(dict(r.firmware_params["ns2type"]) == table[0] for r in s2.robots)
        for r in s2.robots:   # each robot's own type, also where the file shared its parameters by an alias
            assert r.firmware_params["ns2"]["selfType"] == cfg.robot_types.index(r.ns2_type), r.name


def _radio_lines(n=30):
    """ns2 fly's radio log of two robots (a header, then their log blocks at 20 Hz)."""
    out = [{"flight": {"robots": {"cf1": "small", "cf40": "large"}, "sync": 7}}]
    for k in range(n):
        for name, z, boot in (("cf1", 0.5, 1000), ("cf40", 0.9, 77)):
            t = boot + 50 * k
            out += [{"robot": name, "t_ms": t, "host_ms": 50 * k + 3, "pm.vbat": 3.9, "ns2.faHat": -1.0},
                    {"robot": name, "t_ms": t, "host_ms": 50 * k + 4, "stateEstimate.x": 0.01 * k,
                     "stateEstimate.y": 0.0, "stateEstimate.z": z, "stateEstimate.vx": 0.2, "stateEstimate.vy": 0.0,
                     "stateEstimate.vz": 0.0, **{f"motor.m{j}": 30000 for j in range(1, 5)},
                     "stateEstimate.qw": 1.0, "stateEstimate.qx": 0.0, "stateEstimate.qy": 0.0,
                     "stateEstimate.qz": 0.0}]
    return [json.dumps(x) for x in out]


RADIO_LINES = _radio_lines()
_LINE_PIECES = st.one_of(
    st.sampled_from(["", "[", "]", "{", "}", ",", ":", '"', "\\", "\\u0000", "\\ud800", "\u2028", "\x00", "\r",
                     "NaN", "-Infinity", "1e999", "1" + "0" * 400, "1" + "0" * 5000, "true", "null", '"robot"',
                     '"cf1"', '"cf9"', '"t_ms"', '"stateEstimate.z"', "3e38", "-1", "150.0", "65536"]),
    st.sampled_from([9, 50, 2_000, 100_000]).map(lambda n: "[" * n),
    st.sampled_from([9, 50, 2_000, 100_000]).map(lambda n: "[" * n + "]" * n),
    st.sampled_from([9, 2_000, 100_000]).map(lambda n: '{"a": ' * n + "1" + "}" * n),
    st.text(max_size=10))


@st.composite
def radio_logs(draw):
    """Bytes of a radio log: ns2 fly's mutated (lines dropped, repeated or spliced into),
    in any encoding, with bytes flipped or cut; or any bytes at all."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=600))
    lines = list(RADIO_LINES)
    for _ in range(draw(st.integers(0, 3))):
        k = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["splice", "splice", "drop", "repeat", "new"]))
        if op == "splice":
            i = draw(st.integers(0, len(lines[k])))
            j = min(len(lines[k]), i + draw(st.integers(0, 8)))
            lines[k] = lines[k][:i] + draw(_LINE_PIECES) + lines[k][j:]
        elif op == "drop":
            del lines[k]
        elif op == "repeat":
            lines.insert(k, lines[k])
        else:
            lines.insert(k, draw(_LINE_PIECES))
        if not lines:
            break
    data = _encode("\n".join(lines) + "\n", draw(ENCODINGS))
    if data and draw(st.integers(0, 4)) == 0:
        k = draw(st.integers(0, len(data) - 1))
        data = data[:k] + bytes([data[k] ^ draw(st.integers(1, 255))]) + data[k + 1:]
    if data and draw(st.integers(0, 4)) == 0:
        data = data[:draw(st.integers(0, len(data)))]
    return data


@settings(derandomize=True, max_examples=300, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_56_radio_log_property(cfg, data):
    """ns2codegen.logs.radiolog (ns2 logs-to-data LOG.jsonl) on any bytes: a RadioLogError
    of one line naming the file (and the line, when a line is at fault), or flights whose
    every sample is a checked, finite value in its physical range."""
    from ns2codegen.logs import radiolog
    from ns2codegen.logs.align import LogError

    raw = data.draw(radio_logs())
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "flight.jsonl"
        f.write_bytes(raw)
        try:
            flights = radiolog.read(f)
        except radiolog.RadioLogError as e:
            msg = str(e)
            assert msg.startswith(f"{f}: ") and "\n" not in msg and len(msg) < 500, msg
            event("radio log refused by read")
            return
        for fl in flights:
            assert fl["robots"] and all(n.isprintable() and 0 < len(n) <= radiolog.NAME_MAX for n in fl["robots"])
            for samples in fl["samples"].values():
                for line, t, h, vals in samples:
                    assert radiolog._number(t) and radiolog._number(h) and t >= 0
                    assert all(radiolog._number(v) for v in vals.values())
                    assert all(lo <= vals[k] <= hi for k, (lo, hi) in radiolog.RANGE.items() if k in vals)
        try:
            pieces, reports = radiolog.radiolog_to_flights(cfg, f)
        except LogError as e:
            msg = str(e)
            assert msg.startswith(f"{f}: ") and "\n" not in msg and len(msg) < 500, msg
            event("radio log refused")
            return
        event("radio log accepted")
        for p in pieces:
            assert np.isfinite(p.p).all() and np.isfinite(p.v).all() and np.isfinite(p.t).all()


@pytest.mark.parametrize("line", ["[" * 100_000, "[" * 100_000 + "]" * 100_000, '{"a": ' * 100_000])
def test_56_radio_log_nested_100000_deep_is_one_line(tmp_path, line):
    """Issue 56: ns2 logs-to-data on a line nested 100,000 deep: one line naming file and line."""
    f = tmp_path / "flight.jsonl"
    f.write_text("\n".join(RADIO_LINES[:3] + [line] + RADIO_LINES[3:]) + "\n")
    out = tmp_path / "d.npz"
    out.write_bytes(SENTINEL)
    r = run(["logs-to-data", f, "--out", out])
    assert_refused(r, f, "line 4: not JSON of a radio log: nested deeper than 8 levels", out)
