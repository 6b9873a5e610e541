"""Bit packings of machine-vision pixel formats, vectorised with numpy.

The packings (names as in :data:`polcam.mosaic.PACKINGS`) and their byte
layouts, for consecutive pixels p0, p1, ... of the whole frame (the bit stream
runs on across line ends; there is no per-line padding):

``"8"``
    one byte per pixel.
``"16"``
    one little-endian 16-bit word per pixel (Mono10/12/16: the value sits in
    the low bits unless the camera says it is MSB-aligned).
``"12p"`` (GenICam PFNC ``Mono12p``, ``BayerRG12p``, FLIR ``Polarized12p``, ...)
    an LSB-first bit stream: pixel k occupies bits ``12k .. 12k+11`` of the
    little-endian number formed by the bytes.  Two pixels in three bytes::

        byte0 = p0[7:0]
        byte1 = p1[3:0] << 4 | p0[11:8]
        byte2 = p1[11:4]

``"10p"`` (PFNC ``Mono10p``)
    the same LSB-first stream with 10-bit pixels, four pixels in five bytes::

        byte0 = p0[7:0]
        byte1 = p1[5:0] << 2 | p0[9:8]
        byte2 = p2[3:0] << 4 | p1[9:6]
        byte3 = p3[1:0] << 6 | p2[9:4]
        byte4 = p3[9:2]

``"12packed"`` (GigE Vision ``Mono12Packed``, a GigE Vision 1.x format)
    two pixels in three bytes, the high bits first::

        byte0 = p0[11:4]
        byte1 = p1[3:0] << 4 | p0[3:0]
        byte2 = p1[11:4]

``"10packed"`` (GigE Vision ``Mono10Packed``)
    two pixels in three bytes (so 12 bits a pixel on the wire)::

        byte0 = p0[9:2]
        byte1 = p1[1:0] << 4 | p0[1:0]      (bits 2-3 and 6-7 unused, zero)
        byte2 = p1[9:2]

Sources checked: FLIR's BFS-U3-51S5P ImageFormatControl reference (Mono12p:
"the first byte contains the eight least significant bits of the first pixel
... the four lsb of the second byte contain the four msb of the first pixel";
Mono12Packed: "the first byte contains the eight msb of the first pixel"),
Basler's racer/pilot/scout manuals (Mono 12 Packed byte table:
B0 = P0 bits 11..4, B1 = P1 bits 3..0 | P0 bits 3..0, B2 = P1 bits 11..4),
Euresys' description of the PFNC "lsb packed" formats, and the GigE Vision
pixel-format list (Mono10Packed: "two 10-bit pixels packed into 24 bits", the
grouped byte in the middle).  The Mono10Packed bit positions follow the
Mono12Packed pattern with two low bits per pixel instead of four.

A frame whose pixel count is not a multiple of the packing group ends with a
partial group: the byte count is ``ceil(n * bytes_per_group / pixels_per_group)``
(the same as :meth:`polcam.mosaic.PixelFormat.frame_bytes`) and missing bits
are zero.
"""

from __future__ import annotations

from os import PathLike

import numpy as np

from polcam.errors import FrameReadError, FrameWriteError, PixelFormatError
from polcam.mosaic import PACKINGS

__all__ = ["PACKING_BITS", "PACKING_GROUPS", "pack", "packed_size", "unpack"]

#: Significant bits a pixel carries in each packing.
PACKING_BITS: dict[str, int] = {"8": 8, "16": 16, "10p": 10, "12p": 12, "12packed": 12, "10packed": 10}

#: (bytes, pixels) of one packing group.
PACKING_GROUPS: dict[str, tuple[int, int]] = {
    "8": (1, 1), "16": (2, 1), "10p": (5, 4), "12p": (3, 2), "12packed": (3, 2), "10packed": (3, 2),
}


# (byte offset, bit shift) of each pixel of a group in the LSB-first PFNC packings:
# pixel j starts at bit j * bits, i.e. byte (j * bits) // 8, bit (j * bits) % 8.
_LSB_FIELDS: dict[str, tuple[tuple[int, int], ...]] = {
    "12p": ((0, 0), (1, 4)),
    "10p": ((0, 0), (1, 2), (2, 4), (3, 6)),
}


def _check_packing(packing: str) -> str:
    if packing not in PACKING_GROUPS or packing not in PACKINGS:
        raise PixelFormatError(
            f"packing {packing!r} is not supported; expected one of {', '.join(PACKINGS)}"
        )
    return packing


def packed_size(packing: str, n_values: int) -> int:
    """Bytes that ``n_values`` pixel values take in ``packing``.

    Parameters
    ----------
    packing
        One of :data:`polcam.mosaic.PACKINGS`.
    n_values
        Number of pixel values (pixels x channels), >= 0.

    Returns
    -------
    int
        ``ceil(n_values * bytes_per_group / pixels_per_group)``.
    """
    nbytes, npix = PACKING_GROUPS[_check_packing(packing)]
    return -(-int(n_values) * nbytes // npix)


def _as_bytes(data: bytes | bytearray | memoryview | np.ndarray, path: str | PathLike[str] | None) -> np.ndarray:
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8 or data.ndim != 1:
            raise FrameReadError(
                f"packed data must be bytes or a 1-D uint8 array, got a {data.ndim}-D {data.dtype} array",
                path=path,
            )
        return np.ascontiguousarray(data)
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    raise FrameReadError(
        f"packed data must be bytes or a 1-D uint8 array, got {type(data).__name__}", path=path
    )


def _positive_int(name: str, value: object, path: str | PathLike[str] | None) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or int(value) <= 0:
        raise FrameReadError(f"{name} {value!r}: expected a positive integer", path=path)
    return int(value)


def _groups(buf: np.ndarray, nbytes: int) -> np.ndarray:
    """The buffer as (groups, nbytes), zero-padding a last partial group."""
    rem = buf.size % nbytes
    if rem:
        buf = np.concatenate([buf, np.zeros(nbytes - rem, dtype=np.uint8)])
    return buf.reshape(-1, nbytes)


def unpack(
    data: bytes | bytearray | memoryview | np.ndarray,
    *,
    packing: str,
    width: int,
    height: int,
    channels: int = 1,
    path: str | PathLike[str] | None = None,
) -> np.ndarray:
    """Unpack a frame's bytes into pixel values.

    Parameters
    ----------
    data
        The frame as it came from the camera or a ``.raw`` dump: ``bytes`` or a
        1-D ``uint8`` array of exactly :func:`packed_size` bytes.
    packing
        One of :data:`polcam.mosaic.PACKINGS` (see the module docstring).
    width, height
        Frame size in pixels.
    channels
        Values per pixel (4 for LUCID ``PolarizedAngles_*``: 0, 45, 90, 135
        degrees, interleaved per pixel).
    path
        File the bytes came from, named in error messages.

    Returns
    -------
    numpy.ndarray
        ``uint8`` for packing ``"8"``, else ``uint16``; shape
        (height, width), or (height, width, channels) when ``channels > 1``.
        Values in [0, 2**bits - 1] with bits = :data:`PACKING_BITS` [packing].
        A new, writable array (it does not share memory with ``data``).

    Raises
    ------
    FrameReadError
        Wrong byte count (the message gives the expected and the found
        count), non-positive sizes, or data that is not bytes.
    PixelFormatError
        Unknown packing.
    """
    _check_packing(packing)
    width = _positive_int("width", width, path)
    height = _positive_int("height", height, path)
    channels = _positive_int("channels", channels, path)
    buf = _as_bytes(data, path)
    n = width * height * channels
    expected = packed_size(packing, n)
    if buf.size != expected:
        what = f"{width}x{height}" + (f"x{channels}" if channels > 1 else "")
        raise FrameReadError(
            f"expected {expected} bytes for a {what} frame in packing {packing!r}, found {buf.size} bytes",
            path=path,
        )
    shape = (height, width) if channels == 1 else (height, width, channels)
    if packing == "8":
        return buf.copy().reshape(shape)
    if packing == "16":
        return buf.view("<u2").astype(np.uint16, copy=True).reshape(shape)

    nbytes, npix = PACKING_GROUPS[packing]
    g = _groups(buf, nbytes)
    ngroups = g.shape[0]
    out = np.empty((ngroups, npix), dtype=np.uint16)
    if packing in _LSB_FIELDS:
        # LSB-first stream: pixel j of a group is the little-endian 16-bit word at byte
        # offset o_j, shifted right by s_j and masked; read with strided (unaligned) views.
        flat_groups = g.reshape(-1)
        mask = (1 << PACKING_BITS[packing]) - 1
        for j, (offset, shift) in enumerate(_LSB_FIELDS[packing]):
            word = np.ndarray((ngroups,), dtype="<u2", buffer=flat_groups, offset=offset,
                              strides=(nbytes,))
            if shift:
                np.right_shift(word, shift, out=out[:, j])
                if shift + PACKING_BITS[packing] < 16:
                    np.bitwise_and(out[:, j], mask, out=out[:, j])
            else:
                np.bitwise_and(word, mask, out=out[:, j])
        flat = out.reshape(-1)
        if flat.size != n:
            flat = flat[:n].copy()
        return flat.reshape(shape)
    b = [g[:, i].astype(np.uint16) for i in range(nbytes)]
    if packing == "12packed":
        out[:, 0] = (b[0] << 4) | (b[1] & 0x0F)
        out[:, 1] = (b[2] << 4) | (b[1] >> 4)
    else:  # "10packed"
        out[:, 0] = (b[0] << 2) | (b[1] & 0x03)
        out[:, 1] = (b[2] << 2) | ((b[1] >> 4) & 0x03)
    flat = out.reshape(-1)
    if flat.size != n:
        flat = flat[:n].copy()
    return flat.reshape(shape)


def pack(values: np.ndarray, *, packing: str) -> bytes:
    """Pack pixel values into bytes: the exact inverse of :func:`unpack`.

    Parameters
    ----------
    values
        Unsigned (or non-negative signed) integer array of any shape, read in
        C order, so an (H, W, C) array gives pixel-interleaved channels as
        :func:`unpack` expects.  Values in [0, 2**bits - 1] for the packing.
    packing
        One of :data:`polcam.mosaic.PACKINGS`.

    Returns
    -------
    bytes
        :func:`packed_size` (packing, values.size) bytes; unused bits are zero.

    Raises
    ------
    FrameWriteError
        Non-integer values, negative values or values wider than the packing.
    PixelFormatError
        Unknown packing.
    """
    _check_packing(packing)
    arr = np.asarray(values)
    if arr.dtype.kind not in "ui":
        raise FrameWriteError(f"cannot pack {arr.dtype} values: expected an integer array")
    bits = PACKING_BITS[packing]
    flat = arr.reshape(-1)
    if flat.size:
        lo, hi = int(flat.min()), int(flat.max())
        if lo < 0 or hi > (1 << bits) - 1:
            raise FrameWriteError(
                f"values span [{lo}, {hi}], which does not fit packing {packing!r}: "
                f"expected integers in [0, {(1 << bits) - 1}]"
            )
    if packing == "8":
        return flat.astype(np.uint8).tobytes()
    if packing == "16":
        return flat.astype("<u2").tobytes()

    nbytes, npix = PACKING_GROUPS[packing]
    n = flat.size
    p = flat.astype(np.uint16)
    rem = n % npix
    if rem:
        p = np.concatenate([p, np.zeros(npix - rem, dtype=np.uint16)])
    p = p.reshape(-1, npix)
    out = np.empty((p.shape[0], nbytes), dtype=np.uint8)
    c = [p[:, i] for i in range(npix)]
    if packing == "12p":
        out[:, 0] = c[0] & 0xFF
        out[:, 1] = (c[0] >> 8) | ((c[1] & 0x0F) << 4)
        out[:, 2] = c[1] >> 4
    elif packing == "12packed":
        out[:, 0] = c[0] >> 4
        out[:, 1] = (c[0] & 0x0F) | ((c[1] & 0x0F) << 4)
        out[:, 2] = c[1] >> 4
    elif packing == "10packed":
        out[:, 0] = c[0] >> 2
        out[:, 1] = (c[0] & 0x03) | ((c[1] & 0x03) << 4)
        out[:, 2] = c[1] >> 2
    else:  # "10p"
        out[:, 0] = c[0] & 0xFF
        out[:, 1] = (c[0] >> 8) | ((c[1] & 0x3F) << 2)
        out[:, 2] = (c[1] >> 6) | ((c[2] & 0x0F) << 4)
        out[:, 3] = (c[2] >> 4) | ((c[3] & 0x03) << 6)
        out[:, 4] = c[3] >> 2
    return out.reshape(-1)[: packed_size(packing, n)].tobytes()
