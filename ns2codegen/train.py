"""Training of the heterogeneous deep set (paper, "Learning Results and Ablation Analysis").

Loss: || rho_I(i)( sum phi_I(j)(x_ij) ) - y_i ||^2 over all robots of all scenarios,
Adam, spectral normalization (eq. sn) after every optimizer step, a seeded
80/20 split by trajectory piece, validation MSE per scenario and overall.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from .config import Config
from .data.dataset import Dataset, DatasetError, split_by_pieces
from .errors import Ns2Error
from .model import VARIANTS, HeteroDeepSet


class TrainingError(Ns2Error, ValueError):
    """Training diverged (a non-finite loss): nothing is written."""


@dataclass
class Batched:
    """A data set as torch tensors, with CSR gather for a batch of sample indices."""

    robot_type: torch.Tensor
    label: torch.Tensor
    offsets: torch.Tensor
    nbr_type: torch.Tensor
    nbr_state: torch.Tensor

    @staticmethod
    def of(ds: Dataset) -> "Batched":
        return Batched(torch.from_numpy(ds.robot_type), torch.from_numpy(ds.label_g),
                       torch.from_numpy(ds.nbr_offsets), torch.from_numpy(ds.nbr_type),
                       torch.from_numpy(ds.nbr_state))

    def to(self, device) -> "Batched":
        return Batched(*(getattr(self, f).to(device) for f in
                         ("robot_type", "label", "offsets", "nbr_type", "nbr_state")))

    def batch(self, idx: torch.Tensor):
        """(robot_type, sample_of, nbr_type, nbr_state, label) for samples ``idx``."""
        start = self.offsets[idx]
        counts = self.offsets[idx + 1] - start
        sample_of = torch.repeat_interleave(torch.arange(idx.numel(), device=idx.device), counts)
        first = torch.cumsum(counts, 0) - counts
        rows = start[sample_of] + torch.arange(int(counts.sum()), device=idx.device) - first[sample_of]
        return (self.robot_type[idx], sample_of, self.nbr_type[rows], self.nbr_state[rows],
                self.label[idx])


def predict(model: HeteroDeepSet, data: Batched, batch_size: int = 8192) -> torch.Tensor:
    out = []
    dev = data.robot_type.device
    with torch.no_grad():
        for s in range(0, data.robot_type.numel(), batch_size):
            rt, so, nt, ns, _ = data.batch(torch.arange(s, min(s + batch_size, data.robot_type.numel()), device=dev))
            out.append(model(rt, so, nt, ns))
    return torch.cat(out) if out else torch.zeros(0, device=dev)


def evaluate(model: HeteroDeepSet, ds: Dataset, device: str = "cpu") -> dict:
    """MSE (g^2) per scenario and overall, plus the label variance for reference."""
    pred = predict(model, Batched.of(ds).to(device)).cpu().numpy().astype(np.float64)
    err = (pred - ds.label_g) ** 2
    per = {}
    for s, name in enumerate(ds.scenario_names):
        m = ds.scenario == s
        if m.any():
            per[name] = float(err[m].mean())
    return {"mse": float(err.mean()) if err.size else float("nan"),
            "label_var": float(np.var(ds.label_g)) if err.size else float("nan"),
            "mse_per_scenario": per, "samples": int(err.size)}


def train(cfg: Config, ds: Dataset, epochs: int | None = None, seed: int | None = None,
          batch_size: int | None = None, lr: float | None = None, progress=None, device: str = "cpu",
          variant: str = "hetero", patience: int | None = None,
          min_delta: float = 0.01, lr_drops: int = 0) -> tuple[HeteroDeepSet, dict]:
    """Train on ``ds``; returns the model (on the CPU) and a report (train/validation
    MSE, timing).  ``device``: torch device of the training ("cpu", "cuda").
    ``variant``: the heterogeneous deep set or an ablation (model.VARIANTS).
    ``patience``: stopping rule, ``epochs`` is then the most: stop when the
    validation MSE has not improved by ``min_delta`` (relative) for ``patience``
    epochs, and keep the best epoch's weights; with ``lr_drops`` = k, the first k
    times that happens the learning rate is halved instead and training goes on
    from the best weights (a plateau schedule), and only the (k+1)-th stops."""
    tr = cfg.train
    epochs = tr["epochs"] if epochs is None else epochs
    seed = tr["seed"] if seed is None else seed
    batch_size = tr["batch_size"] if batch_size is None else batch_size
    lr = tr["lr"] if lr is None else lr
    if list(ds.neighbor_types) != cfg.neighbor_types:
        raise DatasetError(f"data set neighbor_types {ds.neighbor_types} do not match the config's "
                           f"{cfg.neighbor_types}")
    if ds.nbr_state.shape[1] != cfg.input_dim:
        raise DatasetError(f"data set nbr_state has {ds.nbr_state.shape[1]} values per row, the config's phi takes "
                           f"{cfg.input_dim} (model.history_ms {cfg.history_ms})")
    torch.manual_seed(seed)
    val_mask = split_by_pieces(ds, tr["pieces_per_scenario"], tr["validation_fraction"], seed)
    train_ds, val_ds = ds.subset(~val_mask), ds.subset(val_mask)
    if len(train_ds) == 0 or len(val_ds) == 0:
        raise DatasetError(f"data set: {len(ds)} samples give {len(train_ds)} for training and {len(val_ds)} "
                           "for validation; both need at least one")
    if variant not in VARIANTS:
        raise ValueError(f"unknown model variant {variant!r}: {sorted(VARIANTS)}")
    data = Batched.of(train_ds).to(device)
    model = VARIANTS[variant](cfg).to(device)
    model.spectral_normalize_()
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    n = len(train_ds)
    steps = (n + batch_size - 1) // batch_size
    t0 = time.perf_counter()
    history, val_history, best, best_state, best_epoch, since = [], [], float("inf"), None, 0, 0
    drops_done = 0
    for epoch in range(epochs):
        model.train()
        perm = torch.randperm(n, generator=gen).to(device)
        total = 0.0
        for s in range(steps):
            rt, so, nt, ns, y = data.batch(perm[s * batch_size:(s + 1) * batch_size])
            loss = torch.mean((model(rt, so, nt, ns) - y) ** 2)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            model.spectral_normalize_()  # eq. (sn) after every step
            total += float(loss.detach()) * y.numel()
            if progress is not None:
                progress(y.numel())
        history.append(total / max(n, 1))
        if not np.isfinite(history[-1]):
            raise TrainingError(f"training diverged in epoch {epoch + 1} (loss {history[-1]}); lower --lr")
        if patience is not None:
            model.eval()
            val_history.append(evaluate(model, val_ds, device)["mse"])
            if val_history[-1] < best * (1.0 - min_delta):
                best, best_epoch, since = val_history[-1], epoch + 1, 0
                best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
            else:
                since += 1
                if since >= patience:
                    if drops_done >= lr_drops:
                        break
                    drops_done, since = drops_done + 1, 0
                    model.load_state_dict(best_state)
                    for group in opt.param_groups:
                        group["lr"] *= 0.5
    elapsed = time.perf_counter() - t0
    if best_state is not None:
        model.load_state_dict(best_state)
    model = model.to("cpu").eval()
    done = len(history)
    report = {"epochs": done, "seed": seed, "batch_size": batch_size, "lr": lr, "device": str(device),
              "variant": variant, "train_samples": n, "val_samples": len(val_ds), "train_seconds": elapsed,
              "samples_per_second": n * done / elapsed if elapsed > 0 else None,
              "train_mse_history": history,
              "validation": evaluate(model, val_ds)}
    if patience is not None:
        report["stopping"] = {"max_epochs": epochs, "patience": patience, "min_delta": min_delta,
                              "lr_drops": drops_done, "lr_final": opt.param_groups[0]["lr"],
                              "best_epoch": best_epoch, "validation_mse_history": val_history}
    return model, report
