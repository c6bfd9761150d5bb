"""The packages import one way only: core <- host <- simulator / planner <- experiments <- ground <- CLI.

Every import in every module, at module level and inside functions, is checked
against the layer table (AST, so an import hidden in a function counts too)."""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

# package -> (folder, layers it may import besides itself)
LAYERS = {
    "ns2codegen": ("ns2codegen", set()),
    "ns2host": ("host", {"ns2codegen"}),
    "ns2host.sim": ("host/sim", {"ns2codegen", "ns2host"}),
    "ns2plan": ("planner", {"ns2codegen"}),
    "ns2exp": ("experiments", {"ns2codegen", "ns2host", "ns2host.sim", "ns2plan"}),
    "ns2ground": ("ground", {"ns2codegen", "ns2host", "ns2host.sim", "ns2plan", "ns2exp"}),
    "ns2cli": ("cli", {"ns2codegen", "ns2host", "ns2host.sim", "ns2plan", "ns2exp", "ns2ground"}),
}
ALL = set(LAYERS)


def _layer_of(module: str) -> str | None:
    """The layer an absolute module name belongs to (the longest matching package)."""
    best = None
    for pkg in LAYERS:
        if module == pkg or module.startswith(pkg + "."):
            if best is None or len(pkg) > len(best):
                best = pkg
    return best


def _module_name(pkg: str, path: Path) -> str:
    rel = path.relative_to(REPO / LAYERS[pkg][0]).with_suffix("")
    parts = [p for p in rel.parts if p != "__init__"]
    return ".".join([pkg, *parts])


def _imports(path: Path, module: str) -> list[tuple[int, str]]:
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_pkg else base[:-1]
                base = base[:len(base) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.append((node.lineno, name))
    return out


def _files(pkg: str):
    folder = REPO / LAYERS[pkg][0]
    for path in sorted(folder.rglob("*.py")):
        owner = _layer_of(_module_name(pkg, path)) if pkg == "ns2host" else pkg
        if owner == pkg:
            yield path


def test_packages_import_one_way_only():
    bad = []
    n_files = 0
    for pkg, (_, allowed) in LAYERS.items():
        for path in _files(pkg):
            n_files += 1
            module = _module_name(pkg, path)
            for line, name in _imports(path, module):
                target = _layer_of(name)
                if target is None or target == pkg:
                    continue
                if target not in allowed:
                    bad.append(f"{path.relative_to(REPO)}:{line} ({pkg}) imports {name} ({target})")
    assert n_files > 40, n_files
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_layer_check_catches_a_hidden_upward_import(tmp_path):
    """The checker itself: an import inside a function, and a relative one, are seen."""
    src = "def f():\n    from ns2plan.problem import Problem\n    return Problem\nfrom ..sim import cloop\n"
    p = REPO / "host" / "crazyflie.py"
    names = [n for _, n in _imports(_write(tmp_path, src), "ns2host.sim.x")]
    assert "ns2plan.problem" in names and "ns2host.sim" in names
    assert _layer_of("ns2host.sim.cloop") == "ns2host.sim" and _layer_of("ns2host.cbuild") == "ns2host"
    assert _layer_of(_module_name("ns2host", p)) == "ns2host"


def _write(tmp_path: Path, src: str) -> Path:
    f = tmp_path / "x.py"
    f.write_text(src)
    return f


def test_planner_functions_are_short():
    """No function of the planner over about 60 lines (its parameters are grouped by the
    stage that reads them, its loops split into named steps)."""
    long = []
    for path in sorted((REPO / "planner").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 60:
                long.append(f"{path.name}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)")
    assert not long, long


def test_gravity_has_one_value():
    """g: one Python constant (ns2codegen.vehicle.G, imported everywhere else) and one C
    macro (NS2_G_MPS2 in ns2_controller.h, used by the controller, the app and the
    simulator's kernel), equal."""
    import re

    from ns2codegen.vehicle import G

    header = (REPO / "firmware/include/ns2_controller.h").read_text()
    assert float(re.search(r"#define NS2_G_MPS2 ([0-9.]+)\n", header).group(1)) == G
    literal = re.compile(r"(?<![\w.])9\.81(?![\d])")
    places = [p for p in [*REPO.glob("ns2codegen/**/*.py"), *REPO.glob("host/**/*.py"), *REPO.glob("planner/*.py"),
                          *REPO.glob("experiments/*.py"), *REPO.glob("firmware/**/*.c"), *REPO.glob("host/*.c")]
              if literal.search(p.read_text())]
    assert sorted(p.relative_to(REPO).as_posix() for p in places) == ["ns2codegen/vehicle.py"], places
