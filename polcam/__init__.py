"""polcam: polarization cameras, from raw sensor frames to diffuse and specular layers.

The pipeline (docs/architecture.md): raw frame -> :func:`demosaic` -> stack
(4 angles x H x W [x RGB]) -> :mod:`polcam.stokes` -> :func:`separate`.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from polcam import stokes
from polcam.demosaicing import DEMOSAIC_METHODS, demosaic
from polcam.errors import PolcamError
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout
from polcam.separation import METHODS, Separation, separate



def __getattr__(name: str):  # lazy: polcam.io pulls in OpenImageIO and rawpy
    if name in ("read_frame", "write_image"):
        from polcam import io

        return getattr(io, name)
    raise AttributeError(f"module 'polcam' has no attribute {name!r}")


try:
    __version__ = version("polcam")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = [
    "DEMOSAIC_METHODS",
    "METHODS",
    "Separation",
    "separate",
    "Frame",
    "Layout",
    "PolcamError",
    "__version__",
    "demosaic",
    "parse_layout",
    "read_frame",
    "stokes",
    "write_image",
]
