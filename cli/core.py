"""`ns2 gen-data`, `ns2 train`, `ns2 export`: data set, model, C headers."""
from __future__ import annotations

from pathlib import Path

import click

from ns2codegen.config import ONBOARD_WIDTHS

from .common import (
    _config, _config_option, _emit, _json_option, _parent_ok, _progress,
    _quiet_option, _vehicle_option, main,
)


@main.command("gen-data")
@click.option("--kind", type=click.Choice(["downwash", "max"]), default="downwash", show_default=True,
              help="analytic downwash + ground effect, or the paper's 2-group max example")
@click.option("--samples-per-scenario", type=click.IntRange(min=1), default=2000, show_default=True,
              help="samples drawn per scenario (team and flight pattern)")
@click.option("--seed", type=int, default=0, show_default=True, help="random seed (same seed, same data set)")
@click.option("--noise", type=click.FloatRange(min=0.0), default=0.0, show_default=True,
              help="label noise std (g)")
@_config_option
@click.option("--out", type=click.Path(dir_okay=False), required=True, help="data set to write (.npz)")
@_json_option
def gen_data(kind, samples_per_scenario, seed, noise, config_path, out, as_json):
    """Generate an analytic training data set (.npz, format in docs/training.md)."""
    from ns2codegen.data import analytic

    cfg = _config(config_path)
    if kind == "downwash":
        ds = analytic.downwash_dataset(cfg, samples_per_scenario, seed=seed, noise_g=noise)
    else:
        ds = analytic.max_dataset(cfg, samples_per_scenario, seed=seed)
    _parent_ok(out)
    ds.save(out)
    _emit(as_json, {"out": out, "samples": len(ds), "scenarios": ds.scenario_names},
          f"wrote {out}: {len(ds)} samples, {len(ds.scenario_names)} scenarios")


@main.command()
@click.option("--data", "data_paths", type=click.Path(dir_okay=False), required=True, multiple=True,
              help="data set (.npz); repeat to train on several (e.g. curriculum rounds)")
@_config_option
@click.option("--out", type=click.Path(dir_okay=False), required=True,
              help="checkpoint to write (.pt; it carries the config)")
@click.option("--epochs", type=click.IntRange(min=1), default=None, help="training epochs [default: config train.epochs]")
@click.option("--seed", type=int, default=None, help="random seed [default: config train.seed]")
@click.option("--batch-size", type=click.IntRange(min=1), default=None,
              help="mini-batch size [default: config train.batch_size]")
@click.option("--lr", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="Adam learning rate [default: config train.lr]")
@click.option("--hidden", type=click.IntRange(min=1), default=None, help="H (overrides config)")
@click.option("--layers", type=click.IntRange(min=2), default=None, help="L (overrides config)")
@click.option("--width", type=click.IntRange(min=1), default=None,
              help="intermediate layer width (overrides config; paper 40)")
@click.option("--phi-first", type=click.IntRange(min=1), default=None,
              help="width of phi's first hidden layer (overrides config; paper 25)")
@click.option("--onboard", is_flag=True,
              help="the one-tick on-board variant: intermediate widths 24, phi's first layer 16")
@click.option("--device", default="cpu", show_default=True,
              help="torch device to train on: cpu, cuda, cuda:1 ... (the checkpoint is the same format)")
@_vehicle_option
@_quiet_option
@_json_option
def train(data_paths, config_path, out, epochs, seed, batch_size, lr, hidden, layers, width, phi_first, onboard,
          device, vehicle_files, quiet, as_json):
    """Train the heterogeneous deep set; writes a checkpoint and reports the validation error."""
    from ns2codegen.checkpoint import save_checkpoint
    from ns2codegen.data.dataset import Dataset
    from ns2codegen.train import train as run

    import torch

    try:
        torch.empty(0, device=device)
    except (RuntimeError, ValueError, AssertionError) as e:   # AssertionError: torch built without CUDA
        raise click.BadParameter(f"{device!r} is not usable here ({str(e).splitlines()[0]})",
                                 param_hint="--device") from None
    cfg = _config(config_path, vehicle_files)
    overrides = dict(ONBOARD_WIDTHS) if onboard else {}
    overrides.update({k: v for k, v in (("hidden", hidden), ("layers", layers), ("width", width),
                                        ("phi_first", phi_first)) if v is not None})
    if overrides:
        cfg = cfg.with_overrides(**overrides)
    ds = Dataset.concat([Dataset.load(p, cfg.neighbor_types) for p in data_paths])
    _parent_ok(out)
    n_epochs = epochs or cfg.train["epochs"]
    total = int(len(ds) * (1 - cfg.train["validation_fraction"])) * n_epochs
    with _progress(quiet, total, "sample", "train") as update:
        model, report = run(cfg, ds, epochs=epochs, seed=seed, batch_size=batch_size, lr=lr, progress=update,
                            device=device)
    save_checkpoint(out, model, cfg, {"seed": report["seed"], "data_hash": ds.content_hash(),
                                      "data_files": [Path(p).name for p in data_paths], "report": report})
    v = report["validation"]
    result = {"checkpoint": out, "validation_mse": v["mse"], "label_variance": v["label_var"],
              "mse_per_scenario": v["mse_per_scenario"], "samples_per_second": report["samples_per_second"]}
    _emit(as_json, result,
          f"wrote {out}: validation MSE {v['mse']:.4g} g^2 (label variance {v['label_var']:.4g} g^2), "
          f"{report['samples_per_second']:.0f} samples/s\n"
          + "\n".join(f"  {name}: MSE {mse:.4g} g^2" for name, mse in v["mse_per_scenario"].items()))


@main.command()
@click.argument("checkpoint", type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="firmware/generated",
              show_default=True, help="export folder: C headers, manifest and the model's config")
@_quiet_option
@_json_option
def export(checkpoint, out_dir, quiet, as_json):
    """Export CHECKPOINT (.pt) to C headers (float + fixed point), a manifest and its config."""
    from ns2codegen.export import export as run

    with _progress(quiet, None, "step", "export (quantize, prove, measure)"):
        man = run(checkpoint, out_dir)
    err = man["fixed_vs_float_error_g"]
    result = {"out": out_dir, "model_hash": man["model_hash"], "lipschitz": man["lipschitz"]["per_neighbor_input"],
              "overflow_min_margin_bits": man["overflow_proof"]["min_margin_bits"],
              "fixed_vs_float_max_abs_g": {k: err[k]["max_abs_g"] for k in ("box", "typical")}}
    _emit(as_json, result,
          f"wrote {out_dir}: model {man['model_hash'][:16]}, Lipschitz bound "
          f"{man['lipschitz']['per_neighbor_input']:.4g} g per unit input, overflow margin "
          f"{man['overflow_proof']['min_margin_bits']} bits, |fixed-float| max "
          f"{err['box']['max_abs_g']:.3g} g (box), {err['typical']['max_abs_g']:.3g} g (typical)")
