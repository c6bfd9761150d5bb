"""The Neural-Swarm2 authors' published networks as a project ``HeteroDeepSet``.

The authors (aerorobotics/neural-swarm) publish one PyTorch ``state_dict`` per net:
``phi_S``, ``phi_L`` (neighbour types small and large), ``phi_G`` (the ground, i.e.
the environment) and ``rho_S``, ``rho_L`` (robot types), each a ReLU MLP with layers
``fc1`` ... ``fcL`` (``fcK.weight`` [out, in], ``fcK.bias`` [out]), eq. (learningmodel-hetero):

    f_a,z(i) = rho_I(i)( phi_G(x_iG) + sum_j phi_I(j)(x_ij) )      (grams)

Input conventions (established from the tensors, the authors' export C and the
logged on-board predictions, docs/real-flights.md):
  * robot neighbour j of robot i: x_ij = [p_j - p_i; v_j - v_i] (m, m/s, world frame),
    the project's convention;
  * ground: phi_G takes 4 inputs, [-z_i, -vx_i, -vy_i, -vz_i] (the ground is a neighbour
    at rest at z = 0 whose x and y do not matter); the project's environment input is
    [-p_i; -v_i], so phi_G becomes the environment phi with zero weights for -x_i, -y_i
    (x * 0 adds exactly 0: the same float result as the 4-input net);
  * a set without phi_G (the 2019 nets) gets an environment phi that is exactly 0.
The weights are carried unchanged (float32; float64 files are rounded to float32 once):
nothing is spectrally normalized (the project normalizes only while training).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import torch

from ns2codegen.config import Config, ConfigError
from ns2codegen.model import HeteroDeepSet, lipschitz_bound
from ns2codegen.errors import Ns2Error

# the authors' file stem -> (kind, project type name); environment last, as in Config
NETS = {"phi_S": ("phi", "small"), "phi_L": ("phi", "large"), "phi_G": ("phi", "env"),
        "rho_S": ("rho", "small"), "rho_L": ("rho", "large")}
GROUND_INPUTS = {4: [2, 3, 4, 5], 6: [0, 1, 2, 3, 4, 5]}  # phi_G width -> columns of [-p; -v]
_KEY = re.compile(r"^(.*?)(\d+)\.(weight|bias)$")


class AuthorsModelError(Ns2Error, ValueError):
    """A published network file that cannot be used (missing, not a state_dict, inconsistent)."""


def load_net(path: str | Path) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """[(W [out, in], b [out])] of one published MLP, in layer order, as stored."""
    path = Path(path)
    if not path.is_file():
        raise AuthorsModelError(f"{path}: network file not found")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a pickled nn.Module, garbage, a cut zip file
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise AuthorsModelError(f"{path}: not a loadable state_dict of tensors ({first}); a pickled "
                                f"module must be re-saved as its state_dict") from e
    if not isinstance(obj, dict) or not obj or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise AuthorsModelError(f"{path}: expected a state_dict of tensors, got {type(obj).__name__}")
    layers: dict[int, dict[str, torch.Tensor]] = {}
    for key, t in obj.items():
        m = _KEY.match(key)
        if not m:
            raise AuthorsModelError(f"{path}: unexpected entry {key!r} (expected <name><k>.weight/.bias)")
        layers.setdefault(int(m.group(2)), {})[m.group(3)] = t
    net, width = [], None
    for k in sorted(layers):
        w, b = layers[k].get("weight"), layers[k].get("bias")
        if w is None or b is None or w.dim() != 2 or b.dim() != 1 or b.shape[0] != w.shape[0]:
            raise AuthorsModelError(f"{path}: layer {k} needs weight [out, in] and bias [out]")
        if width is not None and w.shape[1] != width:
            raise AuthorsModelError(f"{path}: layer {k} takes {w.shape[1]} inputs, the previous layer gives {width}")
        if not w.is_floating_point() or not b.is_floating_point():
            raise AuthorsModelError(f"{path}: layer {k} is not floating point ({w.dtype})")
        if not (torch.isfinite(w).all() and torch.isfinite(b).all()):
            raise AuthorsModelError(f"{path}: layer {k} contains NaN or Inf")
        width = w.shape[0]
        net.append((w, b))
    return net


def _dims(net) -> list[int]:
    return [net[0][0].shape[1]] + [w.shape[0] for w, _ in net]


def load_authors(models_dir: str | Path, suffix: str = "", base: Config | None = None):
    """(HeteroDeepSet, Config, meta) carrying the published nets of ``models_dir``
    (files ``phi_S<suffix>.pth`` ...; ``phi_G`` optional).  ``base`` gives the vehicle
    parameters, boxes and interaction volumes (default: the package's default.toml)."""
    folder = Path(models_dir)
    if not folder.is_dir():
        raise AuthorsModelError(f"{folder}: not a folder of published networks")
    nets = {}
    for stem in NETS:
        path = folder / f"{stem}{suffix}.pth"
        if stem == "phi_G" and not path.exists():
            continue
        nets[stem] = load_net(path)
    dims = {stem: _dims(net) for stem, net in nets.items()}
    phi, rho = dims["phi_S"], dims["rho_S"]
    for stem, d in dims.items():
        path = folder / f"{stem}{suffix}.pth"
        if stem.startswith("rho") and (d != rho or d[-1] != 1):
            raise AuthorsModelError(f"{path}: layers {d}, expected {rho} ending in 1 output (as rho_S)")
        if stem in ("phi_S", "phi_L") and (d != phi or d[0] != 6):
            raise AuthorsModelError(f"{path}: layers {d}, expected {phi} with 6 inputs (as phi_S)")
        if stem == "phi_G" and (d[1:] != phi[1:] or d[0] not in GROUND_INPUTS):
            raise AuthorsModelError(f"{path}: layers {d}, expected 4 or 6 inputs then {phi[1:]}")
    if phi[-1] != rho[0]:
        raise AuthorsModelError(f"{folder}: phi gives {phi[-1]} latent dimensions, rho takes {rho[0]}")
    if len(phi) != len(rho) or len(phi) < 4 or len(set(phi[2:-1] + rho[1:-1])) != 1:
        raise AuthorsModelError(f"{folder}: phi {phi} and rho {rho} are not the project's shape "
                                f"(6-a-w..w-H and H-w..w-1, with L layers each)")

    raw = (base or Config.load()).raw
    raw = {**raw, "model": dict(raw["model"], hidden=phi[-1], layers=len(phi) - 1, phi_first=phi[1], width=phi[2])}
    lips = [lipschitz_bound([w.double() for w, _ in net]) for net in nets.values()]
    if not all(math.isfinite(x) for x in lips):
        raise AuthorsModelError(f"{folder}: weights too large (a Lipschitz bound overflows)")
    raw["model"]["gamma"] = math.ceil(max(lips) * 10) / 10  # recorded only: never applied to these weights
    names = [t["name"] for t in raw["robot_types"]]
    if names != ["small", "large"]:
        raise AuthorsModelError(f"the authors' nets are for robot types ['small', 'large'], the config has {names}")
    try:
        cfg = Config.from_dict(raw)
    except ConfigError as e:
        raise AuthorsModelError(f"{folder}: {e}") from None

    model = HeteroDeepSet(cfg)
    index = {"small": 0, "large": 1, "env": cfg.env_index}
    sd = {k: torch.zeros_like(v) for k, v in model.state_dict().items()}
    for stem, net in nets.items():
        kind, name = NETS[stem]
        for l, (w, b) in enumerate(net):
            w = w.to(torch.float32)
            if stem == "phi_G" and l == 0:
                full = torch.zeros((w.shape[0], 6), dtype=torch.float32)
                full[:, GROUND_INPUTS[w.shape[1]]] = w
                w = full
            sd[f"{kind}.{index[name]}.layers.{l}.weight"] = w.clone()
            sd[f"{kind}.{index[name]}.layers.{l}.bias"] = b.to(torch.float32).clone()
    model.load_state_dict(sd)
    model.eval()
    ground = "phi_G" in nets
    meta = {"source": "authors", "models_dir": str(folder), "suffix": suffix,
            "files": {stem: f"{stem}{suffix}.pth" for stem in nets},
            "dtype": sorted({str(w.dtype).removeprefix("torch.") for net in nets.values() for w, _ in net}),
            "phi_dims": phi, "rho_dims": rho,
            "ground": ({"inputs": dims["phi_G"][0],
                        "columns_of_env_input": GROUND_INPUTS[dims["phi_G"][0]]} if ground else None),
            "lipschitz_per_net": {stem: lip for stem, lip in zip(nets, lips)},
            "assumptions": [
                "robot neighbour input x_ij = [p_j - p_i; v_j - v_i] in m and m/s (world frame)",
                "phi_G input [-z_i, -vx_i, -vy_i, -vz_i] (the 4-input net) = environment input [-p_i; -v_i] "
                "without -x_i, -y_i" if ground else "no phi_G: the environment contributes exactly 0",
                "output f_a,z in grams; no input or output scaling",
                "vehicle parameters, boxes and interaction volumes from the base config, not from the authors"]}
    return model, cfg, meta
