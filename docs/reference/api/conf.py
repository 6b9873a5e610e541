"""Sphinx configuration of polcam's API reference.

Build: ``sphinx-build -W -b html docs/reference/api OUT`` (tests/test_api_docs.py runs it with
warnings as errors).  One page per public module is generated at build time from the module's
``__all__``, so a name added to ``__all__`` is documented without editing this folder.
"""

from __future__ import annotations

import inspect
from importlib import import_module
from pathlib import Path

project = "polcam"
extensions = ["sphinx.ext.autodoc", "sphinx.ext.autosummary", "numpydoc"]
html_theme = "alabaster"
exclude_patterns = ["_build"]
templates_path: list[str] = []

autodoc_typehints = "signature"
autodoc_member_order = "bysource"
autosummary_generate = False
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False

#: The public API: polcam's own ``__all__`` and the public subpackages.
MODULES = [
    "polcam",
    "polcam.io",
    "polcam.demosaicing",
    "polcam.polarimetry",
    "polcam.separation",
    "polcam.calibration",
    "polcam.camera",
    "polcam.acquisition",
    "polcam.sinks",
    "polcam.synth",
    "polcam.mosaic",
    "polcam.errors",
]

_DIRECTIVES = {"function": "autofunction", "class": "autoclass", "exception": "autoexception",
               "data": "autodata"}


def _kind(obj: object) -> str:
    if inspect.isclass(obj):
        return "exception" if issubclass(obj, BaseException) else "class"
    if callable(obj):
        return "function"
    return "data"


#: ids of the classes already documented: a class exported by two modules (``polcam.Separation``,
#: ``polcam.separation.Separation``) is indexed once, under the first.
_SEEN: set[int] = set()


def _page(modname: str) -> str:
    module = import_module(modname)
    names = [n for n in module.__all__ if not n.startswith("__")]
    lines = [modname, "=" * len(modname), "", f".. automodule:: {modname}", "   :no-members:", "",
             f".. currentmodule:: {modname}", "", ".. autosummary::", ""]
    lines += [f"   {n}" for n in names]
    lines.append("")
    for n in names:
        obj = getattr(module, n)
        kind = _kind(obj)
        lines.append(f".. {_DIRECTIVES[kind]}:: {n}")
        if kind in ("class", "exception"):
            lines.append("   :members:")
            if id(obj) in _SEEN:
                lines.append("   :no-index:")
            _SEEN.add(id(obj))
        lines.append("")
    return "\n".join(lines)


def _write_pages(app) -> None:
    _SEEN.clear()
    out = Path(app.srcdir) / "generated"
    out.mkdir(exist_ok=True)
    for modname in MODULES:
        page = out / f"{modname}.rst"
        text = _page(modname)
        if not page.exists() or page.read_text() != text:
            page.write_text(text)


def _doc_comment(name: str, obj: object) -> list[str] | None:
    """The ``#:`` comment above the assignment of a constant that a package re-exports, or None."""
    import sys

    from sphinx.pycode import ModuleAnalyzer

    short = name.rpartition(".")[2]
    for modname, mod in sorted(sys.modules.items()):
        if not modname.startswith("polcam") or getattr(mod, short, None) is not obj:
            continue
        try:
            docs = ModuleAnalyzer.for_module(modname).find_attr_docs()
        except Exception:  # a module without source (a C extension): look further
            continue
        if ("", short) in docs:
            return [line for line in docs[("", short)] if line is not None]
    return None


def _constant_docs(app, what, name, obj, options, lines) -> None:
    """A re-exported constant shows its own ``#:`` comment, not its type's docstring (``float``'s)."""
    if what != "data" or inspect.isclass(obj) or callable(obj):
        return
    own = _doc_comment(name, obj)
    doc = type(obj).__doc__
    type_doc = doc.strip().splitlines() if isinstance(doc, str) else []
    if own is not None or (lines and type_doc and lines[0].strip() == type_doc[0].strip()):
        lines[:] = own if own is not None else []


def setup(app):
    app.connect("builder-inited", _write_pages)
    app.connect("autodoc-process-docstring", _constant_docs)
