"""The app in the Crazyflie's 1 kHz stabilizer loop (JSON on stdout): the worst 1 ms
iteration of the firmware's own Kalman estimator (kalman_core, 100 Hz prediction and
a mocap position measurement in the same tick) with its stock PID controller and with
the ns2 app's out-of-tree controller (ns2_pilot_step: begin + position, phi slices,
finish, attitude, spread over the milliseconds of its 100 Hz period), over every phase
of the estimator's costly tick against that period; all compiled from the
crazyflie-firmware tarball and counted on the emulated Cortex-M4 with
ns2host/cm4_count.py's cost model (the same as bench_target.py), at zero wait states and
on its memory-system model.  Fixed point (the default app) and float; 15 peers broadcast
by mocap at 100 Hz, 4 positions per packet and millisecond, all of them in the app's table.
With the on-board adaptation on (issue 53, "<infer>_adaptation"): the stabilizer with
ns2adapt.enable = 1 (in the ring every tick is a wake: no update), and as an upper bound
that plus one whole label-and-update step (budget.adapt_runs) in the position tick, where it runs;
the issue's budget: at most 10 % of 1 ms added to the stock worst tick.  The network is
the export's (--gen; its ns2_config.toml): with wake memory (model.history_ms) the app keeps
its peers' and its own past and runs 6 (1 + lags) inputs per neighbour.

    python benchmarks/bench_stabilizer.py [--gen firmware/generated]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from ns2codegen.export import export_config
from ns2codegen.results import stamp
from ns2host import crazyflie, stabilizer, target
from ns2host.cbuild import REPO

def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gen", default=None,
                    help="export folder (default: firmware/generated, else a freshly trained default model)")
    args = ap.parse_args()
    if not target.have_toolchain():
        sys.exit("arm-none-eabi-gcc missing: run scripts/install-deps.sh")
    try:
        crazyflie.firmware_dir()
    except crazyflie.FirmwareMissing as e:
        sys.exit(str(e))
    with tempfile.TemporaryDirectory() as tmp:
        gen = Path(args.gen) if args.gen else REPO / "firmware" / "generated"
        if not (gen / "ns2_model_config.h").is_file():
            sys.path.insert(0, str(Path(__file__).parent))
            from bench_target import default_export

            gen = default_export(Path(tmp))
        cfg = export_config(gen)
        result = {"network": {"phi": cfg.phi_dims(), "rho": cfg.rho_dims(), "history_ms": cfg.history_ms,
                              "input_dim": cfg.input_dim},
                  "cost_model": "ns2host/cm4_count.py (Cortex-M4 TRM cycle counts; zero_wait: no wait "
                                "states, memory: STM32F405_168MHZ, flash wait states and ART accelerator)",
                  "loop": "stabilizer at RATE_MAIN_LOOP = 1000 Hz, 168 MHz",
                  **{infer: stabilizer.iteration(gen, 15, infer) for infer in ("fixed", "float")},
                  **{f"{infer}_adaptation": stabilizer.with_adaptation(gen, 15, infer) for infer in ("fixed", "float")}}
    print(json.dumps(stamp(result), indent=2))


if __name__ == "__main__":
    main()
