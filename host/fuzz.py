"""Structured fuzzing of the firmware library under ASan + UBSan (fuzz/ns2_fuzz.c).

The very sources of firmware/flags.mk (inference, sliced API, peer table,
controller, label and adaptation, the app's per-tick ns2_pilot) and the HIL
parser are compiled with gcc
``-fsanitize=address,undefined,float-cast-overflow -fno-sanitize-recover=all``
against the headers of one export folder, together with the driver.  Each target
runs COUNT structured inputs from a fixed seed; any sanitizer report, failed
contract check or failed recovery check ends the run with a non-zero status.  The
inputs take their width from the export (NS2_INPUT_DIM): a network with wake memory
gets each neighbour's past and the robot's own through the *_hist entry points, the
peer table's history ring and HIL bodies with the past; each target's JSON names
input_dim and predictions_ok (inference reached with status NS2_OK).

    python -m ns2host.fuzz --gen firmware/generated --count 1000000   (make fuzz)
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from .cbuild import BUILD_ROOT, GENERATED, REPO, BuildError, cached, compile_error, content_hash, flags, host_cc

DRIVER = REPO / "fuzz" / "ns2_fuzz.c"
TARGETS = ("infer", "sliced", "peers", "ctrl", "adapt", "pilot", "hil")
# share of the inputs of `--count` per target (cheap targets get more; pilot: one input a millisecond)
SHARE = {"infer": 0.20, "sliced": 0.10, "peers": 0.20, "ctrl": 0.20, "adapt": 0.10, "pilot": 0.10, "hil": 0.10}
SANITIZE = ["-fsanitize=address,undefined,float-cast-overflow", "-fno-sanitize-recover=all",
            "-fno-omit-frame-pointer", "-g", "-O1"]
ENV = {"ASAN_OPTIONS": "abort_on_error=0:halt_on_error=1:detect_leaks=1:exitcode=86",
       "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1:exitcode=87"}


class FuzzFailure(AssertionError):
    """A sanitizer report or a failed check."""


def build(gen_dir: str | Path) -> Path:
    """Compile the driver and the library with the sanitizers (cached by content)."""
    gen_dir = Path(gen_dir).resolve()
    for g in GENERATED + ("ns2_vehicles.h",):
        if not (gen_dir / g).is_file():
            raise BuildError(f"{gen_dir / g} missing: run `ns2 export` first")
    f = flags()
    sources = [REPO / s for s in f["NS2_SOURCES"] + f["NS2_HIL_SOURCES"]] + [DRIVER]
    headers = sorted((REPO / "firmware").glob("*/*.h")) + [gen_dir / g for g in GENERATED + ("ns2_vehicles.h",)]
    cmd_flags = [*f["NS2_STD_FLAGS"], *f["NS2_WARN_FLAGS"], *SANITIZE,
                 *[f"-I{REPO / i}" for i in f["NS2_INCLUDES"]], f"-I{gen_dir}"]
    exe = BUILD_ROOT.parent / "fuzz" / content_hash([repr(cmd_flags), host_cc(), *sources, *headers], 20) / "ns2_fuzz"

    def build_exe(out: Path) -> None:
        cmd = [host_cc(), *cmd_flags, *map(str, sources), "-o", str(out / exe.name), "-lm"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise compile_error("the fuzz driver", cmd, r)

    return cached(exe, build_exe, product=None)


def run(exe: Path, target: str, count: int, seed: int) -> dict:
    """Run one target; returns its JSON line plus the time, or raises FuzzFailure."""
    t0 = time.perf_counter()
    r = subprocess.run([str(exe), target, str(count), str(seed)], capture_output=True, text=True,
                       env={**os.environ, **ENV})
    wall = time.perf_counter() - t0
    sanitizer = any(k in r.stderr for k in ("AddressSanitizer", "runtime error:", "LeakSanitizer"))
    if r.returncode != 0 or sanitizer:
        raise FuzzFailure(f"{target} (seed {seed}): exit {r.returncode}\n{r.stdout[-2000:]}{r.stderr[-4000:]}")
    out = json.loads(r.stdout.strip().splitlines()[-1])
    out["seconds"] = round(wall, 2)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gen", default=str(REPO / "firmware" / "generated"))
    ap.add_argument("--count", type=int, default=1_000_000, help="inputs in all targets together")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--targets", default=",".join(TARGETS))
    a = ap.parse_args(argv)
    exe = build(a.gen)
    results = [run(exe, "regress", 1, a.seed)]
    for t in a.targets.split(","):
        try:
            results.append(run(exe, t, max(1, int(a.count * SHARE[t])), a.seed))
        except FuzzFailure as e:
            print(json.dumps({"failed": t, "report": str(e)}, indent=2))
            return 1
    total = sum(r["inputs"] for r in results[1:])
    print(json.dumps({"sanitizers": SANITIZE[0], "input_dim": results[0]["input_dim"], "inputs": total,
                      "seconds": round(sum(r["seconds"] for r in results), 1), "targets": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
