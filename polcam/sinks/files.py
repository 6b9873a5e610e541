"""Result files: one output format table and one way to write a frame's products.

``polcam process`` and ``polcam stokes`` write, per frame, one image file per
product (``OUT/<frame>/<product>.<ext>``) and a ``meta.json`` written last, so
its presence marks a finished frame.  Every file is written atomically
(:mod:`polcam.io.atomic`): a crash leaves whole files or none.

Formats (:data:`FORMATS`):

- ``exr``: float32 OpenEXR (the default; metadata as EXR attributes);
- ``tiff``: float32 TIFF (metadata as JSON in the ImageDescription tag);
- ``tiff16``: uint16 TIFF for the products whose values lie in [0, 1]
  (scaled from [0, 1] to [0, 65535]); the other products (signed, or above
  1 like S0) stay float32 TIFF.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from polcam.errors import FrameWriteError, MethodError

__all__ = ["FORMATS", "check_format", "extension", "write_meta", "write_products"]

#: Output format -> (file extension, dtype of the files; ``None``: the writer's default float).
FORMATS: dict[str, tuple[str, str | None]] = {
    "exr": (".exr", None),
    "tiff": (".tif", "float32"),
    "tiff16": (".tif", "uint16"),
}


def check_format(fmt: str) -> str:
    """``fmt`` if it is one of :data:`FORMATS`, else a :class:`MethodError` listing them."""
    if fmt not in FORMATS:
        raise MethodError(f"output format {fmt!r} is unknown; expected one of {', '.join(FORMATS)}")
    return fmt


def extension(fmt: str) -> str:
    """File extension of output format ``fmt`` (``.exr`` or ``.tif``)."""
    return FORMATS[check_format(fmt)][0]


def _dtype(name: str, fmt: str, unit: Iterable[str]) -> str | None:
    dtype = FORMATS[fmt][1]
    if dtype == "uint16":
        return "uint16" if name in unit else "float32"
    return dtype


def _make_folder(target: Path) -> None:
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FrameWriteError(f"cannot create the output folder: {exc.strerror}", path=target) from exc


def write_products(target: str | Path, products: Mapping[str, np.ndarray], *, fmt: str = "exr",
                   unit: Iterable[str] = (), metadata: Mapping[str, Any] | None = None) -> list[str]:
    """Write each product as ``target/<name><ext>``, atomically.

    Parameters
    ----------
    target
        Output folder of the frame (created).
    products
        Name -> image: (H, W) or (H, W, 3) float arrays.
    fmt
        One of :data:`FORMATS`.
    unit
        Names of the products whose values lie in [0, 1]: with ``tiff16``
        these are clipped to [0, 1] and stored as uint16, the others stay float32.
    metadata
        Written into every file (plus ``product``: its name).

    Returns
    -------
    list of str
        The file names written, in the order of ``products``.

    Raises
    ------
    FrameWriteError
        The folder or a file cannot be written.
    MethodError
        An unknown ``fmt``.
    """
    import polcam.io as pio  # looked up at call time (tests substitute a failing writer)

    ext = extension(fmt)
    target = Path(target)
    _make_folder(target)
    unit = tuple(unit)
    written = []
    for name, arr in products.items():
        dtype = _dtype(name, fmt, unit)  # uint16: the writer clips to [0, 1] and scales
        pio.write_image(target / f"{name}{ext}", arr, metadata={**(metadata or {}), "product": name},
                            dtype=dtype)
        written.append(f"{name}{ext}")
    return written


def write_meta(target: str | Path, meta: Mapping[str, Any]) -> Path:
    """Write ``target/meta.json`` atomically (last: it marks the frame finished); returns its path."""
    from polcam.io.atomic import atomic_write

    path = Path(target) / "meta.json"
    _make_folder(path.parent)
    with atomic_write(path, "w") as fh:
        json.dump(meta, fh, indent=2)
    return path
