"""Demosaicing of polarization (and colour-polarization) mosaics into angle stacks.

``demosaic(raw, layout=..., method=...)`` turns an (H, W) mosaic into the stack
every later stage uses: (4, H, W) for a mono layout, (4, H, W, 3) RGB for a
colour layout, angle order 0, 45, 90, 135 degrees, linear float32.

Methods (registry :data:`DEMOSAIC_METHODS`):

``bilinear``
    Normalised convolution of each (angle, colour) sample lattice with a tent
    kernel whose radius is the lattice period: exact bilinear interpolation on
    the 2-periodic mono lattices and on the 4-periodic R and B lattices of a
    colour sensor, and tent-weighted interpolation on the G quincunx.

``resolution="cell"`` skips interpolation between polarizer cells: each 2x2 cell
gives one sample per angle, so the stack is (4, H/2, W/2) (mono), and for a colour
sensor the cell images form a Bayer mosaic that is interpolated per angle.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from polcam.errors import LayoutError
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout

__all__ = ["DEMOSAIC_METHODS", "demosaic", "register_demosaic", "to_float"]

DemosaicFn = Callable[[np.ndarray, Layout], np.ndarray]
_REGISTRY: dict[str, DemosaicFn] = {}

#: Names of the demosaicing methods (filled by :func:`register_demosaic`).
DEMOSAIC_METHODS: tuple[str, ...] = ()


def register_demosaic(name: str) -> Callable[[DemosaicFn], DemosaicFn]:
    """Register ``fn(mosaic_float32 (H, W), layout) -> stack`` under ``name``."""

    def deco(fn: DemosaicFn) -> DemosaicFn:
        global DEMOSAIC_METHODS
        _REGISTRY[name] = fn
        DEMOSAIC_METHODS = tuple(_REGISTRY)
        return fn

    return deco


def to_float(raw: np.ndarray | Frame, *, black_level: float = 0.0,
             white_level: float | None = None) -> np.ndarray:
    """A mosaic as linear float32 ``(raw - black) / (white - black)``.

    Integer input without ``white_level`` is scaled by its dtype's full range
    (a 16-bit container is full-range 16-bit); float input is taken as already
    normalised unless levels are given.
    """
    if isinstance(raw, Frame):
        return raw.normalized()
    arr = np.asarray(raw)
    if arr.ndim != 2:
        raise ValueError(f"raw mosaic of shape {arr.shape}: expected a 2-D (H, W) array")
    if np.issubdtype(arr.dtype, np.integer):
        white = float(np.iinfo(arr.dtype).max) if white_level is None else float(white_level)
    elif np.issubdtype(arr.dtype, np.floating):
        if not np.all(np.isfinite(arr)):
            raise ValueError("raw mosaic contains NaN or infinite values")
        white = 1.0 if white_level is None else float(white_level)
    else:
        raise ValueError(f"raw mosaic of dtype {arr.dtype}: expected integers or floats")
    span = white - float(black_level)
    if span <= 0:
        raise ValueError(f"white level {white} is not above black level {black_level}")
    return ((arr.astype(np.float32) - np.float32(black_level)) / np.float32(span)).astype(np.float32)


def demosaic(
    raw: np.ndarray | Frame,
    *,
    layout: str | Layout | None = None,
    method: str = "bilinear",
    resolution: str = "full",
) -> np.ndarray:
    """Demosaic a polarization mosaic into a stack of four angle images.

    Parameters
    ----------
    raw
        (H, W) mosaic: integers (scaled by the dtype's range), floats already
        in [0, 1], or a :class:`~polcam.frame.Frame` (scaled by its black and
        white levels, its layout used when ``layout`` is not given).
    layout
        Sensor layout name or :class:`~polcam.mosaic.Layout`.
    method
        One of :data:`DEMOSAIC_METHODS`.
    resolution
        ``"full"``: one output pixel per input pixel; ``"cell"``: one per 2x2
        polarizer cell (H and W halved).

    Returns
    -------
    numpy.ndarray
        float32 stack, (4, H, W) for mono or (4, H, W, 3) RGB for colour
        (H, W halved with ``resolution="cell"``), angles 0, 45, 90, 135.
    """
    if layout is None:
        if isinstance(raw, Frame) and raw.layout is not None:
            layout = raw.layout
        else:
            raise LayoutError("no layout given: pass layout= (e.g. 'imx250mzr' or 'imx250myr')")
    lay = parse_layout(layout)
    img = to_float(raw)
    h, w = img.shape
    p = lay.period
    if h < 2 * p or w < 2 * p or h % 2 or w % 2:
        raise ValueError(
            f"mosaic of {w}x{h} pixels: expected even dimensions of at least {2 * p} "
            f"for layout {lay}"
        )
    if resolution == "cell":
        return _cell(img, lay)
    if resolution != "full":
        raise ValueError(f"resolution {resolution!r}: expected 'full' or 'cell'")
    if method not in _REGISTRY:
        raise ValueError(
            f"demosaicing method {method!r} is unknown; expected one of {', '.join(DEMOSAIC_METHODS)}"
        )
    return _REGISTRY[method](img, lay)


# ---------------------------------------------------------------------------
# Shared helpers
# ---------------------------------------------------------------------------

def _tent(radius: int) -> np.ndarray:
    k = np.concatenate([np.arange(1, radius + 1), np.arange(radius - 1, 0, -1)]).astype(np.float32)
    return k / radius


def lattice_masks(lay: Layout, h: int, w: int) -> np.ndarray:
    """Sampling masks of each (angle, channel): (4, C, H, W) float32, C = 3 or 1."""
    ai = lay.angle_index(h, w)
    if not lay.is_color:
        return np.stack([(ai == k) for k in range(4)])[:, None].astype(np.float32)
    ci = lay.channel_index(h, w)
    return np.stack([[(ai == k) & (ci == c) for c in range(3)] for k in range(4)]).astype(np.float32)


def normalized_convolution(img: np.ndarray, mask: np.ndarray, radius: int) -> np.ndarray:
    """``(K * (img mask)) / (K * mask)`` with the separable tent K of ``radius``."""
    k = _tent(radius)
    num = cv2.sepFilter2D(img * mask, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)
    den = cv2.sepFilter2D(mask, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)
    return num / np.maximum(den, np.float32(1e-12))


@register_demosaic("bilinear")
def _bilinear(img: np.ndarray, lay: Layout) -> np.ndarray:
    h, w = img.shape
    masks = lattice_masks(lay, h, w)
    radius = lay.period
    out = np.empty((4, masks.shape[1], h, w), dtype=np.float32)
    for k in range(4):
        for c in range(masks.shape[1]):
            out[k, c] = normalized_convolution(img, masks[k, c], radius)
    if lay.is_color:
        return np.ascontiguousarray(out.transpose(0, 2, 3, 1))
    return out[:, 0]


def _cell(img: np.ndarray, lay: Layout) -> np.ndarray:
    h, w = img.shape
    ai = lay.angle_index(2, 2)
    planes = np.empty((4, h // 2, w // 2), dtype=np.float32)
    for r in range(2):
        for c in range(2):
            planes[ai[r, c]] = img[r::2, c::2]
    if not lay.is_color:
        return planes
    # the cell images form a Bayer mosaic (one colour per 2x2 cell): bilinear per angle
    ci = lay.channel_index(h, w)[::2, ::2]
    out = np.empty((4, h // 2, w // 2, 3), dtype=np.float32)
    for c in range(3):
        mask = (ci == c).astype(np.float32)
        for k in range(4):
            out[k, ..., c] = normalized_convolution(planes[k], mask, 2)
    return out
