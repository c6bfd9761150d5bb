"""Cross-build report of the firmware library: flash, RAM and worst-case stack.

Compiles ``firmware/src`` for the STM32F405 (Cortex-M4F, hard float) with the
flags of ``firmware/flags.mk`` plus ``-fstack-usage -fcallgraph-info=su``, reads
``arm-none-eabi-size`` and the call graphs, and computes the worst-case stack
of each entry point (deepest call chain; the library has no recursion and no
function pointers, which the call graph would show as unknown targets): the
predictions, the controller's two halves and the app's per-millisecond
``ns2_pilot_step`` (with the simulator's ``ns2_pilot_tick``; both inference paths
unless ``--define NS2_PILOT_F32=0``, the default app's fixed-point path alone).

    python -m ns2host.firmware_report [GEN_DIR] [--opt -Os] [--define NAME=VALUE ...]   (JSON on stdout)
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import tempfile
from pathlib import Path

from .cbuild import REPO, flags
from .target import ARM_CC

ENTRY_POINTS = ("ns2_predict_f32", "ns2_predict_q15", "ns2_ctrl_position", "ns2_ctrl_attitude", "ns2_pilot_step",
                "ns2_pilot_tick")


def _parse_ci(text: str, nodes: dict, edges: dict) -> None:
    for m in re.finditer(r'node: \{ title: "([^"]+)" label: "([^"]*)"', text):
        name = m.group(1).split(":")[-1]
        size = re.search(r"(\d+) bytes \((\w+)\)", m.group(2))
        if size:
            nodes[name] = (int(size.group(1)), size.group(2))
    for m in re.finditer(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', text):
        edges.setdefault(m.group(1).split(":")[-1], set()).add(m.group(2).split(":")[-1])


def worst_stack(name: str, nodes: dict, edges: dict, seen=()) -> tuple[int, list[str], set]:
    """(bytes, deepest chain, functions without stack data) from ``name``."""
    if name in seen:
        raise ValueError(f"recursion through {name}")
    own, unknown = 0, set()
    if name in nodes:
        own = nodes[name][0]
        if nodes[name][1] != "static":
            unknown.add(f"{name} ({nodes[name][1]})")
    else:
        unknown.add(name)
    best, chain = 0, []
    for callee in sorted(edges.get(name, ())):
        b, c, u = worst_stack(callee, nodes, edges, seen + (name,))
        unknown |= u
        if b > best:
            best, chain = b, c
    return own + best, [name] + chain, unknown


def report(gen_dir: Path, opt: str | None = None, defines: tuple = ()) -> dict:
    """The report of the library compiled against ``gen_dir`` (``defines``: NAME=VALUE)."""
    f = flags()
    inc = [f"-I{REPO / i}" for i in f["NS2_INCLUDES"]] + [f"-I{Path(gen_dir).resolve()}"]
    opt_flags = [opt] if opt else f["NS2_OPT_FLAGS"]
    nodes, edges, sizes = {}, {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for src in f["NS2_SOURCES"]:
            stem = Path(src).stem
            obj = Path(tmp) / f"{stem}.o"
            subprocess.run([ARM_CC, *f["NS2_ARM_FLAGS"], *f["NS2_STD_FLAGS"], *opt_flags, *f["NS2_WARN_FLAGS"],
                            *inc, *(f"-D{d}" for d in defines), "-fstack-usage", "-fcallgraph-info=su", "-c", str(REPO / src),
                            "-o", str(obj)], check=True, capture_output=True, cwd=tmp)
            _parse_ci((Path(tmp) / f"{stem}.ci").read_text(), nodes, edges)
            out = subprocess.run(["arm-none-eabi-size", "-A", str(obj)], check=True, capture_output=True,
                                 text=True).stdout
            sec = {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\.\S+)\s+(\d+)", out, re.M)}
            sizes[stem] = {"text": sum(v for k, v in sec.items() if k.startswith(".text")),
                           "rodata": sum(v for k, v in sec.items() if k.startswith(".rodata")),
                           "data": sec.get(".data", 0), "bss": sec.get(".bss", 0)}
    result = {"opt": " ".join(opt_flags), "defines": list(defines), "objects": sizes}
    every = tuple(Path(s).stem for s in f["NS2_SOURCES"])
    for entry, objs in (("ns2_predict_f32", ("ns2_select", "ns2_f32")), ("ns2_predict_q15", ("ns2_select", "ns2_q15")),
                        ("ns2_ctrl_position", ("ns2_controller",)), ("ns2_ctrl_attitude", ("ns2_controller",)),
                        ("ns2_pilot_step", every), ("ns2_pilot_tick", every)):
        flash = sum(sizes[o]["text"] + sizes[o]["rodata"] + sizes[o]["data"] for o in objs)
        ram = sum(sizes[o]["data"] + sizes[o]["bss"] for o in objs)
        stack, chain, unknown = worst_stack(entry, nodes, edges)
        result[entry] = {"flash_bytes": flash, "static_ram_bytes": ram, "worst_case_stack_bytes": stack,
                         "deepest_chain": chain, "without_stack_data": sorted(unknown)}
    return result


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("gen_dir", nargs="?", default=str(REPO / "firmware" / "generated"))
    ap.add_argument("--opt", default=None)
    ap.add_argument("--define", action="append", default=[], metavar="NAME=VALUE",
                    help="a macro for every compile (NS2_PILOT_F32=0: the default app's fixed-point path alone)")
    args = ap.parse_args()
    print(json.dumps(report(Path(args.gen_dir), args.opt, tuple(args.define)), indent=2))


if __name__ == "__main__":
    main()
