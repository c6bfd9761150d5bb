"""The Crazyflie firmware with the ns2 app, built for real, and what is in its ELF.

``build_app`` runs the app's own documented command (``make -C firmware/app``)
against the real crazyflie-firmware (``ns2host.crazyflie``); ``build_stock`` builds
the stock ``cf2`` once.  Both are cached under ``build/cf/<hash of every input>``
(app and library sources, generated headers, NS2_INFER, the firmware tree), built
in a temporary folder and renamed into place.  ``sizes`` computes flash, RAM and
CCM as the firmware's ``tools/make/size.py`` does; ``param_groups``,
``log_groups`` and ``event_triggers`` read the firmware's ``.param``, ``.log`` and
``.eventtrigger`` tables (between ``_param_start``/``_param_stop`` etc.) from the ELF.

    python -m ns2host.cfapp [GEN_DIR] [--infer fixed|float|both] [--out build/app]

prints the size report (JSON): stock, with the app, and the difference.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

from . import crazyflie
from .cbuild import REPO, GENERATED, BuildError, cached, compile_error, content_hash

APP_DIR = REPO / "firmware" / "app"
CF_BUILD = crazyflie.BUILD / "cf"
INFER = ("fixed", "float", "both")
TABLES = ("flash", "ram")  # where the fixed-point phi tables live (NS2_TABLES)
FLASH_K, RAM_K, CCM_K = 1008, 128, 64  # the firmware Makefile's MEM_SIZE_*_K
PARAM_SIZE, LOG_SIZE, EVENT_SIZE = 20, 12, 20  # struct param_s, log_s, eventtrigger (32-bit)
PARAM_GROUP, LOG_GROUP, START = 0x80, 0x80, 1


def _firmware_id(fw: Path) -> bytes:
    """The firmware tree's identity: the unpacked pinned tarball, or CRAZYFLIE_BASE's path and git HEAD."""
    marker = fw / ".ns2-unpacked"
    if marker.is_file():
        return marker.read_bytes()
    head = subprocess.run(["git", "-C", str(fw), "rev-parse", "HEAD"], capture_output=True, text=True)
    return f"{fw}:{head.stdout.strip()}".encode()


def _make(args: list[str], log: Path) -> None:
    """make, started outside the project (the app's commands work from any folder)."""
    with open(log, "w") as f:
        r = subprocess.run(["make", *args], stdout=f, stderr=subprocess.STDOUT, cwd=log.parent)
    if r.returncode != 0:
        tail = log.read_text(errors="replace").splitlines()[-25:]
        raise BuildError(f"make {' '.join(args)} failed (log {log}):\n" + "\n".join(tail))


def _cached(name: str, key: bytes, build, product: str = "cf2.elf") -> Path:
    """``build(tmp_dir)`` once into CF_BUILD/<name>-<hash of key> (cbuild.cached), its
    objects pruned; returns that folder."""
    def pruned(out: Path) -> None:
        build(out)
        _prune(out)

    return cached(CF_BUILD / f"{name}-{content_hash([key], 16)}", pruned, product)


KEEP = ("cf2.elf", "cf2.bin", "cf2.map", ".config", "oot/built-in.o", "include/generated/autoconf.h")


def _prune(out: Path) -> None:
    """Drop a finished cache build's objects (about 350 MB with the firmware's -g3):
    only its products and what the checks read stay."""
    keep = {out / k for k in KEEP}
    for p in sorted(out.rglob("*"), key=lambda p: len(p.parts), reverse=True):
        if p in keep or any(k.is_relative_to(p) for k in keep) or p.suffix == ".log":
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()


def build_stock() -> Path:
    """The stock cf2 firmware (cf2_defconfig), built once; returns its build folder."""
    fw = crazyflie.firmware_dir()

    def build(out: Path) -> None:
        common = ["-C", str(fw), f"KBUILD_OUTPUT={out}"]
        _make([*common, "KCONFIG_ALLCONFIG=configs/cf2_defconfig", "alldefconfig"], out / "config.log")
        _make([*common, f"-j{os.cpu_count() or 1}"], out / "build.log")

    return _cached("stock", _firmware_id(fw), build)


def _config(name: str, fragments: list[Path]) -> Path:
    """A firmware configuration only (cf2_defconfig merged with ``fragments``, as the
    app build makes it: .config and include/generated/autoconf.h); cached."""
    fw = crazyflie.firmware_dir()

    def build(out: Path) -> None:
        common = ["-C", str(fw), f"KBUILD_OUTPUT={out}"]
        _make([*common, "KCONFIG_ALLCONFIG=configs/cf2_defconfig", "alldefconfig"], out / "config.log")
        if fragments:
            subprocess.run([str(fw / "scripts/kconfig/merge_config.sh"), "-O", str(out), "-m", str(out / ".config"),
                            *map(str, fragments)], capture_output=True, check=True, cwd=out)
        _make([*common, "silentoldconfig"], out / "silentoldconfig.log")

    key = _firmware_id(fw) + b"".join(f.read_bytes() for f in fragments)
    return _cached(name, key, build, "include/generated/autoconf.h")


def app_config() -> Path:
    """The app's firmware configuration only (cf2_defconfig + app-config), for every
    host and emulator build of firmware code (the simulator's estimator and
    controllers, the harness, the Cortex-M4 counts; the Mellinger robots' battery
    compensation excepted, see stock_config): the configuration the drone flies with;
    cached, seconds to make."""
    return _config("config", [APP_DIR / "app-config"])


def stock_config() -> Path:
    """The stock firmware's configuration only (cf2_defconfig): what a Crazyflie flying
    the firmware's own controllers has, battery thrust compensation on
    (CONFIG_ENABLE_THRUST_BAT_COMPENSATED, which app-config turns off); the simulator's
    Mellinger robots compensate with it (host/cfhost.py)."""
    return _config("stockconfig", [])


def app_inputs(gen_dir: Path) -> list[Path]:
    files = sorted(p for p in APP_DIR.rglob("*") if p.is_file() and "test_stubs" not in p.parts)
    for d in ("src", "include"):
        files += sorted((REPO / "firmware" / d).glob("*.[ch]"))
    return files + [Path(gen_dir) / g for g in (*GENERATED, "ns2_vehicles.h")]


def app_make_args(gen_dir: Path, infer: str, out: Path, tables: str = "flash") -> list[str]:
    """Arguments of ``make`` for the app (README's command plus where things are)."""
    return ["-C", str(APP_DIR), f"CRAZYFLIE_BASE={crazyflie.firmware_dir()}", f"NS2_GEN={Path(gen_dir).resolve()}",
            f"NS2_INFER={infer}", f"NS2_TABLES={tables}", f"APP_BUILD={out}", f"PYTHON={sys.executable}", f"-j{os.cpu_count() or 1}"]


def build_app(gen_dir: Path, infer: str = "fixed", out: Path | None = None, tables: str = "flash") -> Path:
    """cf2 with the app: into ``out`` (incremental, e.g. build/app for ``make app``)
    or a cache folder keyed by every input; returns the build folder.  ``tables``:
    flash, or ram (the fixed-point phi tables in SRAM)."""
    if infer not in INFER:
        raise ValueError(f"infer={infer!r}: must be one of {INFER}")
    if tables not in TABLES:
        raise ValueError(f"tables={tables!r}: must be one of {TABLES}")
    gen_dir = Path(gen_dir).resolve()
    if out is not None:
        out = Path(out).resolve()
        out.mkdir(parents=True, exist_ok=True)
        _make(app_make_args(gen_dir, infer, out, tables), out / "ns2-build.log")
        return out
    fw = crazyflie.firmware_dir()
    # the inputs' digest, hashed again by _cached (the cache names the builds have had)
    key = bytes.fromhex(content_hash([_firmware_id(fw), infer, tables,
                                      *(p.name.encode() + b"\0" + p.read_bytes() for p in app_inputs(gen_dir))], 64))
    return _cached(f"app-{infer}-{tables}", key,
                   lambda tmp: _make(app_make_args(gen_dir, infer, tmp, tables), tmp / "ns2-build.log"))


def kconfig(build_dir: Path) -> dict[str, str]:
    """The final .config: set options as name -> value, unset ones as name -> 'n'."""
    out = {}
    for line in (Path(build_dir) / ".config").read_text().splitlines():
        if line.startswith("CONFIG_") and "=" in line:
            k, v = line.split("=", 1)
            out[k] = v
        elif line.startswith("# CONFIG_") and line.endswith(" is not set"):
            out[line[2:-len(" is not set")]] = "n"
    return out


def section_sizes(elf: Path) -> dict[str, int]:
    from elftools.elf.elffile import ELFFile  # [target] extra; the simulator needs only app_config

    with open(elf, "rb") as f:
        return {s.name: s["sh_size"] for s in ELFFile(f).iter_sections() if s.name}


def sizes(elf: Path) -> dict[str, int]:
    """Flash, RAM and CCM used, as the firmware's tools/make/size.py counts them."""
    s = section_sizes(elf)
    g = lambda n: s.get(n, 0)  # noqa: E731
    return {"flash": g(".text") + g(".data") + g(".ccmdata"), "ram": g(".bss") + g(".data"),
            "ccm": g(".ccmbss") + g(".ccmdata"), "text": g(".text"), "data": g(".data"), "bss": g(".bss"),
            "flash_free": FLASH_K * 1024 - (g(".text") + g(".data") + g(".ccmdata")),
            "ram_free": RAM_K * 1024 - (g(".bss") + g(".data")), "ccm_free": CCM_K * 1024 - (g(".ccmbss") + g(".ccmdata"))}


class Image:
    """An ELF's symbols and memory for reading the firmware's tables."""

    def __init__(self, elf: Path):
        from elftools.elf.elffile import ELFFile

        self.f = open(elf, "rb")
        self.elf = ELFFile(self.f)
        self.symbols = {s.name: s for s in self.elf.get_section_by_name(".symtab").iter_symbols() if s.name}

    def close(self) -> None:
        self.f.close()

    def read(self, addr: int, n: int) -> bytes:
        for seg in self.elf.iter_segments():
            if seg["p_type"] == "PT_LOAD" and seg["p_vaddr"] <= addr < seg["p_vaddr"] + seg["p_filesz"]:
                return seg.data()[addr - seg["p_vaddr"]:addr - seg["p_vaddr"] + n]
        raise ValueError(f"0x{addr:08x}: not in a loaded segment")

    def cstr(self, addr: int) -> str:
        raw = self.read(addr, 64)
        return raw[:raw.index(b"\0")].decode()

    def table(self, name: str, size: int) -> list[bytes]:
        a, b = self.symbols[f"_{name}_start"]["st_value"], self.symbols[f"_{name}_stop"]["st_value"]
        raw = self.read(a, b - a)
        return [raw[i:i + size] for i in range(0, len(raw), size)]

    def address_of(self, addr: int) -> str | None:
        for s in self.symbols.values():
            if s["st_info"]["type"] == "STT_OBJECT" and s["st_value"] <= addr < s["st_value"] + max(s["st_size"], 1):
                return s.name
        return None


def _groups(entries) -> dict[str, list[tuple[str, int, int]]]:
    out = {}
    for group, name, typ, _, addr in entries:
        out.setdefault(group, []).append((name, typ, addr))
    return out


def _entries(entries, parse, group_bit: int) -> list[tuple[str, str, int, int, int]]:
    """The variables of a table in its order (the TOC ids the firmware gives them):
    (group, name, type, extended type, address)."""
    out, cur = [], None
    for e in entries:
        typ, ext, name, addr = parse(e)
        if typ & group_bit:
            cur = name if typ & START else None
        elif cur is not None:
            out.append((cur, name, typ, ext, addr))
    return out


def param_entries(elf: Path) -> list[tuple[str, str, int, int, int]]:
    """The PARAM table in order: (group, name, type, extended type, address)
    (struct param_s: u8 type, u8 extended_type, char *name, void *address, callback, getter)."""
    im = Image(elf)
    try:
        def parse(e):
            typ, ext, name, addr = struct.unpack_from("<BBxxII", e)
            return typ, ext, im.cstr(name), addr
        return _entries(im.table("param", PARAM_SIZE), parse, PARAM_GROUP)
    finally:
        im.close()


def log_entries(elf: Path) -> list[tuple[str, str, int, int, int]]:
    """The LOG table in order: (group, name, type, 0, address) (struct log_s: u8 type, char *name, void *address)."""
    im = Image(elf)
    try:
        def parse(e):
            typ, name, addr = struct.unpack_from("<BxxxII", e)
            return typ, 0, im.cstr(name), addr
        return _entries(im.table("log", LOG_SIZE), parse, LOG_GROUP)
    finally:
        im.close()


def param_groups(elf: Path) -> dict[str, list[tuple[str, int, int]]]:
    """PARAM groups: group -> [(name, type, address)]."""
    return _groups(param_entries(elf))


def log_groups(elf: Path) -> dict[str, list[tuple[str, int, int]]]:
    """LOG groups: group -> [(name, type, address)]."""
    return _groups(log_entries(elf))


def event_triggers(elf: Path) -> dict[str, dict]:
    """Event triggers: name -> payload variables [(name, type)], payload size and
    the payload's symbol (struct eventtrigger: char *name, payloadDesc *, u8 count,
    void *payload, u8 size; eventtriggerPayloadDesc: u8 type, char *name)."""
    im = Image(elf)
    try:
        out = {}
        for e in im.table("eventtrigger", EVENT_SIZE):
            name, desc, count, payload, size = struct.unpack_from("<IIBxxxIB", e)
            variables = []
            for i in range(count):
                typ, vname = struct.unpack_from("<BxxxI", im.read(desc + 8 * i, 8))
                variables.append((im.cstr(vname), typ))
            out[im.cstr(name)] = {"variables": variables, "payload_size": size,
                                  "payload_symbol": im.address_of(payload)}
        return out
    finally:
        im.close()


def app_objects_ram(build_dir: Path) -> dict[str, int]:
    """text/data/bss of the app's own objects (the Kbuild folder's built-in.o)."""
    from .target import ARM_CC

    size = ARM_CC.replace("gcc", "size")
    r = subprocess.run([size, "-B", str(Path(build_dir) / "oot" / "built-in.o")], capture_output=True, text=True,
                       check=True)
    text, data, bss = map(int, r.stdout.splitlines()[1].split()[:3])
    return {"text": text, "data": data, "bss": bss}


def report(gen_dir: Path, infer: str = "fixed", out: Path | None = None, tables: str = "flash") -> dict:
    """Flash/RAM/CCM of the stock firmware and with the app; what the app adds; the
    network it was built with (the export's ``ns2_config.toml``, as bench_target.py reports it)."""
    from ns2codegen.export import export_config

    net = export_config(gen_dir)
    stock, app = build_stock(), build_app(gen_dir, infer, out, tables)
    s, a = sizes(stock / "cf2.elf"), sizes(app / "cf2.elf")
    cfg = kconfig(app)
    stack = int(cfg.get("CONFIG_APP_STACKSIZE", "0")) * 4
    d = {k: a[k] - s[k] for k in ("flash", "ram", "ccm", "text", "data", "bss")}
    return {"infer": infer, "tables": tables, "elf": str(app / "cf2.elf"), "bin": str(app / "cf2.bin"),
            "network": {"phi": net.phi_dims(), "rho": net.rho_dims(), "history_ms": net.history_ms,
                        "input_dim": net.input_dim},
            "stock": s, "app": a, "delta": d,
            # what the app's RAM is: its task's static stack, its own bss (the app
            # objects' .data is their PARAM/LOG tables, which the linker puts in flash)
            "ram_added": {"bytes": d["ram"], "app_task_stack": stack, "app_bss": app_objects_ram(app)["bss"]},
            "flash_budget_bytes": FLASH_BUDGET, "within_flash_budget": d["flash"] <= FLASH_BUDGET}


FLASH_BUDGET = 72 * 1024  # the app's flash over stock (issue 13): default app, paper-sized network
# the firmware Makefile's ARCH_CFLAGS defines that its headers need
FIRMWARE_DEFINES = ("-DSTM32F4XX", "-DSTM32F40_41xxx", "-DHSE_VALUE=8000000", "-DUSE_STDPERIPH_DRIVER")


def firmware_includes(build_dir: Path) -> list[Path]:
    """The include folders of the firmware's Makefile (its INCLUDES lines), for a build in build_dir."""
    fw = crazyflie.firmware_dir()
    subst = {"$(srctree)": str(fw), "$(FREERTOS)": str(fw / "vendor/FreeRTOS"),
             "$(PORT)": str(fw / "vendor/FreeRTOS/portable/GCC/ARM_CM4F"), "$(LIB)": str(fw / "src/lib"),
             "$(KBUILD_OUTPUT)": str(build_dir)}
    out = []
    for line in (fw / "Makefile").read_text().splitlines():
        if line.startswith("INCLUDES +="):
            for flag in line.split("+=", 1)[1].split():
                for k, v in subst.items():
                    flag = flag.replace(k, v)
                out.append(Path(flag[2:]))
    return out


def build_harness(gen_dir: Path, out: Path) -> Path:
    """The app's host harness (firmware/app/test_stubs/app_harness.c) against the
    firmware's real headers and its real peer_localization.c (``-isystem``: their
    warnings are the firmware's; the app and the library get the strict flags),
    with both inference paths and the app's autoconf.h.  Returns the executable."""
    from .cbuild import flags, host_cc

    app = app_config()  # the configuration (autoconf.h) the app flies with
    f = flags()
    fw = crazyflie.firmware_dir()
    common = ["-std=gnu11", "-O1", "-ffp-contract=off", *FIRMWARE_DEFINES,
              *[a for d in firmware_includes(app) for a in ("-isystem", str(d))],
              "-include", str(app / "include/generated/autoconf.h")]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    obj, exe = out / "peer_localization.o", out / "app_harness"
    for cmd in ([host_cc(), *common, "-Wall", "-Werror", "-c", str(fw / "src/modules/src/peer_localization.c"),
                 "-o", str(obj)],
                [host_cc(), *common, *[w for w in f["NS2_WARN_FLAGS"] if w != "-pedantic"],
                 "-DNS2_APP_FIXED=1", "-DNS2_APP_FLOAT=1", *[f"-I{REPO / i}" for i in f["NS2_INCLUDES"]],
                 f"-I{Path(gen_dir).resolve()}", str(APP_DIR / "test_stubs/app_harness.c"), str(obj), "-lm",
                 "-o", str(exe)]):
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise compile_error(" ".join(cmd[-3:]), cmd, r)
    return exe


HL_SOURCES = ("src/modules/src/planner.c", "src/modules/src/pptraj.c", "src/modules/src/pptraj_compressed.c")


def build_hl_harness(out: Path) -> Path:
    """The firmware's own high-level commander on the host (firmware/app/test_stubs/
    hl_harness.c includes crtp_commander_high_level.c; with the firmware's planner.c,
    pptraj.c, pptraj_compressed.c), against its real headers and the app build's
    autoconf.h, warnings as errors.  Returns the executable."""
    from .cbuild import host_cc

    app = app_config()
    fw = crazyflie.firmware_dir()
    cmd = [host_cc(), "-std=gnu11", "-O1", "-ffp-contract=off", "-Wall", "-Werror", *FIRMWARE_DEFINES,
           *[a for d in firmware_includes(app) for a in ("-isystem", str(d))], "-I", str(fw / "src/modules/src"),
           "-include", str(app / "include/generated/autoconf.h"), str(APP_DIR / "test_stubs/hl_harness.c"),
           *[str(fw / s) for s in HL_SOURCES], "-lm", "-o", str(Path(out) / "hl_harness")]
    Path(out).mkdir(parents=True, exist_ok=True)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise compile_error("hl_harness.c", cmd, r)
    return Path(out) / "hl_harness"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m ns2host.cfapp", description=__doc__.splitlines()[0])
    ap.add_argument("gen", nargs="?", default=str(REPO / "firmware" / "generated"))
    ap.add_argument("--infer", choices=INFER, default="fixed")
    ap.add_argument("--tables", choices=TABLES, default="flash",
                    help="flash, or ram: the fixed-point phi tables in SRAM (docs/memory.md)")
    ap.add_argument("--out", default=None, help="build folder (default: a cache folder under build/cf)")
    a = ap.parse_args(argv)
    from ns2codegen.errors import Ns2Error
    from ns2codegen.results import command_line, stamp

    command = command_line(None if argv is None else ["", *argv], prog=ap.prog)
    try:
        rep = report(Path(a.gen), a.infer, Path(a.out) if a.out else None, a.tables)
    except (Ns2Error, crazyflie.FirmwareMissing) as e:     # a build error, a folder that is not an export
        raise SystemExit(str(e))
    print(json.dumps(stamp(rep, command), indent=2))      # docs/app.md's tables: docs/results/runs/app-sizes/


if __name__ == "__main__":
    main()
