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


def setup(app):
    app.connect("builder-inited", _write_pages)
