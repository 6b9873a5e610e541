"""polcam's modules import one another without cycles, counting imports made inside functions.

Every module of the package is parsed (nothing is imported); an edge A -> B is
any ``import`` or ``from ... import`` of a polcam module B anywhere in A
(module level, inside functions, under ``TYPE_CHECKING`` excepted: those are
annotations only).  ``from polcam.x import name`` counts as an edge to
``polcam.x.name`` when that is a module, else to ``polcam.x``.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "polcam"

#: Entry-point shims: the only modules outside polcam.commands allowed to import it.
SHIMS = {"polcam.cli", "polcam.__main__", "polcam.capture", "polcam.calibration.__main__",
         "polcam.calibration.cli"}


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


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_type_checking(node):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in modules:
                    found.add(alias.name)
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
                    found.add(sub)
                elif target in modules:
                    found.add(target)
    found.discard(name)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: {t for t in _imports(name, path, modules)}
            for name, path in modules.items()}


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


def test_the_graph_sees_imports_inside_functions():
    graph = _graph()
    # polcam.process imports the pipeline inside a function only
    assert "polcam.pipeline" in graph["polcam.process"]
    assert "polcam.camera.registry" in graph["polcam.camera.aravis"]


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


def test_the_camera_layer_does_not_import_acquisition_or_commands():
    bad = sorted(f"{m} -> {t}" for m, targets in _graph().items() if m.startswith("polcam.camera")
                 for t in targets if t.startswith(("polcam.acquisition", "polcam.capture", "polcam.commands")))
    assert not bad, bad
