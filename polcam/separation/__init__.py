"""Diffuse/specular separation: one module per method, behind :func:`separate`.

Every module in this package whose name does not start with an underscore is
a method module; importing the package imports them all, and each registers
itself with :func:`register`.  :func:`resolve_separation` turns a method name (or
None, the default for an input form) and its options into a
:class:`ResolvedSeparation`, checked once, which :func:`separate` and the
commands take as it is.
"""

from __future__ import annotations

import importlib
import pkgutil

from polcam.separation._illuminant import SATURATED
from polcam.separation._registry import (
    MethodSpec,
    ResolvedSeparation,
    Separation,
    check_options,
    default_method,
    estimated_illuminant,
    input_form,
    layout_form,
    method_spec,
    methods,
    register,
    resolve_separation,
    separate,
    takes_illuminant,
    unregister,
)

for _mod in pkgutil.iter_modules(__path__):
    if not _mod.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_mod.name}")

def __getattr__(name: str) -> tuple[str, ...]:
    """``METHODS``: the registered method names now (:func:`methods`), so a later :func:`register` shows."""
    if name == "METHODS":
        return methods()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["METHODS", "SATURATED", "MethodSpec", "ResolvedSeparation", "Separation", "check_options", "default_method",
           "estimated_illuminant", "input_form", "layout_form", "method_spec", "methods", "register",
           "resolve_separation", "separate", "takes_illuminant", "unregister"]
