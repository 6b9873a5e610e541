"""polcam's import graph: no cycles, the layering of docs/architecture.md, no private names shared.

Every module of the package is parsed (nothing is imported); an edge A -> B is
any ``import`` or ``from ... import`` of a polcam module B anywhere in A
(module level, inside functions, under ``TYPE_CHECKING`` excepted: those are
annotations only).  ``from polcam.x import name`` counts as an edge to
``polcam.x.name`` when that is a module, else to ``polcam.x``.
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from collections import Counter
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "polcam"

#: Entry-point shims: the only modules outside polcam.commands allowed to import it.
SHIMS = {"polcam.cli", "polcam.__main__", "polcam.capture", "polcam.calibration.__main__"}

#: The layers of docs/architecture.md, bottom up.  A unit is a top-level module or a
#: sub-package; a module imports its own unit and units of lower layers only, plus
#: SAME_LAYER below.  Longest prefix wins (the shims are named whole).
LAYERS: list[tuple[str, set[str]]] = [
    ("errors", {"polcam.errors"}),
    ("base", {"polcam.registry", "polcam._jsonable", "polcam._hashing", "polcam._version",
              "polcam._xp", "polcam._imageops", "polcam.filters", "polcam.parallel", "polcam.workpool"}),
    ("mosaic", {"polcam.mosaic"}),
    ("frame", {"polcam.frame"}),
    ("io", {"polcam.io"}),
    ("algorithms", {"polcam.polarimetry", "polcam.demosaicing", "polcam.calibration", "polcam.separation"}),
    ("api", {"polcam"}),
    ("synth", {"polcam.synth"}),
    ("pipeline", {"polcam.pipeline"}),
    ("devices and outputs", {"polcam.camera", "polcam.sinks"}),
    ("runs", {"polcam.process", "polcam.process_checks", "polcam.outdir", "polcam.footprint", "polcam._memory",
              "polcam.acquisition", "polcam.viewer", "polcam._browser"}),
    ("bench", {"polcam.bench"}),
    ("commands", {"polcam.commands"}),
    ("entry points", SHIMS),
]

#: Imports between different units of one layer, each with its reason.
SAME_LAYER: dict[tuple[str, str], str] = {
    ("polcam._imageops", "polcam._xp"): "the neighbourhood filters are written over the array namespace",
    ("polcam.filters", "polcam._xp"): "the joint bilateral filter is written over the array namespace",
    ("polcam.workpool", "polcam.parallel"): "the worker pool applies the one parallel policy",
    ("polcam.separation", "polcam.polarimetry"): "the methods separate with Stokes maps, Imin and Imax",
    ("polcam.calibration", "polcam.demosaicing"): "correct_stack demosaics a calibrated mosaic",
    ("polcam.process", "polcam.process_checks"): "the batch run's checks, one module apart",
    ("polcam.process", "polcam.footprint"): "the batch run's memory and disk estimates",
    ("polcam.process", "polcam._memory"): "the workers' peak memory",
    ("polcam.viewer", "polcam.process"): "polcam view reads a process folder's layout hint",
}

#: Private names imported from another module that other tasks' files still hold (the lead
#: empties this at merge; each is renamed in its owning module).  (importer, module, name).
KNOWN_PRIVATE: dict[tuple[str, str, str], str] = {
}

#: Package-private modules imported from outside their package, still to be made public in the
#: package that owns them (the lead empties this at merge).  (importer, module).
KNOWN_PRIVATE_MODULES: dict[tuple[str, str], str] = {
}

#: Imports of polcam modules made inside functions, per module.  A module not listed may make none.
#: The modules of tasks still open (resolve: method resolution once; speed) keep theirs until they
#: merge; the lead hoists them then and lowers these.
LAZY_BUDGET: dict[str, int] = {
    "polcam.sinks": 1,                              # RerunSink on first use (polcam.sinks.__getattr__)
    # polcam.separation._kernels imports numba (0.25 s): loaded where a compiled loop first runs
    "polcam.separation._registry": 1,
    "polcam.pipeline": 1,                           # the live maps' loops (polcam._cell_kernels)
    "polcam.separation._rpca": 2,
    "polcam.separation.wen21": 3,
}

#: Libraries loaded on first use only (docs/architecture.md, lazy imports).
HEAVY = ("gi", "OpenImageIO", "rawpy", "torch", "rerun", "dask", "distributed", "matplotlib", "polanalyser",
         "numba")


# ---------------------------------------------------------------------------
# the parse
# ---------------------------------------------------------------------------


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _statements(name: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, str | None, bool]]:
    """(target module, imported name or None, inside a function) per polcam import of a module."""
    return _parsed(name, path, tuple(sorted(modules)))


@functools.lru_cache(maxsize=None)
def _parsed(name: str, path: Path, names: tuple[str, ...]) -> list[tuple[str, str | None, bool]]:
    return list(_walk(name, path, set(names)))


def _walk(name: str, path: Path, modules: set[str]):
    tree = ast.parse(path.read_text(), filename=str(path))
    skip: set[int] = set()
    in_function: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_type_checking(node):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            in_function.update(id(n) for n in ast.walk(node))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        lazy = id(node) in in_function
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in modules:
                    yield alias.name, None, lazy
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in modules:
                    yield sub, None, lazy
                elif target in modules:
                    yield target, alias.name, lazy


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    return {t for t, _, _ in _statements(name, path, modules)} - {name}


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


# ---------------------------------------------------------------------------
# the layers
# ---------------------------------------------------------------------------


def _unit(module: str) -> str:
    """The unit a module belongs to: the longest name of LAYERS that is the module or a package above it."""
    units = {u for _, us in LAYERS for u in us}
    parts = module.split(".")
    for k in range(len(parts), 0, -1):
        if ".".join(parts[:k]) in units:
            return ".".join(parts[:k])
    raise AssertionError(f"{module}: in no layer of LAYERS (add its unit to docs/architecture.md and here)")


def _layer(unit: str) -> int:
    return next(i for i, (_, us) in enumerate(LAYERS) if unit in us)


def _violations(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for m, targets in graph.items():
        um = _unit(m)
        for t in targets:
            ut = _unit(t)
            if ut == um or _layer(ut) < _layer(um) or (um, ut) in SAME_LAYER:
                continue
            bad.append(f"{m} ({LAYERS[_layer(um)][0]}) -> {t} ({LAYERS[_layer(ut)][0]})")
    return sorted(bad)


def _private_names() -> tuple[set[tuple[str, str, str]], set[tuple[str, str]]]:
    """(importer, module, name) of underscore names imported from another module, and (importer,
    module) of package-private modules imported from outside the package above them."""
    modules = _modules()
    names: set[tuple[str, str, str]] = set()
    private_modules: set[tuple[str, str]] = set()
    for m, path in modules.items():
        for target, name, _ in _statements(m, path, modules):
            if name is not None and name.startswith("_") and not name.startswith("__") and target != m:
                names.add((m, target, name))
            parts = target.split(".")
            for k, part in enumerate(parts):
                owner = ".".join(parts[:k])
                if part.startswith("_") and not part.startswith("__") and m != owner \
                        and not m.startswith(owner + "."):
                    private_modules.add((m, ".".join(parts[: k + 1])))
    return names, private_modules


def _lazy_counts() -> Counter[str]:
    modules = _modules()
    return Counter(m for m, path in modules.items() for t, _, lazy in _statements(m, path, modules)
                   if lazy and t != m)


# ---------------------------------------------------------------------------
# the tests
# ---------------------------------------------------------------------------


def test_the_graph_sees_imports_inside_functions():
    modules = _modules()
    lazy = {t for t, _, inside in _statements("polcam.camera.aravis", modules["polcam.camera.aravis"], modules)
            if inside}
    assert "polcam.camera.registry" in _graph()["polcam.camera.aravis"]
    assert lazy <= _graph()["polcam.camera.aravis"]


def test_no_import_cycle():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles among polcam's modules: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_a_planted_cycle_is_found():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_library_never_imports_the_commands():
    offenders = sorted(f"{m} -> {t}" for m, targets in _graph().items() for t in targets
                       if t.startswith("polcam.commands") and not m.startswith("polcam.commands")
                       and m not in SHIMS)
    assert not offenders, offenders


def test_every_module_is_in_a_layer():
    for m in _modules():
        _unit(m)


def test_imports_follow_the_layers():
    bad = _violations(_graph())
    assert not bad, "imports against the layers of docs/architecture.md:\n" + "\n".join(bad)


def test_a_planted_upward_import_is_found():
    graph = {"polcam.calibration.store": {"polcam.acquisition.saving"}, "polcam.io.readers": {"polcam.mosaic"},
             "polcam.separation.yang10": {"polcam.polarimetry", "polcam.filters"},
             "polcam.demosaicing.eari": {"polcam.separation"}}
    assert _violations(graph) == [
        "polcam.calibration.store (algorithms) -> polcam.acquisition.saving (runs)",
        "polcam.demosaicing.eari (algorithms) -> polcam.separation (algorithms)"]


def test_the_same_layer_exceptions_are_used():
    graph = _graph()
    used = {(_unit(m), _unit(t)) for m, ts in graph.items() for t in ts}
    assert not set(SAME_LAYER) - used, set(SAME_LAYER) - used


def test_no_private_name_crosses_a_module():
    names, private_modules = _private_names()
    new = sorted(names - set(KNOWN_PRIVATE))
    assert not new, "private names imported from another module (make them public where they live):\n" + \
        "\n".join(f"{m}: from {t} import {n}" for m, t, n in new)
    new_mods = sorted(private_modules - set(KNOWN_PRIVATE_MODULES))
    assert not new_mods, "package-private modules imported from outside their package:\n" + \
        "\n".join(f"{m} -> {t}" for m, t in new_mods)


def test_the_known_private_names_are_still_there():
    # an entry fixed is an entry removed: the lists only shrink
    names, private_modules = _private_names()
    assert not set(KNOWN_PRIVATE) - names, set(KNOWN_PRIVATE) - names
    assert not set(KNOWN_PRIVATE_MODULES) - private_modules, set(KNOWN_PRIVATE_MODULES) - private_modules


def test_function_level_imports_stay_within_the_budget():
    counts = _lazy_counts()
    over = sorted(f"{m}: {n} imports of polcam modules inside functions (budget {LAZY_BUDGET.get(m, 0)})"
                  for m, n in counts.items() if n > LAZY_BUDGET.get(m, 0))
    assert not over, ("import polcam modules at the top of the module (docs/architecture.md, lazy imports):\n"
                      + "\n".join(over))


def test_the_heavy_libraries_load_on_first_use():
    code = ("import importlib, pkgutil, sys\n"
            "import polcam, polcam.cli, polcam.process, polcam.acquisition, polcam.sinks, polcam.viewer\n"
            "import polcam.camera, polcam.pipeline, polcam.bench, polcam.synth\n"
            "polcam.cli.build_parser()\n"
            "for m in pkgutil.iter_modules(polcam.bench.__path__):\n"
            "    importlib.import_module('polcam.bench.' + m.name)\n"
            f"print(sorted(set({HEAVY!r}) & set(sys.modules)))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          cwd=PACKAGE.parent)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]", f"loaded at import: {proc.stdout.strip()}"


def test_the_camera_layer_does_not_import_acquisition_or_commands():
    bad = sorted(f"{m} -> {t}" for m, targets in _graph().items() if m.startswith("polcam.camera")
                 for t in targets if t.startswith(("polcam.acquisition", "polcam.capture", "polcam.commands")))
    assert not bad, bad
