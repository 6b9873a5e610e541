"""What one frame of ``polcam process`` takes: memory while it is processed, disk for its outputs.

Both are estimated from the size a file *declares* (its header or sidecar,
:func:`polcam.io.readers.declared_size`), before any pixel is read, so a
small file that declares a huge image (a 140 KB PNG of 11000 x 11000) is
refused with a clear message instead of reaching the out-of-memory killer.

Memory (:func:`frame_memory`): a fixed 64 MiB plus bytes per sensor pixel,
the peak resident-set growth measured for one frame processed in a frame
worker (one BLAS thread), 1024 x 1024 synthetic 12-bit frames::

    form     resolution   tensor family   imin    other methods
    colour   cell          224 B/px        114     163 (yang10) - 178 (wen21)
    colour   full          890 B/px
    mono     cell          180 B/px (polarized-residual, the mono default)
    mono     full          640 B/px

(``peak ru_maxrss`` after :func:`polcam.process.process_frame` minus before,
``max_iter=3``).  The mono figures are those of ``polarized-residual`` since
it runs its colour path on mono stacks: measured per frame in a warm worker
(118 and 430 B/px; ``imin`` 20 and 97) and scaled by 1.5, the ratio of the two
measurements for the methods measured both ways (``wen21`` 124 -> 178, the
earlier mono path 39 -> 59).  The estimate takes the tensor family's figure for
every colour method and the mono default's for every mono method, except
``imin`` (half of it), so it errs on the large side; a 5 MP colour frame at
cell resolution comes to about 1.2 GB, a mono one to about 1.0 GB.

Disk (:func:`output_bytes`): the five products as uncompressed float32 (EXR
compresses, so this is an upper bound), plus 64 KiB for ``meta.json``.
"""

from __future__ import annotations

import os

__all__ = ["BYTES_PER_PIXEL", "default_max_memory", "frame_memory", "output_bytes", "parse_size"]

#: (colour, resolution) -> bytes per sensor pixel at the peak of one frame (tensor family, mono default).
BYTES_PER_PIXEL: dict[tuple[bool, str], int] = {
    (True, "cell"): 230, (True, "full"): 900, (False, "cell"): 180, (False, "full"): 640,
}
_FIXED = 64 << 20
_LIGHT = ("imin",)   # methods measured at about half the table's figure


def frame_memory(width: int, height: int, *, colour: bool, resolution: str = "cell",
                 method: str | None = None) -> int:
    """Estimated peak memory of one frame in a worker, bytes.

    Parameters
    ----------
    width, height
        Sensor pixels of the raw mosaic.
    colour
        A colour (Bayer) polarization layout; mono otherwise.
    resolution
        ``"cell"`` or ``"full"``.
    method
        The separation method (``None``: the default for the form).
    """
    per_px = BYTES_PER_PIXEL[(bool(colour), "full" if resolution == "full" else "cell")]
    if method in _LIGHT:
        per_px //= 2
    return _FIXED + int(width) * int(height) * per_px


def output_bytes(width: int, height: int, *, colour: bool, resolution: str = "cell") -> int:
    """Upper bound of the disk space one frame's outputs take, bytes (uncompressed float32)."""
    px = int(width) * int(height) // (1 if resolution == "full" else 4)
    return px * 4 * 5 * (3 if colour else 1) + (64 << 10)


def default_max_memory() -> int | None:
    """Default per-frame memory limit: three quarters of the physical memory (None where unknown)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") * 3 // 4)
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return None


def parse_size(text: str) -> int:
    """Bytes of ``"1.5G"``, ``"800M"``, ``"64k"`` or a plain number (powers of 1024).

    Raises
    ------
    ValueError
        Not a non-negative number with an optional K, M, G or T suffix.
    """
    t = str(text).strip().upper().removesuffix("B").removesuffix("I")
    mult = 1
    if t and t[-1] in "KMGT":
        mult = 1024 ** ("KMGT".index(t[-1]) + 1)
        t = t[:-1]
    try:
        value = float(t)
    except ValueError:
        raise ValueError(f"size {text!r}: expected a number of bytes with an optional K, M, G or T "
                         "suffix, e.g. 8G") from None
    if not value >= 0:
        raise ValueError(f"size {text!r}: expected a non-negative size")
    return int(value * mult)
