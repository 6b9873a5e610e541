"""Diffuse/specular separation: one module per method, behind :func:`separate`.

Every module in this package whose name does not start with an underscore is
a method module; importing the package imports them all, and each registers
itself with :func:`polcam.separation._registry.register`.
"""

from __future__ import annotations

import importlib
import pkgutil

from polcam.separation._registry import (
    Separation,
    default_method,
    input_form,
    method_spec,
    methods,
    register,
    separate,
)

for _mod in pkgutil.iter_modules(__path__):
    if not _mod.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_mod.name}")

#: Registered separation method names.


def __getattr__(name: str) -> tuple[str, ...]:
    """``METHODS``: the registered method names now (:func:`methods`), so a later :func:`register` shows."""
    if name == "METHODS":
        return methods()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["METHODS", "Separation", "default_method", "input_form", "method_spec", "methods", "register",
           "separate"]
