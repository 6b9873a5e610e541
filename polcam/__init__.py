"""polcam: polarization cameras, from raw sensor frames to diffuse and specular layers.

The pipeline (docs/architecture.md): raw frame -> :func:`demosaic` -> stack
(4 angles x H x W [x RGB]) -> :func:`stokes` (and :func:`dolp`, :func:`aolp`,
:func:`imin`, :func:`imax`, from :mod:`polcam.polarimetry`) -> :func:`separate`.
"""

from __future__ import annotations

from polcam._version import __version__
from polcam.demosaicing import demosaic
from polcam.demosaicing import methods as _demosaic_methods
from polcam.errors import PolcamError
from polcam.frame import Frame
from polcam.io import read_frame, read_image, write_image
from polcam.mosaic import Layout, parse_layout
from polcam.polarimetry import Stokes, aolp, dolp, imax, imin, stokes
from polcam.separation import Separation, separate
from polcam.separation import methods as _separation_methods


def __getattr__(name: str) -> tuple[str, ...]:
    """``METHODS`` / ``DEMOSAIC_METHODS``: the registries' names now (a method registered later is listed)."""
    if name == "METHODS":
        return _separation_methods()
    if name == "DEMOSAIC_METHODS":
        return _demosaic_methods()
    raise AttributeError(f"module 'polcam' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "DEMOSAIC_METHODS",
    "METHODS",
    "Separation",
    "Stokes",
    "aolp",
    "dolp",
    "imax",
    "imin",
    "separate",
    "Frame",
    "Layout",
    "PolcamError",
    "__version__",
    "demosaic",
    "parse_layout",
    "read_frame",
    "read_image",
    "stokes",
    "write_image",
]
