"""Export a checkpoint to C headers (float + fixed point) and a JSON manifest.

Output (deterministic: the same checkpoint gives byte-identical files):
  ns2_model_config.h   types, dimensions, interaction volume, input boxes
  ns2_model_float.h    float32 weights as exact hexadecimal literals
  ns2_model_fixed.h    int16/int32 tables, Q formats, shifts
  ns2_vehicles.h       vehicle parameters and default gains of the controller
  ns2_model_manifest.json  hash, dims, Q formats, Lipschitz bound, overflow proof,
                       measured |fixed - float| error
  ns2_config.toml      the whole config the model was trained with (``export_config``
                       reads it back: every command given an export folder uses it)
The set is written to a new folder and swapped in as a whole
(fileio.write_folder_set), and every header carries the model's id
(NS2_MODEL_ID) and refuses to compile (#error) next to a header of another model.
"""
from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import jinja2
import numpy as np

from . import __version__
from .checkpoint import load_checkpoint
from .config import VEHICLE_KEYS, Config, ConfigError, c_identifier, check_name, dump_toml
from .fileio import write_folder_set
from .queries import random_queries
from .quantize import ExportModel, QuantizationError, from_checkpoint, pad4
from .vehicle import G, default_gains, has_rigid_body, vehicle



def templates_dir() -> Path:
    """The C header templates: package data of ``ns2codegen.templates``, which
    pyproject.toml maps to the checkout's top-level ``templates/`` (a wheel has them in
    ns2codegen/templates, an editable install finds the checkout's folder); an
    editable install made before that mapping finds the checkout's folder directly."""
    spec = importlib.util.find_spec("ns2codegen.templates")
    if spec is not None and spec.submodule_search_locations:
        return Path(list(spec.submodule_search_locations)[0])
    return Path(__file__).resolve().parent.parent / "templates"


HEADERS = ("ns2_model_config.h", "ns2_model_float.h", "ns2_model_fixed.h", "ns2_vehicles.h")
MANIFEST = "ns2_model_manifest.json"
CONFIG_FILE = "ns2_config.toml"
ERROR_QUERIES = 20000


def cfloat(x) -> str:
    """Exact C float literal (hexadecimal) of a float32 value."""
    v = float(np.float32(x))
    if not np.isfinite(v):
        raise ValueError(f"non-finite value {v} cannot be exported")
    if v == 0.0:
        return "-0.0f" if np.signbit(v) else "0.0f"
    m = re.match(r"(-?0x[01])\.?([0-9a-f]*?)0*p([+-]\d+)$", v.hex())
    mant = m.group(1) + ("." + m.group(2) if m.group(2) else "")
    return f"{mant}p{m.group(3)}f"


def float_layout(w: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Stream of a float layer: per block of four rows (rows zero-padded to a multiple
    of four) the four biases, then the four weights of each input: [block][1 + n_in][4]."""
    n_out, n_in = w.shape
    wp = np.zeros((pad4(n_out), n_in + 1), np.float32)
    wp[:n_out, 0] = b
    wp[:n_out, 1:] = w
    return wp.reshape(-1, 4, n_in + 1).transpose(0, 2, 1).ravel()


def fixed_layout(w: np.ndarray, b: np.ndarray, shift: int) -> np.ndarray:
    """Stream of a fixed-point layer (int32 words): per block of four rows the four
    biases plus the rounding offset 2^(shift-1), then per input pair the four rows'
    words of packed int16 weights (even input in the low half):
    [block][4 + n_pairs * 4], n_pairs = 2 n_quads."""
    n_out, n_in = w.shape
    wp = np.zeros((pad4(n_out), pad4(n_in)), np.int64)
    wp[:n_out, :n_in] = w
    pairs = wp.reshape(-1, 4, pad4(n_in) // 2, 2).transpose(0, 2, 1, 3)  # [block][pair][row][2]
    words = (pairs[..., 1] * 65536 + (pairs[..., 0] & 0xFFFF)).reshape(pairs.shape[0], -1)
    bias = np.zeros(pad4(n_out), np.int64)
    bias[:n_out] = b.astype(np.int64) + ((1 << (shift - 1)) if shift else 0)
    return np.concatenate([bias.reshape(-1, 4), words], axis=1).ravel()


def quad_counts(q) -> dict[str, list[int]]:
    """The distinct input-quad counts of the fixed-point layers by role (the C
    instantiates an unrolled Cortex-M4 kernel per count and role)."""
    def counts(layers):
        return sorted({pad4(l.n_in) // 4 for l in layers})

    return {"hidden": counts([l for net in q.phi + q.rho for l in net.layers[:-1]]),
            "phi_hidden": counts([l for net in q.phi for l in net.layers[:-1]]),
            "phi_last": counts([net.layers[-1] for net in q.phi]),
            "rho_last": counts([net.layers[-1] for net in q.rho])}


def _block(items: list[str], per_line: int) -> str:
    lines = ["    " + ", ".join(items[i:i + per_line]) + "," for i in range(0, len(items), per_line)]
    return "\n".join(lines)


def _env() -> jinja2.Environment:
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(templates_dir())), undefined=jinja2.StrictUndefined,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
    env.filters["cfloat"] = cfloat
    env.filters["cfloats"] = lambda xs: ", ".join(cfloat(x) for x in np.ravel(xs))
    env.filters["cfloat_block"] = lambda a: _block([cfloat(x) for x in np.ravel(a)], 6)
    env.filters["int_block"] = lambda a: _block([str(int(x)) for x in np.ravel(a)], 12)
    # a type name inside a C comment: the config admits only names that cannot end
    # the comment or splice a line (config.check_name); checked again here
    env.filters["c_comment"] = lambda name: check_name(name, "type name in a generated header")
    return env


def measure_errors(m: ExportModel) -> dict:
    """Measured |fixed - float| (grams) of the C semantics, via the bit-exact references."""
    from .reference import predict_f32, predict_q15

    out = {}
    cases = {"box": dict(max_given=m.max_neighbors, inside=0.8, edge=0.05),
             "typical": dict(max_given=2, inside=1.0, edge=0.0)}
    for name, kw in cases.items():
        q = random_queries(m.cfg, ERROR_QUERIES, seed=4242, **kw)
        if name == "typical":  # flight-like: within 1.5 m of the ground, |v| small
            q.p[:, 2] = np.abs(q.p[:, 2]) % 1.5
            q.v *= np.float32(0.25)
        f, sel = predict_f32(m, q)
        i, _ = predict_q15(m, q)
        ok = sel.status == 0
        err = np.abs(i.astype(np.float64) * 2.0 ** -m.q15.out_frac - f.astype(np.float64))[ok]
        out[name] = {"queries": int(ok.sum()), "max_abs_g": float(err.max()),
                     "mean_abs_g": float(err.mean()), "p99_abs_g": float(np.percentile(err, 99)),
                     "float_range_g": [float(f[ok].min()), float(f[ok].max())],
                     "description": f"{kw} (random_queries seed 4242)"}
    return out


def output_range_g(m: ExportModel) -> list[float]:
    """Grams that the int16 output of ns2_predict_q15 can represent: larger
    predictions saturate here (the float path does not)."""
    scale = 2.0 ** -m.q15.out_frac
    return [-32768 * scale, 32767 * scale]


def check_output_range(m: ExportModel) -> None:
    """The controller limits the learned force to fa_max_N per robot type; that limit
    must lie inside the fixed-point output range, so that a saturated output is
    always clamped by the controller to the same value the float output would be."""
    lo, hi = output_range_g(m)
    for t in m.cfg.robot_types:
        if not has_rigid_body(m.cfg, t):
            continue
        fa_max_g = default_gains(vehicle(m.cfg, t))["fa_max_N"] * 1000.0 / G
        if fa_max_g > min(-lo, hi):
            raise QuantizationError(f"robot type {t}: the controller's fa_max ({fa_max_g:.3g} g) exceeds the "
                                    f"fixed-point output range [{lo:g}, {hi:g}] g (out_frac {m.q15.out_frac})")


def render(m: ExportModel) -> dict[str, str]:
    cfg, q = m.cfg, m.q15
    types = [{"name": n, "ident": c_identifier(n), "index": i, "is_env": i == cfg.env_index}
             for i, n in enumerate(cfg.neighbor_types)]
    lip = m.lipschitz()
    nets, qnets = [], []
    for kind, fnets, qn, names in (("phi", m.phi, q.phi, cfg.neighbor_types), ("rho", m.rho, q.rho, cfg.robot_types)):
        for i, (net, qnet) in enumerate(zip(fnets, qn)):
            base = {"kind": kind, "type_name": names[i], "ident": c_identifier(names[i])}
            nets.append(dict(base, lipschitz=f"{lip[kind][i]:.9g}",
                             dims=[net[0][0].shape[1]] + [w.shape[0] for w, _ in net],
                             layers=[dict(wb=float_layout(w, b), n_in=w.shape[1], n_blocks=pad4(w.shape[0]) // 4)
                                     for w, b in net]))
            qnets.append(dict(base, layers=[dict(wb=fixed_layout(l.w, l.b, l.shift), layer=l,
                                                 n_quads=pad4(l.n_in) // 4, n_blocks=pad4(l.w.shape[0]) // 4)
                                            for l in qnet.layers]))
    ctx = {"version": __version__, "model_hash": m.model_hash, "model_id": "0x" + m.model_hash[:15], "types": types,
           "num_robot_types": cfg.num_robot_types, "num_neighbor_types": len(types),
           "env_index": cfg.env_index, "max_neighbors": m.max_neighbors, "hidden": m.hidden,
           "input_dim": cfg.input_dim, "history_ms": cfg.history_ms,
           "layers": cfg.model["layers"], "max_width": max(max(cfg.phi_dims()), max(cfg.rho_dims())),
           "lipschitz": lip["per_neighbor_input"], "volumes": m.volumes, "boxes": m.boxes,
           "nets": nets, "qnets": qnets, "q": q, "in_scale": q.in_scale,
           "out_scale": 2.0 ** -q.out_frac, "out_range_g": output_range_g(m),
           "min_margin_bits": min(p["margin_bits"] for p in q.proof),
           "quad_counts": quad_counts(q)}
    if all(has_rigid_body(cfg, t) for t in cfg.robot_types):
        ctx["vehicles"] = [vehicle(cfg, t) for t in cfg.robot_types]
        ctx["gains"] = [default_gains(v) for v in ctx["vehicles"]]
    else:
        ctx["vehicles"], ctx["gains"] = [], []
    env = _env()
    return {h: env.get_template(h + ".j2").render(**ctx) for h in HEADERS}


def manifest(m: ExportModel, errors: dict) -> dict:
    cfg, q = m.cfg, m.q15
    meta = m.meta
    return {
        "generator": f"ns2codegen {__version__}",
        "config_file": CONFIG_FILE,
        "model_hash": m.model_hash,
        "data_hash": meta.get("data_hash"),
        "seed": meta.get("seed"),
        "robot_types": cfg.robot_types,
        "neighbor_types": cfg.neighbor_types,
        "vehicles": {n: {k: v for k, v in cfg.vehicle(n).items() if k in VEHICLE_KEYS or k == "vehicle_file"}
                     for n in cfg.robot_types},  # the parameters the labels were made with (Table cfprops / sysid)
        "dims": {"phi": cfg.phi_dims(), "rho": cfg.rho_dims(), "hidden": m.hidden,
                 "max_neighbors": m.max_neighbors, **({"history_ms": cfg.history_ms} if cfg.history_ms else {})},
        "normalization": meta.get("normalization"),
        "lipschitz": m.lipschitz(),
        "interaction_volume": {f"{cfg.robot_types[r]}.{cfg.robot_types[t]}": m.volumes[r, t].tolist()
                               for r in range(cfg.num_robot_types) for t in range(cfg.num_robot_types)},
        "input_box": {cfg.neighbor_types[t]: m.boxes[t].tolist() for t in range(len(cfg.neighbor_types))},
        "q_formats": {
            "scheme": "int16 weights/activations, int32 accumulators, value = int * 2^-frac; "
                      "y = sat16(floor((acc + 2^(shift-1)) / 2^shift)) (round half up); "
                      "inputs sat16(round_half_up(x * 2^in_frac)) after clamping to the input box",
            "in_frac": dict(zip(cfg.neighbor_types, q.in_frac)),
            "phi_out_frac": q.phi_out_frac, "sum_shift": q.sum_shift,
            "rho_in_frac": q.rho_in_frac, "out_frac": q.out_frac,
            "layers": [{k: p[k] for k in ("layer", "f_in", "f_w", "f_out", "shift")} for p in q.proof[:-1]],
        },
        "overflow_proof": {
            "method": "integer interval arithmetic from the input box through every layer; every partial "
                      "sum of a dot product is bounded by |b| + sum |w_i| max|x_i| (+ rounding term)",
            "layers": q.proof,
            "min_margin_bits": min(p["margin_bits"] for p in q.proof),
        },
        "fixed_output_range_g": {
            "value": output_range_g(m),
            "method": "int16 at out_frac fractional bits: ns2_predict_q15 saturates outside this range while the "
                      "float path does not (the output format comes from calibration queries with headroom; the "
                      "interval-arithmetic bound below is far too loose to set it). The controller clamps the "
                      "learned force to fa_max_N, which the export checks lies inside this range, so a saturated "
                      "fixed output gives the same control as the float one",
            "controller_fa_max_g": {t: round(default_gains(vehicle(cfg, t))["fa_max_N"] * 1000.0 / G, 6)
                                    for t in cfg.robot_types if has_rigid_body(cfg, t)}},
        "float_activation_bound": {
            "value": meta["float_activation_bound"],
            "method": "float64 interval arithmetic over the input box with all neighbour slots "
                      "filled; below 1e30 the float path cannot overflow to Inf/NaN"},
        "fixed_vs_float_error_g": errors,
        "training": meta.get("report", {}).get("validation"),
    }


def export(checkpoint: str | Path, out_dir: str | Path) -> dict:
    """Export ``checkpoint`` into ``out_dir``; returns the manifest."""
    try:
        m = from_checkpoint(load_checkpoint(checkpoint))
        check_output_range(m)
    except QuantizationError as e:   # the weights or the vehicle limits: name the checkpoint
        raise QuantizationError(f"checkpoint {checkpoint}: {e}") from None
    files = render(m)
    man = manifest(m, measure_errors(m))
    files[MANIFEST] = json.dumps(man, indent=2, sort_keys=True) + "\n"
    files[CONFIG_FILE] = dump_toml(m.cfg.raw, f"ns2codegen {__version__}: the config of model {m.model_hash}")
    write_folder_set(Path(out_dir), files)
    return man


def export_config(gen_dir: str | Path) -> Config:
    """The config an export folder was made with (its ``ns2_config.toml``)."""
    path = Path(gen_dir) / CONFIG_FILE
    if not path.is_file():
        raise ConfigError(f"{path} not found: {gen_dir} is not an export folder (run `ns2 export` into it)")
    return Config.load(path)
