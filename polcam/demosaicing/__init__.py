"""Demosaicing of polarization (and colour-polarization) mosaics: one module per method.

``demosaic(raw, layout=..., method=None)`` turns an (H, W) mosaic into the stack
every later stage uses: (4, H, W) for a mono layout, (4, H, W, 3) RGB for a
colour layout, angle order 0, 45, 90, 135 degrees, linear float32.  Without a
method it runs the registry's best one for the layout (:func:`default_method`).
:func:`mosaic_stack` is the forward model (a full stack sampled the way a sensor
of a given layout samples it), used by the benchmarks and the tests.

Every module in this package whose name does not start with an underscore is a
method module; importing the package imports them all, and each registers itself with
:func:`register`.  The ``lmmse`` training and model selection are tooling, beside
the benchmarks (:mod:`polcam.bench.lmmse_training`, :mod:`polcam.bench.demosaic_validation`).
docs/methods/demosaicing.md describes the methods.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

from polcam.demosaicing._registry import (
    RESOLUTIONS,
    MethodSpec,
    ResolvedDemosaic,
    default_method,
    demosaic,
    method_spec,
    methods,
    mosaic_stack,
    register,
    resolve_demosaic,
    to_float,
    unregister,
)

#: Modules of this package that are not methods.
_NOT_METHODS = frozenset({"photos", "training", "validation"})

for _mod in pkgutil.iter_modules(__path__):
    if not _mod.name.startswith("_") and _mod.name not in _NOT_METHODS:
        importlib.import_module(f"{__name__}.{_mod.name}")


def __getattr__(name: str) -> Any:
    # DEMOSAIC_METHODS is read from the registry each time, so it lists methods
    # registered after import too
    if name == "DEMOSAIC_METHODS":
        return methods()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DEMOSAIC_METHODS", "RESOLUTIONS", "MethodSpec", "ResolvedDemosaic", "default_method", "demosaic",
           "method_spec", "methods", "mosaic_stack", "register", "resolve_demosaic", "to_float", "unregister"]
