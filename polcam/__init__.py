"""polcam: polarization cameras, from raw sensor frames to diffuse and specular layers.

The pipeline (docs/architecture.md): raw frame -> :func:`demosaic` -> stack
(4 angles x H x W [x RGB]) -> :func:`stokes` (and :func:`dolp`, :func:`aolp`,
:func:`imin`, :func:`imax`, from :mod:`polcam.polarimetry`) -> :func:`separate`.
"""

from __future__ import annotations

from polcam._version import __version__
from polcam.demosaicing import demosaic
from polcam.errors import PolcamError
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout
from polcam.polarimetry import Stokes, aolp, dolp, imax, imin, stokes
from polcam.separation import Separation, separate

_LAZY_IO = ("read_frame", "read_image", "write_image")


def __getattr__(name: str):
    """``METHODS`` / ``DEMOSAIC_METHODS`` read the registries now (a method registered later is listed);
    the file functions load polcam.io (OpenImageIO, rawpy) on first use."""
    if name == "METHODS":
        from polcam.separation import methods

        return methods()
    if name == "DEMOSAIC_METHODS":
        from polcam.demosaicing import methods as demosaic_methods

        return demosaic_methods()
    if name in _LAZY_IO:
        from polcam import io

        return getattr(io, name)
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
