"""`ns2 real ...`: the paper's own flights (the authors' uSD logs of 16 June 2020) to
data sets, models and C checked on them (``make real``, docs/real-flights.md)."""
from __future__ import annotations

import json
from pathlib import Path

import click

from .common import _emit, _json_option, _progress, _quiet_option, main


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
@_quiet_option
@_json_option
def real_data(shared, unpack_dir, out_dir, quiet, as_json):
    """Unpack, align, label, cut and split the collection into data sets (with a report)."""
    from ns2exp.real import build, unpack
    from ns2host.crazyflie import SHARED

    root = unpack(Path(shared) if shared else SHARED / "neural-swarm-data", unpack_dir)
    with _progress(quiet, None, "step", "real data (read, align, label)"):
        rep = build(root, out_dir)
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
    from ns2exp.real import c_in_the_loop, load_queries, selection_mismatches

    q = load_queries(Path(data_dir) / "heldout_queries.npz")
    labels = Dataset.load(Path(data_dir) / "heldout.npz").label_g
    res = c_in_the_loop(gen_dir, checkpoint, q, labels)
    every = Path(data_dir) / "all_queries.npz"
    if every.is_file():   # issue 29: the selection of every sample of the collection against the C
        res["selection_all_flights"] = selection_mismatches(gen_dir, load_queries(every),
                                                            Dataset.load(Path(data_dir) / "all.npz"))
    if out:
        atomic_write_bytes(Path(out), json.dumps(res, indent=1).encode())
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
    from ns2exp.real import score

    res = score(checkpoint, data_dir)
    if out:
        atomic_write_bytes(Path(out), json.dumps(res, indent=1).encode())
    _emit(as_json, res, ", ".join(f"{k} {v:.3f} g^2" for k, v in res.items() if k.endswith("_mse")))
