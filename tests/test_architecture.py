"""The package's shape: imports flow one way (no cycle), derive/ imports nothing from the
application, function-local imports only on the light paths listed here, one content-hash
helper, and a cross-process cache that misses when any source it depends on changes.

The import graph is read with `ast` from the source tree (this file's own walker: the layout
is pyproject's package-dir), every import counted, function-local ones included; imports under
``if TYPE_CHECKING:`` are annotations only and are not counted.
"""

from __future__ import annotations

import ast
import functools
import importlib
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# pyproject.toml [tool.setuptools.package-dir]
LAYOUT = {"maglevgen": "maglevgen", "maglevgen.api": "maglevgen/api",
          "maglevgen.params": "maglevgen/params",
          "maglevgen.infrastructure": "maglevgen/infrastructure",
          "maglevgen.derive": "derive", "maglevgen.codegen": "maglevgen/codegen",
          "maglevgen.runtime": "runtime", "maglevgen.control": "maglevgen/control",
          "maglevgen.analyses": "maglevgen/analyses", "maglevgen.exports": "maglevgen/exports",
          "maglevgen.report": "maglevgen/report",
          "maglevgen.report.sections": "maglevgen/report/sections"}

# Function-local imports: allowed only where they keep a light path light, and listed here
# (the one place). Keys: the importing module; values: why, and what it may import lazily.
# First-party targets are module names, third-party ones their top-level package.
# The commands reach the stages through the API (maglevgen.api); `build` through the function
# the API calls (an up-to-date folder without numpy), `params` through the schema.
_CLI_STAGES = ("maglevgen.build", "maglevgen.codegen.generate", "maglevgen.exports.fmu",
               "maglevgen.params", "maglevgen.infrastructure.progress",
               "maglevgen.analyses.queries", "maglevgen.infrastructure.cache",
               "maglevgen.controllers", "numpy", "maglevgen.api")
LAZY_IMPORTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "maglevgen.cli": (
        "start-up: a command imports its own stage only; an up-to-date `maglevgen build` "
        "answers without the schema, numpy or the derivation", _CLI_STAGES),
    "maglevgen.build": (
        "the unchanged rebuild (< 0.5 s) reads the parameter text and BUILD.json only; the "
        "stages are imported when something has to be built",
        ("maglevgen.infrastructure.cache", "maglevgen.carriage", "maglevgen.codegen.interface",
         "maglevgen.analyses.envelope", "maglevgen.analyses.envelope_figures",
         "maglevgen.runtime.library",
         "maglevgen.analyses.magnetic_damping", "maglevgen.controllers",
         "maglevgen.params", "maglevgen.runtime.compile", "maglevgen.control.schedule",
         "maglevgen.analyses.sim_output", "maglevgen.analyses.simulate",
         "maglevgen.analyses.verdicts", "maglevgen.analyses.sim_loop",
         "maglevgen.analyses.queries", "maglevgen.infrastructure.texsetup", "maglevgen.report",
         "maglevgen.control.carriage_plant", "maglevgen.control.built_loop",
         "maglevgen.report.figures", "numpy", "maglevgen.analyses.roa")),
    "maglevgen.analyses.verdicts": (
        "`build` imports it at its top (the unchanged rebuild): the analyses it judges with "
        "load when a verdict is computed",
        ("maglevgen.analyses.envelope", "maglevgen.analyses.roa", "maglevgen.analyses.simulate",
         "maglevgen.analyses.worst_case", "maglevgen.analyses.output_feedback",
         "maglevgen.analyses.sim_loop",
         "maglevgen.controllers", "maglevgen.control.estimation", "maglevgen.control.operating",
         "maglevgen.infrastructure.cache", "numpy")),
    "maglevgen.carriage": (
        "`simulate` and the build's simulations run the compiled C without SymPy: the "
        "symbolic layers load when a carriage first needs them",
        ("maglevgen.derive.numeric", "maglevgen.derive.trim", "maglevgen.derive.paper",
         "sympy")),
    "maglevgen.infrastructure.cache": (
        "hashing a key imports nothing heavy; cloudpickle reads an entry", ("cloudpickle",)),
    "maglevgen.runtime.library": (
        "a cached library is loaded without SymPy or CasADi; the batch driver's source is "
        "looked up when a batch runs",
        ("maglevgen.codegen.generate", "maglevgen.derive.model", "importlib")),
    "maglevgen.control.lqr": ("the simulation path stays SciPy-free", ("scipy",)),
    "maglevgen.control.sampled": ("the simulation path stays SciPy-free", ("scipy",)),
    "maglevgen.control.plant": ("the simulation path stays SciPy-free", ("scipy",)),
    "maglevgen.control.margins": ("the simulation path stays SciPy-free", ("scipy",)),
    "maglevgen.control.schedule": (
        "the simulation path stays SciPy-free; the firmware table's C only when written",
        ("scipy", "maglevgen.codegen.checks", "maglevgen.codegen.emit", "numpy")),
    "maglevgen.runtime.ffi": ("the error codes' names only when a generated function fails",
                              ("maglevgen.codegen.checks",)),
    "maglevgen.codegen.checks": ("the ctypes runtime reads the error codes without jinja2: "
                                 "the checks' C is rendered (and CasADi's edited) only when C "
                                 "is generated", ("maglevgen.codegen.cpass",
                                                  "maglevgen.codegen.emit")),
    "maglevgen.analyses.reference": ("imported without SciPy; a reference run loads it",
                                     ("scipy",)),
    "maglevgen.codegen.lanes": ("mpmath only when lane kernels are generated (exp's table)",
                                ("mpmath",)),
    "maglevgen.analyses.sim_loop": (
        "a hold run needs no firmware (the sensors' loop compiles it)",
        ("maglevgen.analyses.sensed",)),
    "maglevgen.exports.fmu": (
        "the FMU's own C is generated or compiled only on a cache miss; fmpy is optional",
        ("maglevgen.codegen.interface", "maglevgen.codegen.emit",
         "maglevgen.infrastructure.cache", "maglevgen.control.operating",
         "maglevgen.runtime.compile",
         "maglevgen.analyses.simulate", "maglevgen.controllers", "maglevgen.control.built_loop",
         "maglevgen.exports.fmu_sense", "fmpy")),
    "maglevgen.analyses.envelope_figures": ("matplotlib only when a figure is drawn",
                                            ("matplotlib",)),
    "maglevgen.analyses.roa": ("the Lyapunov solve's SciPy, matplotlib only for the figure",
                               ("scipy", "matplotlib")),
    "maglevgen.analyses.roa_contact": ("the contact limit's SciPy optimiser", ("scipy",)),
    "maglevgen.analyses.sim_output": ("matplotlib only when figures are drawn", ("matplotlib",)),
    "maglevgen.report.figures": ("matplotlib only when figures are drawn",
                                 ("matplotlib", "cycler", "math")),
    "maglevgen.infrastructure.progress": (
        "rich only when a terminal shows progress (the heartbeat reads the clock at once)",
        ("rich",)),
    "maglevgen.derive.riccati": ("python-control is a reference only", ("control",)),
    "maglevgen.derive.paper": ("sympy.physics.units for the paper's printed units",
                               ("sympy",)),
    "maglevgen": ("`import maglevgen` stays light: the Python API and the registry of "
                  "controllers load when first used (PEP 562)",
                  ("maglevgen.api", "importlib")),
    # the API's package: each method imports the stage it runs, as the CLI's commands do (a
    # script that only simulates loads no SymPy)
    "maglevgen.api.core": (
        "trim, gains and linear models load the model when first asked; python-control only "
        "where it is returned",
        ("control", "maglevgen.carriage", "maglevgen.control.operating",
         "maglevgen.derive.structure", "maglevgen.params")),
    "maglevgen.api.studies": (
        "each study imports the analysis it runs, as its command does",
        ("maglevgen.analyses.envelope", "maglevgen.analyses.envelope_figures",
         "maglevgen.analyses.montecarlo", "maglevgen.analyses.reference",
         "maglevgen.analyses.roa", "maglevgen.analyses.sim_output",
         "maglevgen.analyses.simulate", "maglevgen.control.carriage_plant",
         "maglevgen.control.built_loop", "maglevgen.codegen.generate",
         "maglevgen.infrastructure.output", "maglevgen.params")),
    "maglevgen.api.writers": (
        "each writer imports the stage it runs, as its command does",
        ("maglevgen.analyses.verdicts", "maglevgen.build",
         "maglevgen.codegen.generate", "maglevgen.exports.firmware", "maglevgen.exports.fmu",
         "maglevgen.control.carriage_plant", "maglevgen.infrastructure.output",
         "maglevgen.report")),
    "maglevgen.api.arguments": (
        "a check imports what it checks against (the schema's ranges, the loops, the "
        "commands' functions) when it runs",
        ("maglevgen.analyses.queries", "maglevgen.control.built_loop",
         "maglevgen.infrastructure.text", "maglevgen.params")),
    "maglevgen.api.results": ("pandas only where a DataFrame is returned", ("pandas",)),
    "maglevgen.analyses.montecarlo": (
        "a worker process imports the stages when its first chunk runs; Dask only with "
        "--scheduler",
        ("distributed", "maglevgen.params", "maglevgen.analyses.roa", "re", "warnings")),
    "maglevgen.analyses.montecarlo_report": (
        "pyarrow only for the Parquet table, matplotlib only for the plots, the schema only "
        "for a parameter's unit in a plot's label",
        ("maglevgen.params", "matplotlib", "pyarrow")),
    "maglevgen.params.sections": ("the schema validates without the derivation's conventions "
                                  "unless a tolerance names a state",
                                  ("maglevgen.derive.conventions",)),
    "maglevgen.report.display": ("SymPy and the number formats only when a display is built",
                                 ("maglevgen.report.format", "sympy")),
}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg, folder in LAYOUT.items():
        for f in sorted((ROOT / folder).glob("*.py")):
            out[pkg if f.stem == "__init__" else f"{pkg}.{f.stem}"] = f
    return out


MODULES = _modules()


def _targets(module: str, node: ast.Import | ast.ImportFrom) -> list[str]:
    """What an import statement imports: maglevgen module names, or third-party top levels."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = node.module or ""
        if node.level:
            parts = module.split(".")
            if MODULES[module].stem != "__init__":
                parts = parts[:-1]
            parts = parts[:len(parts) - node.level + 1]
            base = ".".join(parts + ([node.module] if node.module else []))
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base
                 for a in node.names]
    out = []
    for name in names:
        if name.split(".")[0] == "maglevgen":
            while name not in MODULES:  # `import maglevgen.x.y` of a package attribute
                name = name.rsplit(".", 1)[0]
            out.append(name)
        else:
            out.append(name.split(".")[0])
    return out


@functools.cache  # the sources do not change during a run; many tests walk the same graph
def _imports(module: str) -> tuple[tuple[str, bool], ...]:
    """(target, function_local) for every import of ``module`` outside TYPE_CHECKING."""
    tree = ast.parse(MODULES[module].read_text())
    skip: set[int] = set()
    local: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for n in ast.walk(node))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            local.update(id(n) for n in ast.walk(node))
    return tuple((t, id(node) in local) for node in ast.walk(tree)
                 if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in skip
                 for t in _targets(module, node))


def _graph() -> dict[str, set[str]]:
    return {m: {t for t, _ in _imports(m) if t in MODULES and t != m} for m in MODULES}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle (a path that comes back to its start), or None (depth-first search)."""
    state: dict[str, int] = {}  # 1: on the current path, 2: finished
    path: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        path.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                return [*path[path.index(t):], t]
            if t not in state and (found := visit(t)):
                return found
        path.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_walker_finds_a_planted_cycle() -> None:
    """The cycle search itself, on a graph with a known cycle and one without."""
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_the_walker_sees_every_kind_of_import() -> None:
    """Relative, absolute and function-local imports all reach the graph."""
    graph = _graph()
    assert "maglevgen.derive.numeric" in graph["maglevgen.derive.trim"]  # from .numeric
    assert "maglevgen.errors" in graph["maglevgen.runtime.compile"]  # from maglevgen.errors
    assert "maglevgen.build" in graph["maglevgen.cli"]  # function-local
    assert len(MODULES) > 40


def test_no_import_cycles() -> None:
    cycle = _cycle(_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


# The pipeline's layers, first to last (README's layout table): a module imports from its own
# layer and earlier ones only. derive/ (pure), the errors and the version come first.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("maglevgen.derive", "maglevgen.errors", "maglevgen.version"),
    ("maglevgen.infrastructure",),
    ("maglevgen.params", "maglevgen.carriage"),
    ("maglevgen.codegen",),
    ("maglevgen.runtime",),
    ("maglevgen.control", "maglevgen.controllers"),
    ("maglevgen.analyses",),
    ("maglevgen.exports",),
    ("maglevgen.report",),
    ("maglevgen.api", "maglevgen.build", "maglevgen.cli", "maglevgen"),
)
# The one import against the order, and why: the schema checks a controller's name against
# the registry (`maglevgen.controllers`), whose definitions import nothing of the application
# outside themselves (test_the_controller_definitions_stand_alone).
UPWARD_IMPORTS = {("maglevgen.params.sections", "maglevgen.controllers")}
CONTROLLER_DEFINITIONS = ("maglevgen.controllers", "maglevgen.control",
                          "maglevgen.control.registry",
                          "maglevgen.control.paper_designs", "maglevgen.control.spec",
                          "maglevgen.control.lqr")


def _layer(module: str) -> int:
    best = max(((len(prefix), i) for i, names in enumerate(LAYERS) for prefix in names
                if module == prefix or module.startswith(prefix + ".")), default=None)
    assert best is not None, f"{module} is in no layer of LAYERS"
    return best[1]


def test_imports_follow_the_pipeline() -> None:
    """Every module imports only from its own layer and the layers before it."""
    bad = [f"{m} -> {t}" for m, targets in _graph().items() for t in sorted(targets)
           if _layer(t) > _layer(m) and (m, t) not in UPWARD_IMPORTS]
    assert bad == []
    planted = {"maglevgen.derive.model": {"maglevgen.report.format"}}  # the check itself
    assert [m for m, ts in planted.items() for t in ts if _layer(t) > _layer(m)] == [
        "maglevgen.derive.model"]


# The stages after the controls take the compiled library from the `Plant`
# (maglevgen.control.carriage_plant), which loads it once; none of them looks it up again.
PLANT_USERS = ("maglevgen.analyses", "maglevgen.exports", "maglevgen.report")
LIBRARY_MODULE = "maglevgen.runtime.library"


def _loads_the_library(graph: dict[str, set[str]]) -> list[str]:
    return sorted(m for m, targets in graph.items()
                  if LIBRARY_MODULE in targets
                  and any(m == u or m.startswith(u + ".") for u in PLANT_USERS))


def test_analyses_exports_and_report_take_the_library_from_the_plant() -> None:
    """Nothing under analyses/, exports/ or report/ imports the runtime library module (an
    annotation under TYPE_CHECKING aside)."""
    assert _loads_the_library(_graph()) == []
    planted = {"maglevgen.report.figures": {LIBRARY_MODULE}, "maglevgen.control.plant": {
        LIBRARY_MODULE}}
    assert _loads_the_library(planted) == ["maglevgen.report.figures"]


def test_the_controller_definitions_stand_alone() -> None:
    """What the schema imports of the registry imports nothing else of the application."""
    graph = _graph()
    assert all(graph[m] <= set(CONTROLLER_DEFINITIONS) for m in CONTROLLER_DEFINITIONS), {
        m: graph[m] - set(CONTROLLER_DEFINITIONS) for m in CONTROLLER_DEFINITIONS}


def _all_of(module: str) -> list[str] | None:
    """The module's ``__all__`` (a computed one from the module itself), None: none."""
    for n in ast.parse(MODULES[module].read_text()).body:
        targets = n.targets if isinstance(n, ast.Assign) else [n.target] \
            if isinstance(n, ast.AnnAssign) else []
        if "__all__" in {getattr(t, "id", None) for t in targets}:
            try:
                return list(ast.literal_eval(n.value))  # type: ignore[union-attr]
            except ValueError:  # computed (maglevgen.report: PEP 562, its names load on use)
                return list(importlib.import_module(module).__all__)
    return None


def _top_level(body: list[ast.stmt]):
    for n in body:
        if isinstance(n, (ast.If, ast.Try)):
            yield from _top_level(n.body)
            yield from _top_level(n.orelse)
        else:
            yield n


@functools.cache
def _bound(module: str) -> frozenset[str]:
    """The names ``module`` binds at its top level (assigned, imported, defined)."""
    tree = ast.parse(MODULES[module].read_text())
    out: set[str] = set()
    for n in _top_level(tree.body):
        if isinstance(n, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            for t in n.targets if isinstance(n, ast.Assign) else [n.target]:
                out |= {x.id for x in ast.walk(t) if isinstance(x, ast.Name)}
        elif isinstance(n, (ast.Import, ast.ImportFrom)):
            out |= {(a.asname or a.name).split(".")[0] for a in n.names}
        elif isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(n.name)
    if any(isinstance(n, ast.FunctionDef) and n.name == "__getattr__" for n in tree.body):
        out |= set(_all_of(module) or ())  # PEP 562: its names load on use
    return frozenset(out)


# Where other code uses the package from: the package itself, the benchmarks, the tests, the
# examples, the docs' extensions and the mutation scripts.
USERS = ("maglevgen", "derive", "runtime", "bench", "tests", "examples", "docs", "mutation")
# Modules whose ``__all__`` is the documented API (docs/api.rst): it may list names nothing
# in this repository imports.
API_MODULES = {"maglevgen", "maglevgen.api"}
# Modules whose ``__all__`` is not trimmed yet to what others use, and why.
UNTRIMMED_ALL: dict[str, str] = {}  # module -> why its __all__ may list more (none today)


def _resolve(me: str | None, node: ast.ImportFrom) -> str:
    base = node.module or ""
    if node.level and me:
        parts = me.split(".")
        if MODULES[me].stem != "__init__":
            parts = parts[:-1]
        parts = parts[:len(parts) - node.level + 1]
        base = ".".join(parts + ([node.module] if node.module else []))
    return base


@functools.cache
def _used_from_outside() -> dict[str, frozenset[str]]:
    """module -> the names other files use of it: ``from m import name``, ``m.name`` through
    an imported module (``import m as a``, ``from p import m``), a dotted string naming
    ``m.name`` (mock.patch's), and a PEP 562 facade's ``_EXPORTS`` (name -> submodule)."""
    own = {f.resolve(): m for m, f in MODULES.items()}
    used: dict[str, set[str]] = {}
    files = sorted(f for d in USERS for f in (ROOT / d).rglob("*.py") if "_build" not in f.parts)
    for f in files:
        me = own.get(f.resolve())
        tree = ast.parse(f.read_text())
        alias: dict[str, str] = {}

        def use(module: str, name: str, me: str | None = me) -> None:
            if module in MODULES and module != me and f"{module}.{name}" not in MODULES:
                used.setdefault(module, set()).add(name)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = _resolve(me, node)
                for a in node.names:
                    if f"{base}.{a.name}" in MODULES:
                        alias[a.asname or a.name] = f"{base}.{a.name}"
                    else:
                        use(base, a.name)
            elif isinstance(node, ast.Import):
                alias.update({a.asname: a.name for a in node.names if a.asname})
            elif (isinstance(node, ast.Assign) and me
                  and getattr(node.targets[0], "id", "") == "_EXPORTS"):
                for name, sub in ast.literal_eval(node.value).items():
                    use(f"{me}.{sub}", name, None)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute):
                chain = [node.attr]
                x = node.value
                while isinstance(x, ast.Attribute):
                    chain.insert(0, x.attr)
                    x = x.value
                if isinstance(x, ast.Name):
                    chain.insert(0, alias.get(x.id, x.id))
                    dotted = ".".join(chain).split(".")
                    for k in range(len(dotted) - 1, 0, -1):
                        if ".".join(dotted[:k]) in MODULES:
                            use(".".join(dotted[:k]), dotted[k])
                            break
            elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
                  and re.fullmatch(r"maglevgen(\.\w+)+", node.value)):
                dotted = node.value.split(".")
                for k in range(len(dotted) - 1, 0, -1):
                    if ".".join(dotted[:k]) in MODULES:
                        use(".".join(dotted[:k]), dotted[k])
                        break
    # a name the module does not bind is another object's attribute (a local shadowing an
    # imported module's name), not a use of the module
    return {m: frozenset(n for n in names if n in _bound(m)) for m, names in used.items()}


def test_every_module_declares_what_it_offers() -> None:
    """``__all__`` in every module with code (a folder's docstring-only ``__init__`` has none),
    of names that exist there."""
    bad = {}
    for m, f in MODULES.items():
        tree = ast.parse(f.read_text())
        code = [n for n in tree.body if not (isinstance(n, ast.Expr)
                                            and isinstance(n.value, ast.Constant))]
        if not code:
            continue
        names = _all_of(m)
        if names is None:
            bad[m] = "no __all__"
        elif set(names) - _bound(m):
            bad[m] = {"unknown": sorted(set(names) - _bound(m))}
    assert bad == {}


def test_all_is_what_other_modules_use() -> None:
    """``__all__`` marks what a module offers upward (python-control's use): every public
    name another file uses of it is listed, and (the API aside) nothing else."""
    used = _used_from_outside()
    bad = {}
    for m in MODULES:
        offered, wanted = set(_all_of(m) or ()), {n for n in used.get(m, ()) if n[0] != "_"}
        unlisted = wanted - offered
        unused = (set() if m in API_MODULES or m in UNTRIMMED_ALL
                  else offered - wanted - {"__version__"})
        if unlisted or unused:
            bad[m] = {"used but not in __all__": sorted(unlisted),
                      "in __all__, used by no other file": sorted(unused)}
    assert bad == {}


def test_the_use_walker_sees_every_kind_of_use() -> None:
    """The walker behind the rule above finds each form of use (a planted example of each)."""
    used = _used_from_outside()
    assert {"STATE_INDEX", "KINETIC"} <= used["maglevgen.derive.conventions"]  # cv.X
    assert "run_latex" in used["maglevgen.report.latex"]  # the facade's _EXPORTS
    assert "solve_trim" in used["maglevgen.derive.trim"]  # from m import name


def test_no_module_imports_another_modules_private_name() -> None:
    """A leading underscore means "this module only": no package module imports one."""
    bad = [f"{m}: from {n.module} import {a.name}" for m, f in MODULES.items()
           for n in ast.walk(ast.parse(f.read_text()))
           if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("maglevgen")
           for a in n.names if a.name.startswith("_") and not a.name.startswith("__")]
    assert bad == []


def test_derive_imports_nothing_from_the_application() -> None:
    """derive/ is pure SymPy: it imports only derive/ and third-party libraries."""
    bad = [(m, t) for m in MODULES if m.startswith("maglevgen.derive")
           for t, _ in _imports(m)
           if t.startswith("maglevgen") and not t.startswith("maglevgen.derive")]
    assert bad == []


def test_importing_the_package_has_no_side_effects() -> None:
    """`import maglevgen` installs no disk store and imports no submodule but its exceptions
    and its version (two dependency-free modules the package exports)."""
    code = ("import sys, maglevgen; loaded = sorted(m for m in sys.modules "
            "if m.startswith('maglevgen.')); from maglevgen.derive import memo; "
            "print(memo._store is None, loaded)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split(None, 1)
    assert out[0] == "True"
    assert out[1].strip() == "['maglevgen.errors', 'maglevgen.version']"


def test_function_local_imports_are_the_listed_light_paths() -> None:
    """Every function-local import is listed in LAZY_IMPORTS, and every entry is used."""
    unlisted, used = [], set()
    for m in MODULES:
        for t, local in _imports(m):
            if not local:
                continue
            allowed = LAZY_IMPORTS.get(m, ("", ()))[1]
            if t in allowed:
                used.add((m, t))
            else:
                unlisted.append(f"{m} imports {t} in a function")
    assert unlisted == []
    stale = [(m, t) for m, (_, ts) in LAZY_IMPORTS.items() for t in ts if (m, t) not in used]
    assert stale == [], f"LAZY_IMPORTS entries no longer used: {stale}"


# Issue 51: no module over this many lines. The ones listed are still to be split; an entry
# is removed when its module is (the test says when one no longer needs it).
MAX_LINES = 800
LONG_MODULES: frozenset[str] = frozenset()


def test_no_module_is_over_the_line_limit() -> None:
    """Every module at most MAX_LINES long, but the listed ones (and each of those over it)."""
    lengths = {m: len(f.read_text().splitlines()) for m, f in MODULES.items()}
    assert {m: n for m, n in lengths.items() if n > MAX_LINES and m not in LONG_MODULES} == {}
    assert sorted(m for m in LONG_MODULES if lengths.get(m, 0) <= MAX_LINES) == []


def test_one_content_hash_helper() -> None:
    """hashlib is imported by maglevgen.infrastructure.hashing alone."""
    users = sorted(m for m in MODULES for t, _ in _imports(m) if t == "hashlib")
    assert users == ["maglevgen.infrastructure.hashing"]


def test_content_hash_frames_its_parts() -> None:
    """Parts are framed: moving a boundary or a label changes the key; the same parts in the
    same order give the same key; a parameter file's digest is its plain sha256."""
    import hashlib

    from maglevgen.infrastructure.cache import params_digest
    from maglevgen.infrastructure.hashing import ContentHash, sha256_hex

    assert ContentHash("ab", "c").hexdigest() != ContentHash("a", "bc").hexdigest()
    assert ContentHash().text("x", "1").hexdigest() != ContentHash().text("y", "1").hexdigest()
    assert ContentHash("a", "b").hexdigest() == ContentHash("a", "b").hexdigest()
    assert sha256_hex("maglev") == hashlib.sha256(b"maglev").hexdigest()
    text = (ROOT / "maglevgen" / "carriage_llnl.toml").read_text()
    assert params_digest(text, []) == hashlib.sha256(text.encode()).hexdigest()
    assert params_digest(text, ["vehicle.mass=12"]) == hashlib.sha256(
        text.encode() + b"\0vehicle.mass=12").hexdigest()


# ----------------------------------------------------------------------- the stale cache

_PROBE = textwrap.dedent("""
    import sys
    import maglevgen
    assert maglevgen.__file__.startswith(sys.argv[1]), maglevgen.__file__
    from maglevgen.infrastructure.cache import install_store
    from maglevgen.control.symbolic_reference import _minimum_norm
    store = install_store()
    _minimum_norm(((1.0, 0.0, 1.0), (0.0, 1.0, 1.0)))
    print(store.misses)
""")


def _installed_copy(dest: Path) -> Path:
    """The package as it installs (pyproject's package-dir), copied under ``dest``."""
    top = dest / "maglevgen"
    shutil.copytree(ROOT / "maglevgen", top, ignore=shutil.ignore_patterns("__pycache__"))
    for pkg, folder in (("derive", "derive"), ("runtime", "runtime"),
                        ("templates", "templates")):
        shutil.copytree(ROOT / folder, top / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return top


@pytest.mark.slow  # three cold derivations in a copy of the package
def test_editing_a_memoised_modules_source_misses_the_cache(tmp_path: Path) -> None:
    """control/symbolic_reference.py memoises `_minimum_norm` across processes: an edit to it,
    or to a module it imports, is a miss; an edit to a module it does not depend on is a hit."""
    top = _installed_copy(tmp_path / "src")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "src"),
           "MAGLEVGEN_CACHE": str(tmp_path / "cache")}

    def misses() -> int:
        out = subprocess.run([sys.executable, "-c", _PROBE, str(top)], capture_output=True,
                             text=True, env=env, cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        return int(out.stdout.strip())

    assert misses() == 1  # cold
    assert misses() == 0  # the same sources: read back from the disk store
    with (top / "control" / "symbolic_reference.py").open("a") as f:
        f.write("\n# an edit\n")
    assert misses() == 1
    assert misses() == 0
    with (top / "derive" / "allocation.py").open("a") as f:  # imported by it
        f.write("\n# an edit\n")
    assert misses() == 1
    with (top / "analyses" / "sim_output.py").open("a") as f:  # not imported by it
        f.write("\n# an edit\n")
    assert misses() == 0


@pytest.mark.parametrize("module", sorted(MODULES))
def test_a_memo_key_covers_the_modules_imports(module: str) -> None:
    """The source closure a cache key hashes (maglevgen.infrastructure.hashing: a scan of the import
    statements) holds every module ``module`` imports, directly or not (this file's ast
    walker as the reference)."""
    from maglevgen.infrastructure.hashing import source_closure

    graph, seen, todo = _graph(), {module}, [module]
    while todo:
        for t in graph[todo.pop()] - seen:
            seen.add(t)
            todo.append(t)
    # (it may hold more: annotation-only imports count there, a safe excess)
    assert {p.resolve() for p in source_closure(module)} >= {MODULES[m].resolve() for m in seen}


# --------------------------------------------------------------------- the console script

def test_the_console_script_exits_normally() -> None:
    """No os._exit: atexit handlers run, and the exit code is main's."""
    code = ("import atexit, sys; atexit.register(lambda: print('atexit ran', file=sys.stderr));"
            "sys.argv = ['maglevgen', 'params', 'schema']; from maglevgen.cli import run; run()")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and "vehicle.mass" in out.stdout
    assert out.stderr.strip() == "atexit ran"
    bad = code.replace("'params', 'schema'", "'trim', '--set', 'vehicle.mass=-1'")
    out = subprocess.run([sys.executable, "-c", bad], capture_output=True, text=True)
    assert out.returncode == 2 and out.stderr.splitlines()[-1] == "atexit ran"


def test_a_reader_that_goes_away_is_no_error() -> None:
    """`maglevgen params schema | head -1`: exit 0, nothing on stderr."""
    proc = subprocess.Popen([sys.executable, "-m", "maglevgen.cli", "params", "schema"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.readline()
    proc.stdout.close()  # before the command has written everything
    err = proc.stderr.read()
    assert proc.wait() == 0 and err == b""


def test_the_cached_c_is_keyed_by_the_generators_sources(tmp_path: Path) -> None:
    """The derivation's C folder key (library.derivation_key) changes with an edit to the
    code generator or to a module it imports, and to its C templates; not with an edit to a
    module the generator does not use."""
    top = _installed_copy(tmp_path / "src")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "src")}
    code = ("import sys, maglevgen; assert maglevgen.__file__.startswith(sys.argv[1]); "
            "from maglevgen.infrastructure.cache import derivation_fingerprint; "
            "print(derivation_fingerprint())")

    def key() -> str:
        out = subprocess.run([sys.executable, "-c", code, str(top)], capture_output=True,
                             text=True, env=env, cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    keys = [key()]
    for rel in ("codegen/functions.py", "derive/geometry.py",
                "templates/maglev_simulate.c.j2", "templates/maglev_checks.c.j2",
                "analyses/sim_output.py"):
        assert (top / rel).is_file(), rel
        with (top / rel).open("a") as f:
            f.write("\n" + ("{# an edit #}" if rel.endswith(".j2") else "# an edit") + "\n")
        keys.append(key())
    assert len(set(keys[:5])) == 5  # every edit the C depends on: a new key
    assert keys[5] == keys[4]  # sim_output.py: not the generator's
