"""The packages import one way only: core <- host <- simulator / planner <- the paper's
reproduction <- experiments, ground <- CLI.

Every import in every module, at module level and inside functions, is checked
against the layer table (AST, so an import hidden in a function counts too).  The
product never reaches the experiments (ns2exp) nor the paper's reproduction (ns2paper:
the authors' networks, controller and gains, their collections, replays, flight
statistics): not the core, host, simulator, planner or ground side, and not the CLI's
product commands, only its experiment commands (EXPERIMENT_COMMANDS).  No two modules
import each other, directly or round a longer cycle."""
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
    "ns2paper": ("paper", {"ns2codegen", "ns2host", "ns2host.sim"}),
    "ns2exp": ("experiments", {"ns2codegen", "ns2host", "ns2host.sim", "ns2plan", "ns2paper"}),
    "ns2ground": ("ground", {"ns2codegen", "ns2host", "ns2host.sim", "ns2plan"}),
    "ns2cli": ("cli", {"ns2codegen", "ns2host", "ns2host.sim", "ns2plan", "ns2paper", "ns2exp", "ns2ground"}),
}
ALL = set(LAYERS)
# the layers apart from the product, which only the experiments and the CLI's experiment commands import
APART = {"ns2exp", "ns2paper"}
PRODUCT = {"ns2codegen", "ns2host", "ns2host.sim", "ns2plan", "ns2ground"}
# the CLI modules of the experiment commands, the only ones that may import ns2exp and ns2paper: `ns2 real ...`,
# `ns2 sim swaps|rings|calibrate`, `ns2 plan` without --problem (the paper's planning experiments) and
# `ns2 results` (their tables); ns2cli (its __init__) imports them to register their commands
EXPERIMENT_COMMANDS = {"ns2cli.real", "ns2cli.simexp", "ns2cli.planexp", "ns2cli.results"}
# the one way into them from a product command: `ns2 plan` hands the run without --problem to planexp
EXPERIMENT_DISPATCH = {("ns2cli.plan", "ns2cli.planexp")}


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


def _imports(path: Path, module: str, submodules: bool = False) -> list[tuple[int, str]]:
    """(line, module name) of every import; ``submodules``: `from pkg import name` as
    pkg.name (a submodule, or a name that the caller resolves to its module)."""
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
            out += ([(node.lineno, f"{name}.{a.name}") for a in node.names] if submodules
                    else [(node.lineno, name)])
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


def test_no_product_package_imports_the_paper_or_the_experiments(tmp_path):
    """The fence: no product layer may import ns2paper or ns2exp (the layer table says so;
    this keeps the table from growing a way round it)."""
    assert set(LAYERS) == PRODUCT | APART | {"ns2cli"}
    assert not [pkg for pkg in PRODUCT if LAYERS[pkg][1] & APART]
    assert LAYERS["ns2paper"][1] <= PRODUCT and "ns2exp" not in LAYERS["ns2paper"][1]
    # an import of the paper's controller inside a simulator function is seen and refused
    src = "def f():\n    from ns2paper.controller import AuthorsController\n    return AuthorsController\n"
    names = [n for _, n in _imports(_write(tmp_path, src), "ns2host.sim.x")]
    assert [_layer_of(n) for n in names] == ["ns2paper"] and "ns2paper" not in LAYERS["ns2host.sim"][1]


def test_the_product_names_no_c_of_the_paper():
    """The simulator's kernel knows a position law only by its hook (NS2_FLY_LAW,
    ns2_fly_law_fn; cfhost.FlyLaw brings its C): no product source, C or Python, includes
    a header of paper/c/ or names one of its functions or types."""
    import re

    headers = sorted((REPO / "paper" / "c").glob("*.h"))
    product_h = [*(REPO / "firmware" / "include").glob("*.h"), *(REPO / "host").glob("*.h")]
    names = {n for h in headers for n in re.findall(r"\b(ns2_\w+)\b", h.read_text())} - set(
        re.findall(r"\b(ns2_\w+)\b", "".join(p.read_text() for p in product_h)))   # the paper's own names
    assert headers and "ns2_authors_law" in names and "ns2_pilot_t" not in names, names
    product = [p for p in [*REPO.glob("firmware/**/*.[ch]"), *REPO.glob("host/**/*.[ch]"), *REPO.glob("host/**/*.py"),
                           *REPO.glob("ns2codegen/**/*.py"), *REPO.glob("planner/**/*.py"), *REPO.glob("ground/**/*.py")]
               if "/build/" not in p.as_posix()]
    bad = [f"{p.relative_to(REPO)}: {hit}" for p in product
           for hit in sorted({*re.findall(r"\b(ns2_\w+)\b", p.read_text())} & names
                             | {h.name for h in headers if f'"{h.name}"' in p.read_text()})]
    assert not bad, "the product names the paper's C:\n" + "\n".join(bad)


def _all_modules():
    """module name -> path, every module of every layer."""
    return {_module_name(pkg, path): path for pkg in LAYERS for path in _files(pkg)}


def test_product_commands_never_import_the_experiments():
    """Every CLI module but the experiment commands' (and ns2cli, which registers them)
    imports neither ns2exp, ns2paper nor an experiment command's module, at module level
    or in a function; the one dispatch of EXPERIMENT_DISPATCH aside."""
    modules = {m: p for m, p in _all_modules().items() if _layer_of(m) == "ns2cli"}
    assert EXPERIMENT_COMMANDS <= set(modules), EXPERIMENT_COMMANDS - set(modules)
    bad = []
    for module, path in modules.items():
        if module in EXPERIMENT_COMMANDS or module == "ns2cli":
            continue
        for line, name in _imports(path, module):
            upward = _layer_of(name) in APART or any(name == c or name.startswith(c + ".")
                                                        for c in EXPERIMENT_COMMANDS)
            if upward and (module, name) not in EXPERIMENT_DISPATCH:
                bad.append(f"{path.relative_to(REPO)}:{line} imports {name}")
    assert not bad, "a product command reaches the experiments:\n" + "\n".join(bad)


def test_plan_with_a_problem_file_loads_no_experiment_module(tmp_path):
    """`ns2 plan --problem` runs without ns2exp: a problem file planned (BL) in a fresh
    process, whose modules are read after the command."""
    import json
    import subprocess
    import sys

    problem = tmp_path / "p.json"
    problem.write_text(json.dumps({"robots": [{"type": "small", "start": [0, -0.3, 1.0], "goal": [0, 0.3, 1.0]}],
                                   "axes": "yz"}))
    code = ("import sys\nfrom click.testing import CliRunner\nfrom ns2cli import main\n"
            f"r = CliRunner().invoke(main, ['plan', '--problem', {str(problem)!r}, '--baseline', '--quiet', "
            f"'--max-samples', '2000', '--out', {str(tmp_path / 'out')!r}])\n"
            "print(r.exit_code, sorted({m.split('.')[0] for m in sys.modules if m.startswith('ns2')}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    status, packages = out.stdout.strip().splitlines()[-1].split(" ", 1)
    assert status == "0" and (tmp_path / "out" / "plan.json").is_file(), out.stdout
    assert "ns2plan" in packages and "ns2exp" not in packages and "ns2paper" not in packages, packages


def test_no_import_cycles():
    """No module imports another that imports it back, directly or round a longer cycle
    (imports inside functions count: a cycle hidden in a function is still one)."""
    modules = _all_modules()

    def targets(module):
        out = set()
        for _, name in _imports(modules[module], module, submodules=True):
            while name and name not in modules:          # a name inside a module: the module
                name = name.rpartition(".")[0]
            if name and name != module:
                out.add(name)
        return out

    graph = {m: targets(m) for m in modules}
    cycles, state = [], {}

    def visit(m, stack):
        state[m] = "open"
        for n in sorted(graph[m]):
            if state.get(n) == "open":
                cycles.append(" -> ".join(stack[stack.index(n):] + [n]))
            elif n not in state:
                visit(n, stack + [n])
        state[m] = "done"

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


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
                          *REPO.glob("experiments/**/*.py"), *REPO.glob("paper/**/*.py"), *REPO.glob("firmware/**/*.c"),
                          *REPO.glob("host/*.c"), *REPO.glob("paper/c/*.c")]
              if literal.search(p.read_text())]
    assert sorted(p.relative_to(REPO).as_posix() for p in places) == ["ns2codegen/vehicle.py"], places
