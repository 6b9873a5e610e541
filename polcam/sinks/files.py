"""Result files: one output format table and one way to write a frame's products.

``polcam process`` and ``polcam stokes`` write, per frame, one image file per
product (``OUT/<frame>/<product>.<ext>``) and a ``meta.json`` written last, so
its presence marks a finished frame.  Every file is written atomically
(:mod:`polcam.io.atomic`): a crash leaves whole files or none.
:class:`ProductFiles` is the same as a sink (:class:`polcam.sinks.base.Sink`):
one record's products, then its ``meta.json`` with the files it wrote.

Formats (:data:`FORMATS`):

- ``exr``: float32 OpenEXR (the default; metadata as EXR attributes);
- ``tiff``: float32 TIFF (metadata as JSON in the ImageDescription tag);
- ``tiff16``: uint16 TIFF for the products whose values lie in [0, 1]
  (scaled from [0, 1] to [0, 65535]); the other products (signed, or above
  1 like S0) stay float32 TIFF.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

import polcam.io as pio
from polcam._hashing import sha256_file
from polcam.errors import FrameReadError, FrameWriteError, MethodError
from polcam.io import read_frame, read_image
from polcam.io.atomic import atomic_write
from polcam.sinks.base import Record, SinkBase

__all__ = ["FOLDER_PRODUCTS", "FORMATS", "ProductFiles", "check_format", "extension", "file_record", "read_frame_folder", "write_meta",
           "write_products"]

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
    path = Path(target) / "meta.json"
    _make_folder(path.parent)
    with atomic_write(path, "w") as fh:
        json.dump(meta, fh, indent=2)
    return path


def file_record(path: str | Path) -> dict[str, Any]:
    """``{"bytes": size, "sha256": hex digest}`` of a written file (what ``meta.json`` lists)."""
    path = Path(path)
    return {"bytes": path.stat().st_size, "sha256": sha256_file(path)}


class ProductFiles(SinkBase):
    """The file sink of processed frames: a record's products into its folder, then ``meta.json``.

    Each :meth:`log` writes ``record.products`` as ``record.folder/<name><ext>``
    (:func:`write_products`), then ``record.folder/meta.json``
    (:func:`write_meta`): ``record.meta`` with ``outputs`` (the file names)
    and ``files`` (each file's size and SHA-256, :func:`file_record`) set,
    and, where ``record.meta`` has a ``timings`` mapping, ``timings["write"]``
    (seconds spent writing and hashing the products).  Every file is written
    atomically and ``meta.json`` last, so its presence marks a finished frame.

    Parameters
    ----------
    fmt
        One of :data:`FORMATS`.
    unit
        Names of the products in [0, 1] (uint16 with ``tiff16``).
    metadata
        Written into every product file (plus ``product``).
    guard
        Called before the products and again before ``meta.json`` are
        written (``polcam process``'s workers end there when their run is gone).

    Raises
    ------
    MethodError
        An unknown ``fmt`` (at construction).
    """

    def __init__(self, *, fmt: str = "exr", unit: Iterable[str] = (), metadata: Mapping[str, Any] | None = None,
                 guard: Callable[[], None] | None = None) -> None:
        self.fmt = check_format(fmt)
        self.unit = tuple(unit)
        self.metadata = dict(metadata or {})
        self.guard = guard
        #: Frame folders finished (``meta.json`` written).
        self.written: list[Path] = []

    def log(self, index: int, record: Record) -> None:
        """Write ``record``'s products and meta into ``record.folder`` (``index`` is not used: the
        folder names the frame).

        Raises
        ------
        FrameWriteError
            A file cannot be written; ``meta.json`` is then not written.
        ValueError
            A record without ``folder``.
        """
        if record.folder is None:
            raise ValueError("ProductFiles: the record has no folder to write to")
        folder = Path(record.folder)
        t = time.perf_counter()
        if self.guard is not None:
            self.guard()
        names = write_products(folder, record.products, fmt=self.fmt, unit=self.unit, metadata=self.metadata)
        files = {n: file_record(folder / n) for n in names}
        meta = dict(record.meta or {})
        meta["outputs"] = names
        meta["files"] = files
        if isinstance(meta.get("timings"), Mapping):
            meta["timings"] = {**meta["timings"], "write": time.perf_counter() - t}
        if self.guard is not None:
            self.guard()
        write_meta(folder, meta)
        self.written.append(folder)

    def close(self) -> None:
        """Nothing is held between frames: every file is complete when :meth:`log` returns."""


#: Products a ``polcam process`` frame folder holds (besides ``meta.json``), as :func:`read_frame_folder` reads them.
FOLDER_PRODUCTS: tuple[str, ...] = ("s0", "dolp", "aolp", "diffuse", "specular")


def _raw_source(folder: Path, meta: dict[str, Any]) -> Path | None:
    """The raw frame a process frame folder came from (``meta.json``'s ``input``), or None.

    ``input`` is absolute; a relative one (relative to where ``process`` ran)
    is looked for from the current folder, then from each folder above the
    frame folder, and taken only when its SHA-256 is ``input_sha256``.
    """
    src = meta.get("input")
    if not isinstance(src, str) or not src:
        return None
    given = Path(src)
    if given.is_absolute():
        return given if given.is_file() else None
    want = meta.get("input_sha256")
    for base in (Path.cwd(), *folder.resolve().parents):
        candidate = base / given
        if candidate.is_file() and (want is None or sha256_file(candidate) == want):
            return candidate
    return None


def read_frame_folder(folder: str | Path) -> Record:
    """A frame folder written by ``polcam process``, read back as a :class:`Record`.

    Reads :data:`FOLDER_PRODUCTS` (``.exr`` or ``.tif``; ``tiff16`` files
    scaled back to [0, 1]) and ``meta.json``; the raw frame named there
    (``input``) is read too when it still exists (:func:`_raw_source`), and
    its ``timestamp_ns`` becomes the record's.

    Returns
    -------
    Record
        ``products`` (float32, (h, w) or (h, w, 3)), ``frame`` (or ``None``),
        ``timestamp_ns``, ``folder``, ``meta`` (``{}`` when unreadable).

    Raises
    ------
    FrameReadError
        A product file that is missing or unreadable.
    """
    folder = Path(folder)
    products: dict[str, np.ndarray] = {}
    for name in FOLDER_PRODUCTS:
        found = [folder / f"{name}{ext}" for ext in (".exr", ".tif", ".tiff") if (folder / f"{name}{ext}").is_file()]
        if not found:
            raise FrameReadError(f"no {name}.exr or {name}.tif: expected a polcam process frame folder", path=folder)
        arr, _ = read_image(found[0])
        if arr.ndim == 3 and arr.shape[2] == 1:
            arr = arr[..., 0]
        if arr.dtype == np.uint16:  # --format tiff16: [0, 1] scaled to 0..65535
            arr = arr.astype(np.float32) / 65535.0
        products[name] = np.ascontiguousarray(arr, dtype=np.float32)
    meta: dict[str, Any] = {}
    try:
        meta = json.loads((folder / "meta.json").read_text())
    except (OSError, ValueError):
        pass
    ts = (meta.get("frame") or {}).get("timestamp_ns")
    frame = None
    src = _raw_source(folder, meta)
    if src is not None:
        try:
            frame = read_frame(src, layout=meta.get("layout"))
        except (ValueError, OSError):
            frame = None  # the view goes on without the raw panel
    return Record(frame=frame, products=products, timestamp_ns=None if ts is None else int(ts), folder=folder,
                  meta=meta)
