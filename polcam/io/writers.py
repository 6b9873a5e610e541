"""Write polcam's outputs (float layers) and raw frames, atomically.

:func:`write_image` writes linear float images (diffuse, specular, S0, DoLP,
AoLP) as OpenEXR or TIFF through OpenImageIO:

``.exr``
    32-bit float (default) or half (``dtype="half"``; values beyond the half
    range, |x| > 65504, are refused rather than turned into inf).  Metadata
    goes into string attributes ``polcam:<key>`` holding the JSON encoding of
    each value (OpenEXR keeps custom attributes).
``.tif`` / ``.tiff``
    32-bit float (default) or ``dtype="uint16"``: values in [0, 1] scaled to
    0..65535 with rounding, values outside [0, 1] clipped.  OpenImageIO's TIFF
    writer drops custom attributes, so the metadata is stored as one JSON
    object in the ``ImageDescription`` tag.  Float TIFFs are deflate-compressed
    without the floating-point predictor, so tifffile (without imagecodecs) and
    OpenCV read them as installed with polcam.

Arrays are (H, W) or (H, W, C) with C in 1..4, floating point; channels are
named ``Y`` (one), ``Y, A`` (two), ``R, G, B`` (three) or ``R, G, B, A``
(four).  NaN and inf are refused.  A 2-D array is passed to OpenImageIO as
(H, W, 1): OpenImageIO 3.2 wrote a plain 2-D uint16 array transposed.

:func:`read_image` reads such a file back as float32 plus its polcam
metadata.  :func:`write_frame` writes a raw :class:`polcam.frame.Frame`
losslessly (``.raw`` dump in the frame's pixel-format packing, uncompressed
``.tif``, ``.png`` or ``.npy``) with its sidecar; both files are written to
temporary names and renamed into place together at the end, so an error
leaves neither half-written.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from collections.abc import Mapping
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from polcam.errors import FrameReadError, FrameWriteError, PixelFormatError
from polcam.frame import Frame
from polcam.io.atomic import atomic_path, atomic_write
from polcam.io.decoders import read_pixels
from polcam.io.packing import pack
from polcam.io.readers import deinterleave_angles
from polcam.io.sidecar import dumps_metadata, json_value, sidecar_path, validate_metadata
from polcam.mosaic import pixel_format as lookup_pixel_format

__all__ = ["IMAGE_EXTENSIONS", "FRAME_EXTENSIONS", "read_image", "write_frame", "write_image"]

#: Extensions :func:`write_image` writes.
IMAGE_EXTENSIONS: tuple[str, ...] = (".exr", ".tif", ".tiff")
#: Extensions :func:`write_frame` writes.
FRAME_EXTENSIONS: tuple[str, ...] = (".raw", ".bin", ".tif", ".tiff", ".png", ".npy")

_DTYPES = {
    ".exr": {None: "float32", "float32": "float32", "float": "float32", "half": "half", "float16": "half"},
    ".tif": {None: "float32", "float32": "float32", "float": "float32", "uint16": "uint16"},
}
_DTYPES[".tiff"] = _DTYPES[".tif"]
_CHANNEL_NAMES = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
_HALF_MAX = 65504.0
_ATTR_PREFIX = "polcam:"


def _oiio():
    import OpenImageIO as oiio

    return oiio


def _oiio_failure(message: str, folder: Path) -> str:
    """OpenImageIO's message, plus the likely cause it does not name (a full or read-only disk)."""
    try:
        if shutil.disk_usage(folder).free < 64 * 1024:
            return f"{message} ({os.strerror(errno.ENOSPC)})"
    except OSError:
        pass
    return message


def _write_oiio(tmp: Path, target: Path, pixels: np.ndarray, spec: Any) -> None:
    """Write (H, W, C) ``pixels`` with ``spec`` to ``tmp``; OIIO errors name ``target``."""
    oiio = _oiio()
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        raise FrameWriteError(f"OpenImageIO cannot write this file type: {oiio.geterror()}", path=target)
    try:
        if not out.open(str(tmp), spec):
            raise FrameWriteError(f"cannot write: {out.geterror() or oiio.geterror()}", path=target)
        ok = out.write_image(np.ascontiguousarray(pixels))
        if not ok:
            raise FrameWriteError(_oiio_failure(f"cannot write: {out.geterror() or oiio.geterror()}",
                                                tmp.parent), path=target)
    finally:
        closed = out.close()
    if not closed:
        raise FrameWriteError(_oiio_failure(f"cannot write: {out.geterror() or oiio.geterror()}",
                                            tmp.parent), path=target)


def _check_float_image(arr: np.ndarray, target: Path) -> np.ndarray:
    if not isinstance(arr, np.ndarray):
        arr = np.asarray(arr)
    if arr.dtype.kind != "f":
        raise FrameWriteError(
            f"image array has dtype {arr.dtype}: expected floating point (linear values); "
            "write raw integer mosaics with write_frame",
            path=target,
        )
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or not 1 <= arr.shape[2] <= 4 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise FrameWriteError(
            f"image array has shape {arr.shape}: expected (H, W) or (H, W, C) with C in 1..4 and H, W > 0",
            path=target,
        )
    finite = np.isfinite(arr)
    if not finite.all():
        bad = int(arr.size - np.count_nonzero(finite))
        r, c, ch = (int(i) for i in np.argwhere(~finite)[0])
        raise FrameWriteError(
            f"image holds {bad} NaN/inf values (first at row {r}, column {c}, channel {ch}): "
            "expected finite values",
            path=target,
        )
    return arr


def write_image(
    path: str | PathLike[str],
    array: np.ndarray,
    *,
    metadata: Mapping[str, Any] | None = None,
    dtype: str | None = None,
) -> Path:
    """Write a float image as EXR or TIFF, atomically.

    Parameters
    ----------
    path
        Target file; ``.exr``, ``.tif`` or ``.tiff``.  Its folder must exist.
    array
        (H, W) or (H, W, C), C in 1..4, floating point, finite.  For
        ``dtype="uint16"`` the meaningful range is [0, 1].
    metadata
        JSON-serialisable values stored with the image (EXR: attributes
        ``polcam:<key>``; TIFF: JSON in ``ImageDescription``).
    dtype
        EXR: ``"float32"`` (default) or ``"half"``.  TIFF: ``"float32"``
        (default) or ``"uint16"`` (``round(clip(x, 0, 1) * 65535)``).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    FrameWriteError
        Unsupported extension or dtype, bad shape or dtype, NaN/inf, values
        beyond the half range, metadata that is not JSON serialisable, or an
        unwritable target (full disk, read-only folder, ...).
    """
    target = Path(path)
    ext = target.suffix.lower()
    if ext not in IMAGE_EXTENSIONS:
        raise FrameWriteError(
            f"unsupported output type {ext or '(no extension)'!r}; supported: {', '.join(IMAGE_EXTENSIONS)}",
            path=target,
        )
    kinds = _DTYPES[ext]
    if dtype not in kinds:
        allowed = ", ".join(repr(k) for k in kinds if k is not None)
        raise FrameWriteError(f"dtype {dtype!r} for {ext}: expected one of {allowed}", path=target)
    kind = kinds[dtype]
    arr = _check_float_image(array, target)
    meta = dict(metadata or {})
    oiio = _oiio()
    h, w, c = arr.shape
    if kind == "half":
        peak = float(np.max(np.abs(arr)))
        if peak > _HALF_MAX:
            raise FrameWriteError(
                f"values reach magnitude {peak:g}, beyond the half-float range (max {_HALF_MAX:g}); "
                "use dtype='float32'",
                path=target,
            )
        pixels, fmt = arr.astype(np.float32), oiio.HALF
    elif kind == "uint16":
        with np.errstate(invalid="ignore"):
            scaled = np.rint(np.clip(arr.astype(np.float64), 0.0, 1.0) * 65535.0)
        pixels, fmt = scaled.astype(np.uint16), oiio.UINT16
    else:
        pixels, fmt = arr.astype(np.float32), oiio.FLOAT
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.channelnames = _CHANNEL_NAMES[c]
    if ext == ".exr":
        for key, value in meta.items():
            spec.attribute(_ATTR_PREFIX + str(key), json_value(str(key), value, path=target))
    else:
        if meta:
            spec.attribute("ImageDescription", dumps_metadata(meta, path=target, indent=None))
        if kind != "uint16":
            # deflate without the floating-point predictor: OpenImageIO's default for float TIFFs,
            # which tifffile cannot decode without imagecodecs (and OpenCV and PIL not at all)
            spec.attribute("tiff:Predictor", 1)
    with atomic_path(target) as tmp:
        _write_oiio(tmp, target, pixels, spec)
    return target


def read_image(path: str | PathLike[str]) -> tuple[np.ndarray, dict[str, Any]]:
    """Read an image written by :func:`write_image` (or any image OpenImageIO reads).

    Parameters
    ----------
    path
        EXR, TIFF, PNG, ... file.

    Returns
    -------
    image : numpy.ndarray
        float32, (H, W) for one channel, else (H, W, C).  Integer files are
        normalised by OpenImageIO (uint16: value / 65535).
    metadata : dict
        The polcam metadata: EXR ``polcam:<key>`` attributes decoded from
        JSON, or the JSON object in ``ImageDescription``; empty if none.

    Raises
    ------
    FrameReadError
        Missing, empty, unreadable or truncated file.
    """
    p = Path(path)
    if not p.exists():
        raise FrameReadError("file not found", path=p)
    if p.is_dir():
        raise FrameReadError("is a folder, expected an image file", path=p)
    if p.stat().st_size == 0:
        raise FrameReadError("file is empty (0 bytes)", path=p)
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(p))
    if inp is None:
        raise FrameReadError(f"cannot read image: {oiio.geterror() or 'unknown error'}", path=p)
    try:
        spec = inp.spec()
        arr, attrs = read_pixels(inp, spec.nchannels, oiio.FLOAT, p)
    finally:
        inp.close()
    image = np.asarray(arr, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    if spec.nchannels == 1:
        image = image[:, :, 0]
    meta: dict[str, Any] = {}
    desc = attrs.get("ImageDescription")
    if isinstance(desc, str) and desc.strip().startswith("{"):
        with contextlib.suppress(json.JSONDecodeError):
            loaded = json.loads(desc)
            if isinstance(loaded, dict):
                meta.update(loaded)
    for name, value in attrs.items():
        if name.startswith(_ATTR_PREFIX) and isinstance(value, str):
            key = name[len(_ATTR_PREFIX):]
            try:
                meta[key] = json.loads(value)
            except json.JSONDecodeError:
                meta[key] = value
    return np.ascontiguousarray(image), meta


def write_frame(path: str | PathLike[str], frame: Frame) -> Path:
    """Write a raw frame losslessly, with its sidecar ``<stem>.json``.

    Parameters
    ----------
    path
        Target file; the extension picks the container:

        ``.raw`` / ``.bin``
            headerless dump.  When ``frame.metadata`` names a
            ``pixel_format``, the mosaic is packed in that format's packing
            (LUCID ``PolarizedAngles_*`` frames are split back into four
            angle planes first, so :func:`read_frame` re-interleaves them);
            otherwise 8-bit (``uint8`` mosaics) or 16-bit little-endian.
        ``.tif`` / ``.tiff``
            uncompressed 8/16-bit greyscale; the sidecar JSON is also
            embedded in ``ImageDescription``.
        ``.png``
            8/16-bit greyscale (lossless), sidecar JSON also in the
            description text.
        ``.npy``
            the ``uint8``/``uint16`` array.
    frame
        The frame; ``mosaic`` (H, W) ``uint8`` or ``uint16`` counts.

    Returns
    -------
    pathlib.Path
        The frame file written (its sidecar is ``sidecar_path(path)``).

    Notes
    -----
    The frame holds counts, so the sidecar is written with
    ``msb_aligned: false`` whatever the source said.

    Raises
    ------
    FrameWriteError
        Unsupported extension, a mosaic that is not 2-D unsigned 8/16-bit,
        values that do not fit the pixel format, a pixel format that cannot
        be written, or an unwritable target.
    """
    target = Path(path)
    ext = target.suffix.lower()
    if ext not in FRAME_EXTENSIONS:
        raise FrameWriteError(
            f"unsupported raw frame type {ext or '(no extension)'!r}; supported: {', '.join(FRAME_EXTENSIONS)}",
            path=target,
        )
    if not isinstance(frame, Frame):
        raise FrameWriteError(f"expected a polcam Frame, got {type(frame).__name__}", path=target)
    mosaic = np.asarray(frame.mosaic)
    if mosaic.ndim != 2 or mosaic.dtype not in (np.uint8, np.uint16):
        raise FrameWriteError(
            f"mosaic has shape {mosaic.shape} and dtype {mosaic.dtype}: expected a 2-D uint8 or uint16 array",
            path=target,
        )
    side = frame.sidecar()
    if "msb_aligned" in side:
        side["msb_aligned"] = False
    side = validate_metadata(side, path=target, error=FrameWriteError)
    side_text = dumps_metadata(side, path=target) + "\n"

    if ext in (".raw", ".bin"):
        name = frame.metadata.get("pixel_format")
        if name:
            try:
                fmt = lookup_pixel_format(name, frame.metadata.get("vendor"))
            except PixelFormatError as exc:
                raise FrameWriteError(exc.reason, path=target) from None
            values = mosaic
            if fmt.kind == "derived":
                raise FrameWriteError(f"pixel format {fmt.name} is not a raw mosaic format", path=target)
            if fmt.kind == "angles":
                if frame.layout is None or frame.layout.angles != (0, 45, 135, 90):
                    raise FrameWriteError(
                        f"pixel format {fmt.name} stores angle planes; expected the frame's layout to "
                        f"have the cell 0,45 / 135,90 (as read_frame produces), got {frame.layout}",
                        path=target,
                    )
                values = deinterleave_angles(mosaic)
            try:
                payload = pack(values, packing=fmt.packing)
            except FrameWriteError as exc:
                raise FrameWriteError(f"{exc.reason} (pixel format {fmt.name})", path=target) from None
        else:
            payload = mosaic.astype("<u2").tobytes() if mosaic.dtype == np.uint16 else mosaic.tobytes()
    with contextlib.ExitStack() as stack:
        if ext in (".raw", ".bin"):
            fh = stack.enter_context(atomic_write(target, "wb"))
            fh.write(payload)
        elif ext == ".npy":
            fh = stack.enter_context(atomic_write(target, "wb"))
            np.save(fh, np.ascontiguousarray(mosaic), allow_pickle=False)
        else:
            oiio = _oiio()
            tmp = stack.enter_context(atomic_path(target))
            h, w = mosaic.shape
            spec = oiio.ImageSpec(w, h, 1, oiio.UINT8 if mosaic.dtype == np.uint8 else oiio.UINT16)
            spec.channelnames = ("Y",)
            spec.attribute("ImageDescription", dumps_metadata(side, path=target, indent=None))
            if ext in (".tif", ".tiff"):
                spec.attribute("compression", "none")
            _write_oiio(tmp, target, mosaic[:, :, None], spec)
        # the sidecar's context is entered last, so it is renamed first when both succeed
        side_fh = stack.enter_context(atomic_write(sidecar_path(target), "w"))
        side_fh.write(side_text)
    return target
