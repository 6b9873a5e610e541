"""Read raw polarization mosaics from files into :class:`polcam.frame.Frame`.

Formats, chosen by extension (:data:`RAW_EXTENSIONS`):

``.png .tif .tiff .bmp``
    through OpenImageIO, read in the file's own integer type (8 or 16 bit),
    one channel only: a file with three or four channels is a demosaiced or
    colour image, not a raw mosaic, and is refused.  TIFFs that store 10-,
    12- or 14-bit samples are expanded to 16 bits by OpenImageIO; polcam
    maps them back to the stored counts (exactly).  A JSON object in the
    TIFF/PNG ``ImageDescription`` (what :func:`polcam.io.write_frame` writes)
    is read as metadata the file carries.
``.pgm .ppm .pnm``
    parsed by polcam (binary ``P5`` and ASCII ``P2`` greyscale): OpenImageIO
    rescales PNM samples whose maxval is not 255 or 65535, which would lose
    the counts.  The maxval is the file's white level and gives its bit
    depth.  Colour PNM (``P3``/``P6``) is refused.
``.raw .bin``
    headerless dumps as machine-vision SDKs write them.  Width, height and
    the GenICam pixel format come from the sidecar or the keywords; the bytes
    are unpacked with :mod:`polcam.io.packing`.  Without a pixel format, a
    file of exactly width x height bytes is read as 8-bit and one of twice
    that as 16-bit little-endian words.  LUCID ``PolarizedAngles_*`` frames
    (four half-resolution angle planes interleaved per pixel) are
    re-interleaved into a full-resolution mosaic with the 2x2 cell
    ``0 45 / 135 90`` (:func:`polcam.mosaic.layout_for_format`); their
    width/height may be given either as the camera reports them (the
    half-resolution size, four values a pixel) or as the re-interleaved
    mosaic's size.  Formats computed in the camera (Stokes, DoLP, AoLP) are
    refused with :class:`PixelFormatError`.
``.npy``
    :func:`numpy.load` with ``allow_pickle=False``: a 2-D array of integer
    counts in [0, 65535] (``uint8`` stays ``uint8``, every other integer type
    becomes ``uint16``).  Float arrays are accepted only when a white level is
    given (keyword or sidecar), since a float array has no bit depth of its
    own, and only if every value is a finite, non-negative whole number
    (counts stored as float, e.g. from MATLAB); they become ``uint16`` and
    their bit depth, unless given, is that of the white level.
    Normalised float data (fractions) is refused: a Frame holds counts.
``.dng`` and the camera raw formats LibRaw opens (``.nef .cr2 .arw`` ...)
    through rawpy: ``raw_image_visible`` is the mosaic, the black level is
    the mean of ``black_level_per_channel``, the white level LibRaw's
    ``white_level`` and the bit depth the bits of the white level (or of the
    largest count, when a camera records counts above LibRaw's white level:
    those are kept, not refused, since LibRaw's level is an estimate).
    Images LibRaw reports as already demosaiced (LinearRaw DNG) are refused.

Where each value comes from, first found wins: an explicit keyword argument
(the CLI flag), the sidecar ``<stem>.json`` (:mod:`polcam.io.sidecar`), what
the file itself says (embedded JSON, then the pixel format, then the file
header: TIFF BitsPerSample, PNM maxval, LibRaw levels), then the defaults
(bit depth of the container, black 0, white ``2**bit_depth - 1``, no layout).

The layout is the keyword, else the sidecar's ``layout``, else the layout
embedded in the file, else that of the pixel format, else ``None``.  The
sidecar's ``layout`` is the layout of the *delivered image*: when a sidecar
also records ``roi``, ``reverse_x`` or ``reverse_y``, polcam does not derive
the layout again from them (the camera layer already did, with
:meth:`polcam.mosaic.Layout.for_readout`, when it wrote the sidecar); they
are kept in the metadata for reference only.

``msb_aligned`` (sidecar or keyword) says that ``bit_depth`` significant bits
sit at the top of the stored word (12-bit data in 16-bit words shifted up by
4): the reader shifts them down, so the Frame always holds counts in
[0, 2**bit_depth - 1].

Every problem is a :class:`polcam.errors.FrameReadError` (or
:class:`PixelFormatError` for a pixel format) whose message starts with the
file name: missing, empty, truncated or corrupt file, a size that does not
match the sidecar (a sidecar ``width``/``height`` that contradicts the
size the image itself has is refused, naming both), odd width or height (a polarization mosaic is made of 2x2
cells), a bit depth wider than the stored samples, values above the bit
depth or the white level, NaN/inf in a float array, non-2-D arrays, unknown
pixel formats and unsupported extensions.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from polcam.errors import FrameReadError, LayoutError
from polcam.frame import Frame
from polcam.io.decoders import (
    MAX_PIXELS,
    RAW_EXTENSIONS,
    Decoded,
    Decoder,
    DecodeRequest,
    check_raw_file,
    decoder_for,
    deinterleave_angles,
    interleave_angles,
    lookup_raw_format,
)
from polcam.io.sidecar import read_sidecar, sidecar_path, validate_metadata
from polcam.mosaic import Layout, PixelFormat, layout_for_format, parse_layout

__all__ = ["MAX_PIXELS", "RAW_EXTENSIONS", "declared_size", "deinterleave_angles", "interleave_angles", "read_frame"]


def read_frame(
    path: str | PathLike[str],
    *,
    layout: str | Layout | None = None,
    pixel_format: str | None = None,
    vendor: str | None = None,
    width: int | None = None,
    height: int | None = None,
    bit_depth: int | None = None,
    msb_aligned: bool | None = None,
    black_level: float | None = None,
    white_level: float | None = None,
    max_pixels: int | None = None,
) -> Frame:
    """Read a raw polarization mosaic and its metadata.

    Parameters
    ----------
    path
        The raw file; its extension picks the reader (:data:`RAW_EXTENSIONS`,
        see the module docstring).  A sidecar ``<stem>.json`` beside it is
        read when present.
    layout
        Layout of the delivered image (``imx250mzr``, ``mono:90,45,135,0``,
        ...); overrides the sidecar and the pixel format.
    pixel_format, vendor
        GenICam PixelFormat name and DeviceVendorName (needed for ``.raw``
        dumps of packed formats; gives layout and bit depth otherwise).
    width, height
        Frame size for headerless ``.raw``/``.bin`` dumps, pixels.
    bit_depth
        Significant bits per pixel (1 to 16).
    msb_aligned
        The significant bits sit at the top of the stored word; they are
        shifted down to counts.
    black_level, white_level
        Counts of black and saturation.
    max_pixels
        Largest frame to read, pixels (default :data:`MAX_PIXELS`, 2**27): a
        header or sidecar that declares more is refused before any
        allocation of that size.

    Returns
    -------
    Frame
        ``mosaic`` (H, W) ``uint8``/``uint16`` counts in [0, 2**bit_depth - 1];
        ``metadata`` holds ``path``, ``format`` (file type), every sidecar key,
        the metadata the file carries, and the pixel format and vendor used.

    Raises
    ------
    FrameReadError
        Missing, empty, truncated or corrupt file; wrong size; odd
        dimensions; bad sidecar or keyword values; values above the bit depth
        or white level; unsupported extension (the message lists them).
    PixelFormatError
        Unknown pixel format (the message lists the supported ones) or one
        computed in the camera.

    Examples
    --------
    A 4 x 4 mosaic of 12-bit counts, written with its sidecar and read back:

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from polcam import Frame, read_frame
    >>> from polcam.io import write_frame
    >>> tmp = tempfile.TemporaryDirectory()
    >>> mosaic = np.tile(np.array([[0, 1000], [2000, 4095]], dtype=np.uint16), (2, 2))
    >>> path = write_frame(Path(tmp.name) / "frame.npy", Frame(mosaic, layout="imx250mzr", bit_depth=12))
    >>> sorted(p.name for p in Path(tmp.name).iterdir())
    ['frame.json', 'frame.npy']
    >>> frame = read_frame(path)
    >>> str(frame.layout), frame.bit_depth, frame.mosaic.shape, frame.mosaic.dtype
    ('imx250mzr', 12, (4, 4), dtype('uint16'))
    >>> frame.normalized()[0, :2]  # (counts - black) / (white - black)
    array([0.        , 0.24420024], dtype=float32)
    >>> tmp.cleanup()
    """
    p = Path(path)
    check_raw_file(p)
    decoder = decoder_for(p)
    if isinstance(layout, Layout):
        layout = layout.name
    keywords = {
        "layout": layout, "pixel_format": pixel_format, "vendor": vendor, "width": width,
        "height": height, "bit_depth": bit_depth, "msb_aligned": msb_aligned,
        "black_level": black_level, "white_level": white_level,
    }
    side, opts, sources = _given(p, keywords)
    limit = MAX_PIXELS if max_pixels is None else int(max_pixels)
    dec = _decode(decoder, p, DecodeRequest(opts, sources, limit))
    # values the file carries (embedded JSON) rank below the sidecar
    merged: dict[str, Any] = {k: v for k, v in dec.file_meta.items() if v is not None}
    merged.update(opts)
    fmt = dec.pixel_format
    if fmt is None and merged.get("pixel_format"):
        fmt = lookup_raw_format(merged["pixel_format"], merged.get("vendor"), p)
    if not decoder.sized_by_metadata:
        _check_given_size(dec.mosaic, opts, sources, p)
    depth, depth_src = _bit_depth(merged, sources, fmt, dec, p)
    mosaic = dec.mosaic
    if merged.get("msb_aligned") and depth < dec.stored_bits:
        mosaic = mosaic >> (dec.stored_bits - depth)
    top, largest = _check_counts(mosaic, depth, depth_src, merged, dec, p)
    black, white = _levels(largest, top, merged, sources, dec, p)
    metadata: dict[str, Any] = {**dec.extra, **dec.file_meta, **side, "path": str(p), "format": dec.format}
    if fmt is not None:
        metadata["pixel_format"] = fmt.name
        if merged.get("vendor"):
            metadata["vendor"] = merged["vendor"]
    if dec.stored_bits != depth or merged.get("msb_aligned"):
        metadata["stored_bits"] = dec.stored_bits
    return Frame(
        mosaic=np.ascontiguousarray(mosaic),
        layout=_layout(merged, fmt),
        bit_depth=depth,
        black_level=black,
        white_level=white,
        metadata=metadata,
    )


def _given(p: Path, keywords: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], dict[str, str]]:
    """(the sidecar, the sidecar's values overridden by the keywords given, where each value came from)."""
    side = read_sidecar(p) or {}
    side_name = sidecar_path(p).name
    kw = validate_metadata({k: v for k, v in keywords.items() if v is not None}, path=p,
                           source="the keyword arguments")
    opts: dict[str, Any] = {k: v for k, v in side.items() if v is not None}
    opts.update(kw)
    sources = {k: ("the keywords" if k in kw else f"the sidecar {side_name}") for k in opts}
    return side, opts, sources


def _decode(decoder: Decoder, p: Path, request: DecodeRequest) -> Decoded:
    """Run the decoder; an OS error reading the file is a :class:`FrameReadError` naming it."""
    try:
        dec = decoder.decode(p, request)
    except MemoryError:  # pragma: no cover
        raise
    except OSError as exc:
        raise FrameReadError(f"cannot read: {exc.strerror or exc}", path=p) from exc
    if dec.mosaic.ndim != 2:  # pragma: no cover - every decoder returns 2-D
        raise FrameReadError(f"decoded image has shape {dec.mosaic.shape}: expected (height, width)", path=p)
    return dec


def _check_given_size(mosaic: np.ndarray, opts: dict[str, Any], sources: dict[str, str], p: Path) -> None:
    """A sidecar or keyword width/height must be the size the image itself has."""
    said = {k: opts[k] for k in ("width", "height") if opts.get(k) is not None}
    have = {"width": mosaic.shape[1], "height": mosaic.shape[0]}
    if any(int(v) != have[k] for k, v in said.items()):
        src = sources.get("width", sources.get("height", "the sidecar"))
        raise FrameReadError(
            f"{src} gives {said.get('width', '?')}x{said.get('height', '?')} (width x height) but the "
            f"image is {have['width']}x{have['height']}: the sidecar belongs to another frame, or "
            "the image was cropped or resized", path=p)


def _bit_depth(merged: dict[str, Any], sources: dict[str, str], fmt: PixelFormat | None, dec: Decoded,
               p: Path) -> tuple[int, str]:
    """(bit depth, where it came from): keyword > sidecar > embedded > pixel format > file header >
    container; never wider than the stored samples."""
    depth = merged.get("bit_depth")
    depth_src = sources.get("bit_depth", "the file's metadata")
    if depth is None and fmt is not None:
        depth, depth_src = fmt.bit_depth, f"pixel format {fmt.name}"
    if depth is None and dec.file_bits:
        depth, depth_src = dec.file_bits, "the file header"
    if depth is None:
        depth, depth_src = dec.stored_bits, "the file's sample size"
    depth = int(depth)
    if depth > dec.stored_bits:
        raise FrameReadError(
            f"bit_depth {depth} (from {depth_src}) is wider than the {dec.stored_bits}-bit samples "
            "the file stores",
            path=p,
        )
    return depth, depth_src


def _check_counts(mosaic: np.ndarray, depth: int, depth_src: str, merged: dict[str, Any], dec: Decoded,
                  p: Path) -> tuple[int, int]:
    """Refuse odd sizes and counts above the bit depth; return (the top count of the depth, the
    largest count in the mosaic)."""
    h, w = mosaic.shape
    if h % 2 or w % 2:
        raise FrameReadError(
            f"image is {w}x{h} (width x height): a polarization mosaic is made of 2x2 cells, "
            "expected even width and height",
            path=p,
        )
    top = (1 << depth) - 1
    mx = int(mosaic.max()) if mosaic.size else 0
    if mx > top:
        hint = ""
        if not merged.get("msb_aligned") and depth < dec.stored_bits:
            hint = "; if the data are MSB-aligned in wider words, set msb_aligned=true"
        raise FrameReadError(
            f"pixel values reach {mx}, above the {depth}-bit range [0, {top}] "
            f"(bit_depth from {depth_src}){hint}",
            path=p,
        )
    return top, mx


def _levels(mx: int, top: int, merged: dict[str, Any], sources: dict[str, str], dec: Decoded,
            p: Path) -> tuple[float, float]:
    """(black, white) levels: given > the file's > 0 and the top of the bit depth; counts above a
    white level that was given (or that the file states as a limit) are refused."""
    black = merged.get("black_level", dec.black_level)
    white = merged.get("white_level", dec.white_level)
    black = 0.0 if black is None else float(black)
    white = float(top) if white is None else float(white)
    if white <= black:
        raise FrameReadError(f"white level {white} is not above black level {black}", path=p)
    if mx > white and ("white_level" in merged or dec.white_is_limit):
        raise FrameReadError(
            f"pixel values reach {mx}, above the white level {white:g} "
            f"(from {sources.get('white_level', 'the file')}); expected counts <= white_level",
            path=p,
        )
    return black, white


def _layout(merged: dict[str, Any], fmt: PixelFormat | None) -> Layout | None:
    """Layout: keyword > sidecar > embedded > pixel format > None (a plain Mono/Bayer format: the
    caller must say, --layout)."""
    if merged.get("layout"):
        return parse_layout(merged["layout"])
    if fmt is not None:
        try:
            return layout_for_format(fmt)
        except LayoutError:
            return None
    return None


def declared_size(path: str | PathLike[str]) -> tuple[int, int] | None:
    """``(width, height)`` a raw file declares, from its header or sidecar, without reading the pixels.

    Parameters
    ----------
    path
        A raw frame file (:data:`RAW_EXTENSIONS`).

    Returns
    -------
    tuple of int or None
        Width and height in pixels; ``None`` where the size cannot be told
        without decoding (camera raw formats, unreadable headers, a dump
        without width/height in its sidecar, an unsupported extension).  For a
        dump of four angle planes this is the size the sidecar gives.
    """
    p = Path(path)
    try:
        return decoder_for(p).size(p)
    except (OSError, ValueError, FrameReadError):
        return None
