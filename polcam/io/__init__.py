"""Reading raw frames and writing results: files, sidecars, bit packings.

- :func:`read_frame` reads a raw mosaic (PNG, TIFF, PGM, BMP, headerless
  ``.raw`` dumps, ``.npy``, DNG and other camera raw files) into a
  :class:`polcam.frame.Frame`, with its sidecar ``<stem>.json``.
- :func:`write_image` / :func:`read_image` write and read float results (EXR,
  TIFF) with polcam metadata; :func:`write_frame` writes a raw frame
  losslessly with its sidecar.
- :mod:`polcam.io.packing` unpacks and packs GenICam pixel formats (Mono12p,
  Mono10p, Mono12Packed, Mono10Packed, 8/16-bit).
- :mod:`polcam.io.atomic`: every write goes to a temporary file renamed into
  place, so a crash never leaves a half-written file.
"""

from __future__ import annotations

from polcam.io.atomic import atomic_path, atomic_write
from polcam.io.packing import pack, packed_size, unpack
from polcam.io.readers import RAW_EXTENSIONS, read_frame
from polcam.io.sidecar import read_sidecar, sidecar_path, write_sidecar
from polcam.io.writers import IMAGE_EXTENSIONS, read_image, write_frame, write_image

__all__ = [
    "IMAGE_EXTENSIONS",
    "RAW_EXTENSIONS",
    "atomic_path",
    "atomic_write",
    "pack",
    "packed_size",
    "read_frame",
    "read_image",
    "read_sidecar",
    "sidecar_path",
    "unpack",
    "write_frame",
    "write_image",
    "write_sidecar",
]
