"""Decoding each raw container into counts: PNG/TIFF/BMP (OpenImageIO), PGM, headerless dumps, .npy, camera raw.

One :class:`Decoder` per container in :data:`DECODERS`: its extensions, its
reader (returning a :class:`Decoded`: the counts, their container and file
bit depths, the file's own metadata) and its header-only size.
:func:`decoder_for` picks one by extension; :func:`polcam.io.readers.read_frame`
merges what it decoded with the sidecar.  Sizes a header or sidecar declares
are checked against a limit (:data:`MAX_PIXELS`) before anything that size is
allocated.  OpenImageIO and rawpy are imported by the readers that need them.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polcam.errors import FrameReadError, PixelFormatError
from polcam.io.packing import PACKING_BITS, packed_size, unpack
from polcam.io.sidecar import read_sidecar, sidecar_path, validate_metadata
from polcam.mosaic import PixelFormat
from polcam.mosaic import pixel_format as lookup_pixel_format

__all__ = ["DECODERS", "MAX_PIXELS", "RAW_EXTENSIONS", "DecodeRequest", "Decoded", "Decoder", "check_raw_file",
           "decoder_for", "deinterleave_angles", "interleave_angles", "lookup_raw_format", "read_pixels"]


_OIIO_EXTENSIONS = (".png", ".tif", ".tiff", ".bmp")
_PNM_EXTENSIONS = (".pgm", ".ppm", ".pnm")
_DUMP_EXTENSIONS = (".raw", ".bin")
_NPY_EXTENSIONS = (".npy",)
_LIBRAW_EXTENSIONS = (
    ".dng", ".nef", ".nrw", ".cr2", ".cr3", ".crw", ".arw", ".srf", ".sr2", ".orf", ".rw2",
    ".raf", ".pef", ".srw", ".3fr", ".iiq", ".erf", ".kdc", ".dcr", ".mos", ".mef", ".rwl",
)

#: Largest frame :func:`read_frame` reads by default, pixels (a 5 MP sensor has 5 M): a header or
#: sidecar declaring more is refused before anything that size is allocated (``max_pixels=`` raises it).
MAX_PIXELS: int = 1 << 27


def _check_size(w: int, h: int, max_pixels: int, p: Path, what: str) -> None:
    """Refuse a declared size of more than ``max_pixels`` pixels before allocating it."""
    if w * h > max_pixels:
        raise FrameReadError(
            f"{what} declares {w}x{h} = {w * h} pixels, more than the limit of {max_pixels} "
            "(a corrupt or hostile header?); raise the limit (--max-pixels N, max_pixels=) to read it",
            path=p)


# File attributes worth keeping from OpenImageIO's spec.
_KEPT_ATTRIBUTES = ("Make", "Model", "Software", "DateTime", "Artist", "Copyright", "HostComputer")


@dataclass
class Decoded:
    """What a decoder found in the file."""

    mosaic: np.ndarray                    # (H, W) uint8/uint16 as stored (counts)
    stored_bits: int                      # bits of the stored samples (8, 16, 12 for 12p, ...)
    format: str                           # "png", "tiff", "raw", ...
    file_meta: dict[str, Any] = field(default_factory=dict)  # sidecar-like keys the file carries
    file_bits: int | None = None          # bit depth the header states
    black_level: float | None = None
    white_level: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)     # other metadata
    white_is_limit: bool = True           # counts above the file's white level are an error
    pixel_format: PixelFormat | None = None  # the GenICam format a dump was unpacked with


@dataclass(frozen=True)
class DecodeRequest:
    """What a decoder may use besides the file: the sidecar and keyword values (``options``), where
    each came from (``sources``: key -> words for messages), and the largest frame to allocate."""

    options: dict[str, Any] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)
    max_pixels: int = MAX_PIXELS


# ------------------------------------------------------------------ helpers
def interleave_angles(planes: np.ndarray) -> np.ndarray:
    """Re-interleave four angle planes into a 2x2-cell mosaic.

    Parameters
    ----------
    planes
        (h, w, 4) array, channels in the order 0, 45, 90, 135 degrees
        (LUCID ``PolarizedAngles_0d_45d_90d_135d_*``).

    Returns
    -------
    numpy.ndarray
        (2h, 2w) mosaic of the same dtype with the cell ``0 45 / 135 90``.
    """
    h, w, _ = planes.shape
    out = np.empty((2 * h, 2 * w), dtype=planes.dtype)
    out[0::2, 0::2] = planes[..., 0]
    out[0::2, 1::2] = planes[..., 1]
    out[1::2, 1::2] = planes[..., 2]
    out[1::2, 0::2] = planes[..., 3]
    return out


def deinterleave_angles(mosaic: np.ndarray) -> np.ndarray:
    """Inverse of :func:`interleave_angles`: (2h, 2w) mosaic -> (h, w, 4) planes 0, 45, 90, 135."""
    return np.stack(
        [mosaic[0::2, 0::2], mosaic[0::2, 1::2], mosaic[1::2, 1::2], mosaic[1::2, 0::2]], axis=-1
    )


def lookup_raw_format(name: str, vendor: str | None, path: Path) -> PixelFormat:
    """The pixel format ``name`` of ``vendor``, refused (naming ``path``) when unknown or computed in the camera."""
    try:
        fmt = lookup_pixel_format(name, vendor)
    except PixelFormatError as exc:
        raise PixelFormatError(exc.reason, path=path) from None
    if fmt.kind == "derived":
        raise PixelFormatError(
            f"pixel format {fmt.name} carries values computed in the camera (Stokes, DoLP or AoLP), "
            "not a raw mosaic; capture a raw polarization format instead",
            path=path,
        )
    return fmt


def _parse_description(text: str, path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(file_meta, extra) from an ImageDescription: polcam JSON or plain text."""
    stripped = text.strip()
    if stripped.startswith("{"):
        try:
            data = json.loads(stripped)
        except json.JSONDecodeError:
            data = None
        if isinstance(data, dict):
            return validate_metadata(data, path=path, source="the file's ImageDescription JSON"), {}
    return {}, {"description": text}


def _first_line(text: str) -> str:
    """A library's error as one line: its first line, and how many more it had (OpenImageIO repeats
    a truncated file's error once per scanline)."""
    lines = [ln.strip() for ln in str(text).splitlines() if ln.strip()]
    if not lines:
        return "unknown error"
    more = f" (and {len(lines) - 1} more lines like it)" if len(lines) > 1 else ""
    return lines[0][:300] + more


def read_pixels(inp: Any, nchannels: int, fmt: Any, p: Path) -> tuple[Any, dict[str, Any]]:
    """All pixels of an open OpenImageIO ``inp`` as ``fmt`` and its extra attributes (name -> value).

    Raises :class:`FrameReadError` naming ``p`` when the pixels cannot be read (truncated or corrupt).
    """
    arr = inp.read_image(0, 0, 0, nchannels, fmt)
    err = inp.geterror()
    if arr is None or err:
        raise FrameReadError(
            f"cannot read the pixels (truncated or corrupt file?): {_first_line(err)}", path=p
        )
    return arr, {a.name: a.value for a in inp.spec().extra_attribs}


def check_raw_file(p: Path) -> None:
    """Refuse a missing path, a folder or an empty file, naming it."""
    if not p.exists():
        raise FrameReadError("file not found", path=p)
    if p.is_dir():
        raise FrameReadError("is a folder, expected a raw frame file", path=p)
    try:
        size = p.stat().st_size
    except OSError as exc:
        raise FrameReadError(f"cannot read: {exc.strerror or exc}", path=p) from exc
    if size == 0:
        raise FrameReadError("file is empty (0 bytes)", path=p)


# ------------------------------------------------------------ format readers
def _read_oiio(p: Path, req: DecodeRequest) -> Decoded:
    max_pixels = req.max_pixels
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(p))
    if inp is None:
        raise FrameReadError(f"cannot read image (corrupt or truncated file?): {_first_line(oiio.geterror())}",
                             path=p)
    try:
        spec = inp.spec()
        fmt_name = inp.format_name()
        _check_size(spec.width, spec.height, max_pixels, p, "the image header")
        if spec.nchannels != 1:
            names = ", ".join(spec.channelnames)
            raise FrameReadError(
                f"image has {spec.nchannels} channels ({names}): a raw sensor mosaic has exactly one "
                "channel; this is a colour or demosaiced image, not a raw mosaic",
                path=p,
            )
        if spec.format == oiio.UINT8:
            container = 8
        elif spec.format == oiio.UINT16:
            container = 16
        else:
            raise FrameReadError(
                f"image stores {spec.format} samples: expected 8- or 16-bit unsigned integers "
                "(raw sensor counts)",
                path=p,
            )
        arr, attrs = read_pixels(inp, 1, spec.format, p)
    finally:
        inp.close()
    mosaic = np.ascontiguousarray(np.asarray(arr).reshape(spec.height, spec.width))
    file_bits = int(attrs.get("oiio:BitsPerSample", 0) or 0)
    stored_bits = container
    if 0 < file_bits < container:
        # OpenImageIO expands n-bit samples to the full container range; map back to counts.
        top = (1 << file_bits) - 1
        full = (1 << container) - 1
        counts = (mosaic.astype(np.uint32) * top + full // 2) // full
        mosaic = counts.astype(mosaic.dtype)
        stored_bits = file_bits
    elif file_bits <= 0:
        file_bits = container
    file_meta: dict[str, Any] = {}
    extra: dict[str, Any] = {}
    desc = attrs.get("ImageDescription")
    if isinstance(desc, str) and desc:
        file_meta, extra = _parse_description(desc, p)
    kept = {k: attrs[k] for k in _KEPT_ATTRIBUTES if k in attrs}
    if kept:
        extra["file_attributes"] = kept
    return Decoded(mosaic, stored_bits, fmt_name, file_meta, file_bits, extra=extra)


_PNM_TOKEN = re.compile(rb"\s*(?:#[^\n\r]*[\n\r]\s*)*(\S+)")


def _read_pnm(p: Path, req: DecodeRequest) -> Decoded:
    max_pixels = req.max_pixels
    data = p.read_bytes()
    magic = data[:2]
    if magic in (b"P3", b"P6"):
        raise FrameReadError(
            "PPM colour image has 3 channels: a raw sensor mosaic has one channel; "
            "this is a colour or demosaiced image, not a raw mosaic",
            path=p,
        )
    if magic in (b"P1", b"P4"):
        raise FrameReadError("PBM bitmap (1 bit per pixel) is not a raw sensor mosaic", path=p)
    if magic not in (b"P2", b"P5"):
        raise FrameReadError(
            f"not a PGM file (magic {magic!r}): expected binary 'P5' or ASCII 'P2' greyscale", path=p
        )
    pos = 2
    header: list[int] = []
    for what in ("width", "height", "maxval"):
        m = _PNM_TOKEN.match(data, pos)
        if not m or not m.group(1).isdigit():
            raise FrameReadError(f"PGM header is truncated or malformed: no {what}", path=p)
        header.append(int(m.group(1)))
        pos = m.end()
    w, h, maxval = header
    if w <= 0 or h <= 0:
        raise FrameReadError(f"PGM header gives size {w}x{h}: expected positive sizes", path=p)
    if not 1 <= maxval <= 65535:
        raise FrameReadError(f"PGM maxval {maxval}: expected 1 to 65535", path=p)
    _check_size(w, h, max_pixels, p, "the PGM header")
    n = w * h
    dtype = np.uint8 if maxval < 256 else np.uint16
    if magic == b"P5":
        raster = data[pos + 1:]  # exactly one whitespace byte after maxval
        bps = 1 if maxval < 256 else 2
        if len(raster) < n * bps:
            raise FrameReadError(
                f"truncated PGM: expected {n * bps} bytes of pixel data for {w}x{h} "
                f"(maxval {maxval}), found {len(raster)}",
                path=p,
            )
        arr = np.frombuffer(raster, dtype=">u2" if bps == 2 else np.uint8, count=n)
    else:
        tokens = data[pos:].split()
        if len(tokens) < n:
            raise FrameReadError(
                f"truncated PGM: expected {n} values for {w}x{h}, found {len(tokens)}", path=p
            )
        try:
            arr = np.array([int(t) for t in tokens[:n]], dtype=np.int64)
        except ValueError:
            raise FrameReadError("ASCII PGM holds a value that is not an integer", path=p) from None
    mosaic = arr.astype(dtype).reshape(h, w)
    mx = int(arr.max()) if arr.size else 0
    if mx > maxval:
        raise FrameReadError(f"PGM holds value {mx}, above its maxval {maxval}", path=p)
    bits = maxval.bit_length()
    return Decoded(mosaic, 8 if dtype == np.uint8 else 16, "pnm", file_bits=bits,
                    white_level=float(maxval))


def _read_dump(p: Path, req: DecodeRequest) -> Decoded:
    opts, sources, max_pixels = req.options, req.sources, req.max_pixels
    w, h = opts.get("width"), opts.get("height")
    side = sidecar_path(p).name
    if w is None or h is None:
        raise FrameReadError(
            f"a headerless {p.suffix} dump needs its width and height: give them in the sidecar "
            f"{side} (keys 'width', 'height', 'pixel_format') or as width=/height= (--width/--height)",
            path=p,
        )
    _check_size(int(w), int(h), max_pixels, p, f"{sources.get('width', 'the keywords')}")
    data = np.fromfile(p, dtype=np.uint8)
    where = f" (width/height from {sources.get('width', 'the keywords')})"
    name = opts.get("pixel_format")
    if name is None:
        if data.size == w * h:
            return Decoded(data.reshape(h, w).copy(), 8, "raw")
        if data.size == 2 * w * h:
            return Decoded(data.view("<u2").astype(np.uint16).reshape(h, w), 16, "raw")
        raise FrameReadError(
            f"expected {w * h} bytes (8-bit) or {2 * w * h} bytes (16-bit little-endian) for a "
            f"{w}x{h} frame{where}, found {data.size} bytes; for packed formats give the "
            "pixel_format (sidecar key or keyword)",
            path=p,
        )
    fmt = lookup_raw_format(name, opts.get("vendor"), p)
    bits = PACKING_BITS[fmt.packing]
    if fmt.kind == "angles":
        n_cam = packed_size(fmt.packing, w * h * 4)
        n_mosaic = packed_size(fmt.packing, w * h)
        if data.size == n_cam:
            hw, hh = w, h
        elif w % 2 == 0 and h % 2 == 0 and data.size == n_mosaic:
            hw, hh = w // 2, h // 2
        else:
            raise FrameReadError(
                f"expected {n_cam} bytes ({w}x{h} pixels x 4 angles, the camera's half-resolution "
                f"size) or {n_mosaic} bytes (a {w}x{h} re-interleaved mosaic) for pixel format "
                f"{fmt.name}{where}, found {data.size} bytes",
                path=p,
            )
        planes = unpack(data, packing=fmt.packing, width=hw, height=hh, channels=4, path=p)
        return Decoded(interleave_angles(planes), bits, "raw", pixel_format=fmt)
    expected = packed_size(fmt.packing, w * h)
    if data.size != expected:
        raise FrameReadError(
            f"expected {expected} bytes for a {w}x{h} frame in pixel format {fmt.name} "
            f"(packing {fmt.packing!r}){where}, found {data.size} bytes",
            path=p,
        )
    return Decoded(unpack(data, packing=fmt.packing, width=w, height=h, path=p), bits, "raw",
                   pixel_format=fmt)


def _read_npy(p: Path, req: DecodeRequest) -> Decoded:
    opts = req.options
    try:
        arr = np.load(p, allow_pickle=False)
    except ValueError as exc:
        if "pickle" in str(exc).lower() or "object" in str(exc).lower():
            raise FrameReadError(
                "array holds Python objects (dtype object), which polcam refuses to load "
                "(allow_pickle=False); save a numeric array",
                path=p,
            ) from exc
        raise FrameReadError(f"cannot read .npy (truncated or corrupt file?): {exc}", path=p) from exc
    except (OSError, EOFError) as exc:
        raise FrameReadError(f"cannot read .npy (truncated or corrupt file?): {exc}", path=p) from exc
    if not isinstance(arr, np.ndarray):
        raise FrameReadError(f"file holds a {type(arr).__name__}, expected one .npy array", path=p)
    if arr.ndim != 2:
        raise FrameReadError(
            f"array has shape {arr.shape} ({arr.ndim}-D): expected a 2-D (height, width) mosaic", path=p
        )
    kind = arr.dtype.kind
    if kind in "ui":
        if arr.size and int(arr.min()) < 0:
            raise FrameReadError(f"array holds negative values (min {int(arr.min())}): expected counts >= 0",
                                 path=p)
        if arr.dtype.itemsize == 1:
            return Decoded(arr.astype(np.uint8), 8, "npy")
        mx = int(arr.max()) if arr.size else 0
        if mx > 65535:
            raise FrameReadError(f"array holds value {mx}: expected counts up to 65535 (16 bits)", path=p)
        return Decoded(arr.astype(np.uint16), 16, "npy")
    if kind == "f":
        finite = np.isfinite(arr)
        if not finite.all():
            bad = int(arr.size - np.count_nonzero(finite))
            r, c = (int(i) for i in np.argwhere(~finite)[0])
            raise FrameReadError(
                f"float array holds {bad} NaN/inf values (first at row {r}, column {c}): "
                "expected finite counts",
                path=p,
            )
        if opts.get("white_level") is None:
            raise FrameReadError(
                f"float array ({arr.dtype}) has no bit depth of its own: give white_level "
                "(sidecar key or keyword) to read it, or save integer counts",
                path=p,
            )
        if arr.size and float(arr.min()) < 0:
            raise FrameReadError(f"array holds negative values (min {float(arr.min())}): expected counts >= 0",
                                 path=p)
        if arr.size and float(arr.max()) > 65535:
            raise FrameReadError(f"array holds value {float(arr.max())}: expected counts up to 65535", path=p)
        if not np.array_equal(arr, np.round(arr)):
            raise FrameReadError(
                "float array holds fractional values: expected whole-number counts "
                "(a Frame holds integer sensor counts; normalised data cannot be read as a raw frame)",
                path=p,
            )
        counts = arr.astype(np.uint16)
        # no bit depth of its own: that of the white level (or of the largest count)
        bits = max(int(float(opts["white_level"])).bit_length(), int(counts.max()).bit_length(), 1)
        return Decoded(counts, 16, "npy", file_bits=min(bits, 16))
    raise FrameReadError(f"array dtype {arr.dtype}: expected integer counts (or float with white_level)",
                         path=p)


def _read_libraw(p: Path, req: DecodeRequest) -> Decoded:
    import rawpy

    try:
        with rawpy.imread(str(p)) as raw:
            if raw.raw_type != rawpy.RawType.Flat:
                raise FrameReadError(
                    "LibRaw reports an image that is already demosaiced (e.g. LinearRaw DNG, "
                    f"raw type {raw.raw_type.name}), not a CFA or polarizer mosaic",
                    path=p,
                )
            mosaic = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
            black = float(np.mean(raw.black_level_per_channel))
            white = float(raw.white_level)
            extra: dict[str, Any] = {}
            try:
                extra["cfa_pattern"] = raw.raw_pattern.tolist() if raw.raw_pattern is not None else None
                extra["color_desc"] = raw.color_desc.decode("ascii", "replace")
            except Exception:  # pragma: no cover - informational only
                pass
    except rawpy.LibRawError as exc:
        raise FrameReadError(f"LibRaw cannot read this file ({type(exc).__name__}: {exc})", path=p) from exc
    # LibRaw's white level is its estimate of saturation; a few cameras record counts above it,
    # so the bit depth covers both and values above it are not refused (see read_frame).
    data_max = int(mosaic.max()) if mosaic.size else 0
    bits = max(int(white).bit_length() if white > 0 else 0, data_max.bit_length(), 1)
    return Decoded(mosaic, 16, p.suffix.lower().lstrip("."), file_bits=min(bits, 16),
                    black_level=black, white_level=white, extra=extra, white_is_limit=False)


# ------------------------------------------------- sizes from the header alone
def _oiio_size(p: Path) -> tuple[int, int] | None:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(p))
    if inp is None:
        oiio.geterror()  # consumed: the frame's own read reports it
        return None
    try:
        spec = inp.spec()
        return int(spec.width), int(spec.height)
    finally:
        inp.close()


def _pnm_size(p: Path) -> tuple[int, int] | None:
    with open(p, "rb") as fh:
        head = fh.read(1024)
    m = re.match(rb"P[25]\s*(?:#[^\n\r]*[\n\r]\s*)*(\d+)\s*(?:#[^\n\r]*[\n\r]\s*)*(\d+)", head)
    return (int(m.group(1)), int(m.group(2))) if m else None


def _npy_size(p: Path) -> tuple[int, int] | None:
    with open(p, "rb") as fh:
        version = np.lib.format.read_magic(fh)
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape = read(fh)[0]
    return (int(shape[1]), int(shape[0])) if len(shape) == 2 else None


def _dump_size(p: Path) -> tuple[int, int] | None:
    side = read_sidecar(p) or {}
    if side.get("width") and side.get("height"):
        return int(side["width"]), int(side["height"])
    return None


def _libraw_size(p: Path) -> tuple[int, int] | None:
    return None  # LibRaw tells the size only by opening (and unpacking) the file


# ------------------------------------------------------------------ the table
@dataclass(frozen=True)
class Decoder:
    """One raw container: its extensions, its reader and its header-only size.

    ``decode(path, request)`` returns the :class:`Decoded` counts; ``size(path)``
    the declared ``(width, height)`` without reading the pixels, or None.
    ``sized_by_metadata``: the frame size comes from the sidecar or keywords
    (headerless dumps) rather than from the file.
    """

    name: str
    extensions: tuple[str, ...]
    decode: Callable[[Path, DecodeRequest], Decoded]
    size: Callable[[Path], tuple[int, int] | None]
    sized_by_metadata: bool = False


#: Every container polcam reads, in the order :data:`RAW_EXTENSIONS` lists their extensions.
DECODERS: tuple[Decoder, ...] = (
    Decoder("OpenImageIO", _OIIO_EXTENSIONS, _read_oiio, _oiio_size),
    Decoder("PNM", _PNM_EXTENSIONS, _read_pnm, _pnm_size),
    Decoder("headerless dump", _DUMP_EXTENSIONS, _read_dump, _dump_size, sized_by_metadata=True),
    Decoder("NumPy", _NPY_EXTENSIONS, _read_npy, _npy_size),
    Decoder("LibRaw", _LIBRAW_EXTENSIONS, _read_libraw, _libraw_size),
)

_BY_EXTENSION: dict[str, Decoder] = {ext: d for d in DECODERS for ext in d.extensions}

#: File extensions :func:`polcam.io.read_frame` accepts (lower case; matching ignores case).
RAW_EXTENSIONS: tuple[str, ...] = tuple(_BY_EXTENSION)


def decoder_for(path: str | Path) -> Decoder:
    """The decoder of a file's extension (case ignored).

    Raises
    ------
    FrameReadError
        The extension is none of :data:`RAW_EXTENSIONS` (the message lists them).
    """
    p = Path(path)
    ext = p.suffix.lower()
    try:
        return _BY_EXTENSION[ext]
    except KeyError:
        raise FrameReadError(
            f"unsupported file type {ext or '(no extension)'!r}; supported: {', '.join(RAW_EXTENSIONS)}",
            path=p) from None
