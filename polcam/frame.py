"""The raw frame: a sensor mosaic with everything needed to interpret it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from polcam.mosaic import Layout, parse_layout

__all__ = ["Frame", "SIDECAR_KEYS"]

#: Keys of the JSON sidecar ``<stem>.json`` written beside a raw frame (docs/guide/cameras.md lists them).
SIDECAR_KEYS: tuple[str, ...] = (
    "layout", "pixel_format", "vendor", "width", "height", "bit_depth", "msb_aligned",
    "black_level", "white_level", "exposure_us", "gain_db", "timestamp_ns", "frame_id",
    "camera_id", "roi", "reverse_x", "reverse_y",
)


@dataclass
class Frame:
    """One raw mosaic and its metadata.

    Attributes
    ----------
    mosaic
        (H, W) unsigned integer array of sensor counts, exactly as read
        (``uint8`` or ``uint16``; 12-bit data that the file stored MSB-aligned
        is shifted back down, see ``msb_aligned``).
    layout
        The polarizer/colour pattern of ``mosaic`` in the image frame, or
        ``None`` when neither the file nor the caller said.
    bit_depth
        Significant bits per pixel (8, 10, 12 or 16).
    black_level, white_level
        Counts of black and of saturation; normalised values are
        ``(mosaic - black) / (white - black)``.
    metadata
        Everything else the file or its sidecar carried (exposure_us,
        gain_db, timestamp_ns, frame_id, camera_id, roi, pixel_format,
        vendor, source path, ...).
    """

    mosaic: np.ndarray
    layout: Layout | None = None
    bit_depth: int = 8
    black_level: float = 0.0
    white_level: float | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.layout is not None:
            self.layout = parse_layout(self.layout)
        if self.white_level is None:
            self.white_level = float(2**self.bit_depth - 1)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the mosaic."""
        return tuple(self.mosaic.shape[:2])  # type: ignore[return-value]

    def normalized(self) -> np.ndarray:
        """The mosaic as linear float32, ``(counts - black) / (white - black)``.

        Returns
        -------
        numpy.ndarray
            (H, W) float32; values of valid pixels in [0, 1] (not clipped, so
            noise below the black level stays negative).
        """
        black = float(self.black_level)
        span = float(self.white_level) - black  # type: ignore[arg-type]
        if span <= 0:
            raise ValueError(
                f"white level {self.white_level} is not above black level {black}"
            )
        return ((self.mosaic.astype(np.float32) - np.float32(black)) / np.float32(span)).astype(np.float32)

    def sidecar(self) -> dict[str, Any]:
        """The metadata as the sidecar JSON dictionary (keys: :data:`SIDECAR_KEYS`)."""
        h, w = self.shape
        out: dict[str, Any] = {
            "layout": None if self.layout is None else self.layout.short_name,
            "width": int(w),
            "height": int(h),
            "bit_depth": int(self.bit_depth),
            "black_level": float(self.black_level),
            "white_level": float(self.white_level),  # type: ignore[arg-type]
        }
        for key in SIDECAR_KEYS:
            if key not in out and key in self.metadata:
                out[key] = self.metadata[key]
        return out
