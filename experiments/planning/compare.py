"""python -m ns2exp.planning.compare CHECKPOINT... --flights CACHE.npz...: the margin
and the error on the held-out flights per checkpoint (ns2exp.margin), measured over
the experiments' 3-D limits (markdown on stdout; --json FILE too)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from ns2codegen.config import Config
from ns2codegen.fileio import atomic_write_bytes
from ns2plan.forces import load_force_model

from ..margin import compare_table, load_flights, margin_table, measure
from .cases import LIMITS_3D


def main(argv=None) -> None:
    """The margin and the error on the held-out flights per checkpoint."""
    ap = argparse.ArgumentParser(prog="python -m ns2exp.planning.compare", description=__doc__)
    ap.add_argument("checkpoints", nargs="+")
    ap.add_argument("--flights", action="append", required=True, help="held_out_flights cache (.npz), repeatable")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    cfg = Config.load()
    flights = [fl for path in a.flights for fl in load_flights(path)[0]]
    names = [Path(c).parent.name or c for c in a.checkpoints]
    names = names if len(set(names)) == len(names) else list(a.checkpoints)    # one folder: the paths
    reports = {n: measure(cfg, load_force_model(cfg, c), flights, LIMITS_3D)
               for n, c in zip(names, a.checkpoints)}
    for name, rep in reports.items():
        print(f"## {name}\n\n{margin_table(rep)}\n")
    print(compare_table(reports))
    if a.json:
        atomic_write_bytes(Path(a.json), (json.dumps(reports, indent=1, default=float) + "\n").encode())


if __name__ == "__main__":
    main()
