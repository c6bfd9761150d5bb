"""`ns2 real ...`: the paper's own flights (the authors' uSD logs of 16 June 2020) to
data sets, models and C checked on them (``make real``, docs/real-flights.md)."""
from __future__ import annotations

import json
from pathlib import Path

import click

from .common import _config_option, _emit, _json_option, _parent_ok, _progress, _quiet_option, main


@main.group()
def real():
    """The Neural-Swarm2 authors' real Crazyflie flights: data, models, C on real data."""


@real.command("data")
@click.option("--shared", type=click.Path(file_okay=False), default=None,
              help="folder with the three tarballs [default: ../shared/neural-swarm-data beside the checkout]")
@click.option("--unpack-dir", type=click.Path(file_okay=False), default="build/neural-swarm-data", show_default=True,
              help="where the logs are unpacked (once) and flights.toml written")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="build/real", show_default=True,
              help="data sets (all, train, heldout .npz), held-out queries, real.toml, data_report.json")
@click.option("--history-ms", default="", show_default=True,
              help="comma list of lags (ms): every neighbour row also holds its state that long ago "
                   "(model.history_ms, the wake memory; the held-out queries carry the lags for check-c)")
@_quiet_option
@_json_option
def real_data(shared, unpack_dir, out_dir, history_ms, quiet, as_json):
    """Unpack, align, label, cut and split the collections into data sets (with a report)."""
    import copy

    from ns2codegen.config import Config, ConfigError
    from ns2exp.real import build, unpack
    from ns2host.crazyflie import SHARED

    cfg = Config.load(None)
    if history_ms:
        raw = copy.deepcopy(cfg.raw)
        try:
            raw["model"]["history_ms"] = [int(x) for x in history_ms.split(",")]
        except ValueError:
            raise ConfigError(f"--history-ms: a comma list of integers (ms), got {history_ms!r}") from None
        cfg = Config.from_dict(raw)
    root = unpack(Path(shared) if shared else SHARED / "neural-swarm-data", unpack_dir)
    with _progress(quiet, None, "step", "real data (read, align, label)"):
        rep = build(root, out_dir, cfg)
    summary = {k: rep[k] for k in ("data_sets", "masses_g", "alignment", "cuts")}
    _emit(as_json, summary, f"wrote {out_dir}: " + ", ".join(f"{k} {v['samples']} samples / {v['flights']} flights"
                                                           for k, v in rep["data_sets"].items())
          + f"; masses from hover {rep['masses_g']} g; report {Path(out_dir) / 'data_report.json'}")


@real.command("check-c")
@click.option("--gen", "gen_dir", type=click.Path(file_okay=False), required=True, help="export folder of the model")
@click.option("--checkpoint", type=click.Path(dir_okay=False), required=True, help="the checkpoint it was exported from")
@click.option("--data-dir", type=click.Path(file_okay=False), default="build/real", show_default=True,
              help="output folder of `ns2 real data` (heldout_queries.npz, heldout.npz)")
@click.option("--out", type=click.Path(dir_okay=False), default=None, help="write the result as JSON there too")
@_json_option
def real_check_c(gen_dir, checkpoint, data_dir, out, as_json):
    """Every held-out real sample through the exported C, float and fixed, against the references."""
    from ns2codegen.data.dataset import Dataset
    from ns2codegen.fileio import atomic_write_bytes
    from ns2codegen.export import export_config
    from ns2codegen.results import stamp
    from ns2exp.real import c_in_the_loop, load_queries, same_history, selection_mismatches

    q = load_queries(Path(data_dir) / "heldout_queries.npz")
    same_history(q, export_config(gen_dir), Path(data_dir) / "heldout_queries.npz")
    labels = Dataset.load(Path(data_dir) / "heldout.npz").label_g
    res = c_in_the_loop(gen_dir, checkpoint, q, labels)
    res["history_ms"] = export_config(gen_dir).history_ms
    every = Path(data_dir) / "all_queries.npz"
    if every.is_file():   # issue 29: the selection of every sample of the collection against the C
        res["selection_all_flights"] = selection_mismatches(gen_dir, load_queries(every),
                                                            Dataset.load(Path(data_dir) / "all.npz"))
    if out:
        atomic_write_bytes(Path(out), json.dumps(stamp(res), indent=1).encode())
    _emit(as_json, res, f"{res['samples']} held-out samples: float C {res['float_mismatches']} and fixed C "
          f"{res['fixed_mismatches']} differ from the references; |fixed - float| max "
          f"{res['abs_fixed_minus_float_g']['max']:.4f} g; labels {res['label_range_g']} g inside the fixed range "
          f"{res['fixed_output_range_g']} g: {res['labels_inside_fixed_range']}")


@real.command("report")
@click.option("--dir", "out_dir", type=click.Path(file_okay=False), default="build/real", show_default=True,
              help="output folder of `make real`")
@click.option("--checkpoint", type=click.Path(dir_okay=False), required=True,
              help="the model plotted (trained without the held-out flights)")
@click.option("--unpack-dir", type=click.Path(file_okay=False), default="build/neural-swarm-data", show_default=True,
              help="where `ns2 real data` unpacked the logs")
@_json_option
def real_report(out_dir, checkpoint, unpack_dir, as_json):
    """Tables (summary.md, summary.json) and plots of a `make real` run."""
    from ns2exp.real import plots, summary

    res = summary(out_dir)
    paths = plots(out_dir, checkpoint, unpack_dir)
    _emit(as_json, dict(res, plots=[str(p) for p in paths]), res["table_md"] + "\n\nplots: " + ", ".join(map(str, paths)))


@real.command("score")
@click.option("--checkpoint", type=click.Path(dir_okay=False), required=True, help="the model scored")
@click.option("--data-dir", type=click.Path(file_okay=False), default="build/real", show_default=True,
              help="output folder of `ns2 real data`")
@click.option("--out", type=click.Path(dir_okay=False), default=None, help="write the result as JSON there too")
@_json_option
def real_score(checkpoint, data_dir, out, as_json):
    """MSE of a model on every flight and on the held-out flights (both label conventions)."""
    from ns2codegen.fileio import atomic_write_bytes
    from ns2codegen.results import stamp
    from ns2exp.real import score

    res = score(checkpoint, data_dir)
    if out:
        atomic_write_bytes(Path(out), json.dumps(stamp(res), indent=1).encode())
    _emit(as_json, res, ", ".join(f"{k} {v:.3f} g^2" for k, v in res.items() if k.endswith("_mse")))


@real.command("blind")
@click.option("--dir", "out_dir", type=click.Path(file_okay=False), default="build/real", show_default=True,
              help="output folder of `make real` (c-<collection>.npz, loco-<collection>/, heldout/)")
@click.option("--authors", type=click.Path(dir_okay=False), default=None,
              help="the authors' published network (`ns2 real import-authors`): scored beside ours (a training score)")
@click.option("--seeds", type=int, default=3, show_default=True, help="networks per split scored (mean +- std)")
@click.option("--collection", "collections", multiple=True,
              help="score only these blind splits: a collection left out, or heldout for the held-out flights (repeat; default every one)")
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="JSON (and a .md table beside it)")
@_json_option
def real_blind(out_dir, authors, seeds, collections, out, as_json):
    """Blind scores: each collection scored by the networks trained without it, the held-out
    flights by those trained without them, beside the on-board prediction flown on 16 June
    2020, the authors' network and zero; overall, in the wake, per scenario; plain and
    mass-neutral; both mass conventions."""
    from ns2exp.blind import blind, table, write

    _parent_ok(out)
    res = blind(out_dir, authors, seeds, collections or None)
    write(res, Path(out))
    _emit(as_json, res, table(res))


@real.command("adapt")
@click.option("--dir", "out_dir", type=click.Path(file_okay=False), default="build/real", show_default=True,
              help="output folder of `make real` (heldout/, loco-<collection>/, the data sets and their samples)")
@click.option("--gen", "gen_dir", type=click.Path(file_okay=False), required=True,
              help="an export (`ns2 export`): its host build runs the adaptation's C (any network)")
@click.option("--unpack-dir", type=click.Path(file_okay=False), default="build/neural-swarm-data", show_default=True,
              help="the unpacked logs (`ns2 real data`): the sensors the on-board label is computed from")
@click.option("--seeds", type=int, default=3, show_default=True, help="networks per split")
@click.option("--collection", "collections", multiple=True,
              help="only these collections left out (repeat; default every one)")
@click.option("--no-held-out", is_flag=True, help="skip the held-out flights (and so the laws chosen on them)")
@click.option("--choose-on", default=None,
              help="with --no-held-out: the collection left out the laws are chosen on (and the 3 g test made)")
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="JSON (and a .md table beside it)")
@_quiet_option
@_json_option
def real_adapt(out_dir, gen_dir, unpack_dir, seeds, collections, no_held_out, choose_on, out, quiet, as_json):
    """On-board adaptation judged on the blind splits (issue 53 item 4): every robot's flight
    through the host C's label and adaptation, static against adapted MSE; the laws tried
    on the held-out flights, the chosen ones judged on the collections left out; the 3 g test."""
    from ns2exp.adaptation import adaptation, tables, write

    _parent_ok(out)
    if choose_on and not no_held_out:
        raise click.UsageError("--choose-on needs --no-held-out (the laws are chosen on the held-out flights)")
    res = adaptation(out_dir, gen_dir, unpack_dir, seeds, collections or None, not no_held_out, choose_on,
                     progress=None if quiet else (lambda msg: click.echo(msg, err=True)))
    write(res, Path(out))
    _emit(as_json, res, tables(res))


@real.command("memory")
@click.option("--now", "now_path", type=click.Path(dir_okay=False), required=True,
              help="`ns2 real blind` JSON of the networks of the present state")
@click.option("--past", "past_path", type=click.Path(dir_okay=False), required=True,
              help="`ns2 real blind` JSON of the networks that also see the neighbours' past (model.history_ms)")
@click.option("--lags", default="50,100,200", show_default=True, help="the lags of --past (ms), for the table")
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="JSON (and a .md table beside it)")
@_json_option
def real_memory(now_path, past_path, lags, out, as_json):
    """Does the wake have a memory? The blind scores with and without the neighbours' past states."""
    from ns2codegen.fileio import atomic_write_bytes
    from ns2codegen.results import stamp
    from ns2exp.blind import memory, memory_table

    _parent_ok(out)
    try:
        lags_ms = [int(x) for x in lags.split(",")]
    except ValueError:
        raise click.BadParameter(f"{lags!r}: comma-separated whole milliseconds", param_hint="--lags") from None
    try:
        now, past = (json.loads(Path(p).read_text()) for p in (now_path, past_path))
        rows = memory(now, past)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise click.ClickException(f"{now_path}, {past_path}: not two `ns2 real blind` results ({e})") from None
    md = memory_table(rows, lags)
    doc = stamp(dict(rows, lags_ms=lags_ms))
    atomic_write_bytes(Path(out), json.dumps(doc, indent=1, sort_keys=True).encode())
    atomic_write_bytes(Path(out).with_suffix(".md"), (md + "\n").encode())
    _emit(as_json, rows, md)


@real.command("import-authors")
@click.argument("models_dir", type=click.Path(file_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="project checkpoint to write (.pt)")
@click.option("--suffix", default="", show_default=True,
              help="file name suffix of the set (the 2019 folder also holds phi_S_rw.pth ...: --suffix _rw)")
@_config_option
@_json_option
def import_authors(models_dir, out, suffix, config_path, as_json):
    """Load the published phi_S/phi_L/phi_G/rho_S/rho_L.pth of MODELS_DIR into the project's
    deep set, unchanged, and save it as a checkpoint that `ns2 export` exports."""
    from ns2paper.authors import load_authors
    from ns2codegen.checkpoint import save_checkpoint
    from ns2codegen.config import Config

    _parent_ok(out)
    model, cfg, meta = load_authors(models_dir, suffix, Config.load(config_path))
    save_checkpoint(out, model, cfg, {"seed": None, "data_hash": None, "authors": meta})
    result = {"checkpoint": out, "phi_dims": meta["phi_dims"], "rho_dims": meta["rho_dims"],
              "ground": meta["ground"], "files": meta["files"], "assumptions": meta["assumptions"]}
    ground = (f"phi_G with {meta['ground']['inputs']} inputs -> environment columns "
              f"{meta['ground']['columns_of_env_input']}" if meta["ground"] else "no phi_G: environment phi = 0")
    _emit(as_json, result, f"wrote {out}: phi {meta['phi_dims']}, rho {meta['rho_dims']}, {ground}")


@real.command("authors-faz")
@click.argument("checkpoint", type=click.Path(dir_okay=False))
@click.option("--data", "data_dir", type=click.Path(file_okay=False), default=None,
              help="folder of the 16 June 2020 collection [default: unpacked by `ns2 real data` from "
                   "../shared/neural-swarm-data into build/neural-swarm-data]")
@click.option("--out", type=click.Path(dir_okay=False), default=None, help="also write the result as JSON here")
@_json_option
def authors_faz(checkpoint, data_dir, out, as_json):
    """Recompute the logged on-board ctrlFa.Faz of every flight with CHECKPOINT's network
    (with and without the ground input) and report rms / max error per scenario and robot type."""
    from ns2codegen.checkpoint import load_checkpoint
    from ns2codegen.fileio import atomic_write_bytes
    from ns2paper.collection import COLLECTION
    from ns2exp.onboard_faz import reproduce
    from ns2exp.real import unpack
    from ns2host.crazyflie import SHARED

    if data_dir is None:
        data_dir = str(unpack(SHARED / "neural-swarm-data", "build/neural-swarm-data") / COLLECTION)
    model = load_checkpoint(checkpoint).model()
    result = {"checkpoint": checkpoint, "data": str(data_dir),
              "with_ground": reproduce(model, data_dir, ground=True),
              "without_ground": reproduce(model, data_dir, ground=False)}
    if out:
        _parent_ok(out)
        atomic_write_bytes(Path(out), (json.dumps(result, indent=1, sort_keys=True) + "\n").encode())
    lines = []
    for key in ("with_ground", "without_ground"):
        r = result[key]
        lines.append(f"{key.replace('_', ' ')}: " + ", ".join(
            f"{k} rms {v['rms_g']:.2f} g, max {v['max_abs_g']:.1f} g, mean {v['mean_g']:+.2f} g, corr {v['corr']:.3f}, "
            f"Faz ~ {v['fit_slope']:.3f} x prediction {v['fit_offset_g']:+.2f} g" for k, v in r["overall"].items()))
        for name, d in r["per_scenario"].items():
            lines.append(f"  {name:15s} " + "  ".join(
                f"{k}: rms {v['rms_g']:5.2f} max {v['max_abs_g']:5.1f} (|Faz| rms {v['faz_rms_g']:.2f}, "
                f"{v['samples']} samples)" for k, v in d.items()))
    _emit(as_json, result, "\n".join(lines))
