"""Demosaicing of polarization (and colour-polarization) mosaics into angle stacks.

``demosaic(raw, layout=..., method=...)`` turns an (H, W) mosaic into the stack
every later stage uses: (4, H, W) for a mono layout, (4, H, W, 3) RGB for a
colour layout, angle order 0, 45, 90, 135 degrees, linear float32.
:func:`mosaic_stack` is the forward model (a full stack sampled the way a sensor
of a given layout samples it), used by the benchmarks and the tests.

Methods (registry :data:`DEMOSAIC_METHODS`):

``bilinear``
    Normalised convolution of each (angle, colour) sample lattice with its
    bilinear kernel: the separable tent whose radius is the lattice period
    on the 2-periodic mono lattices and the 4-periodic R and B lattices of a
    colour sensor, and the tent product along both diagonals on the G
    quincunx (which, unlike a square tent, vanishes at the other G samples,
    so G samples are kept).  Mirrored borders (OpenCV BORDER_REFLECT).

``eari``
    Edge-aware residual interpolation, after M. Morimatsu, Y. Monno, M. Tanaka
    and M. Okutomi, "Monochrome and Color Polarization Demosaicking Using
    Edge-Aware Residual Interpolation", IEEE ICIP 2020 (arXiv:2007.14292).

    Mono (their MPFA algorithm):

    1. *Edge-aware guide.*  In every 2x3 (or 3x2) window each polarizer angle
       appears with total weight 1/4 under the kernel ``[1 2 1; 1 2 1] / 8``,
       so four one-sided estimates of ``S0 / 2`` are formed, from the rows
       above (north), below (south), and the columns left (west) and right
       (east) of a pixel.  Each direction gets a weight ``1 / (D + eps)``
       where ``D`` is the mean, over a one-sided 5x3 window, of the magnitude
       of an edge indicator that vanishes on any uniformly polarized flat
       patch; the guide G is the weighted mean of the four estimates.
    2. *Residual interpolation per angle* (the minimized-Laplacian residual
       interpolation, MLRI, of Kiku, Monno, Tanaka & Okutomi): on the samples
       of one angle, fit the local linear model ``I_k ~ a G + b`` whose slope
       minimises the energy of the Laplacian of the residual,
       ``a = mean(lap G * lap I_k) / mean((lap G)^2)`` over a window, average
       it over the window, take the tentative estimate ``a G + b``,
       interpolate the residual of the samples bilinearly and add it back.
       Known samples are reproduced exactly.

    Colour (their CPFA algorithm): the samples of each polarizer angle form
    a Bayer mosaic at the polarizer-cell resolution; each is colour
    demosaicked, the four results are interleaved back into a full-resolution
    3-channel polarization mosaic, and each channel goes through the mono
    algorithm above.

    Departures from the paper (docs/demosaic.md has the details and the
    measurements behind them):

    * Any 2x2 arrangement of the four angles, not only IMX250's ``90 45 /
      135 0``.  The paper's edge indicator (the difference of the horizontal
      second differences of two adjacent rows) cancels the polarization
      modulation only when the orthogonal angles sit on the diagonals of the
      cell; here the indicator of each window is the centre's angle plus its
      orthogonal partner minus the other two (each angle's samples in the
      window averaged).  That is the paper's indicator for the IMX250
      arrangement and vanishes on a uniformly polarized patch for every
      arrangement (I0 + I90 = I45 + I135).
    * The residual-interpolation slope is computed on each angle's own sample
      lattice (a 5x5 window of samples, 9x9 pixels; the paper uses 11x11
      pixels) and brought to full resolution by bilinear interpolation
      instead of a second full-resolution box average.  The offset ``b`` then
      cancels out exactly: ``I_k = a G + bilinear(I_k - a G on the samples)``.
      The paper clips the tentative estimate to [0, 1]; this does not (it
      would break that identity).
    * The slope's denominator is damped by ``slope_reg * mean(G)^2`` (the
      paper's code adds 1e-32): where the guide has little Laplacian energy
      relative to its level the slope goes to 0 and the angle is plain
      bilinear interpolation, which removes the guide's small periodic
      artefacts from smooth, strongly polarized areas.  The edge-weight offset
      ``eps`` is likewise relative to the mean of the mosaic, so the method
      does not depend on the scale of the input.
    * The colour stage interpolates each cell-level Bayer mosaic with a
      colour-ratio rule (each missing colour is the local smooth colour plus
      the pixel's own detail scaled by the local colour ratio; see
      :func:`_bayer_ratio`) instead of the paper's residual-interpolation Bayer
      demosaicker; it keeps the four angles of a cell consistent, which is
      what DoLP needs.  Malvar, He & Cutler's gradient-corrected linear
      interpolation (ICASSP 2004) is kept as the alternative
      ``EARI_PARAMS["color_stage"] = "mhc"``.
    * Borders are mirrored without repeating the edge pixel (OpenCV
      BORDER_REFLECT_101), which keeps the mosaic's phase; the paper
      replicates edge pixels.  The image is processed in overlapping strips
      of rows (same result, less memory traffic, run on a thread pool).

``resolution="cell"`` skips interpolation between polarizer cells: each 2x2 cell
gives one sample per angle, so the stack is (4, H/2, W/2) (mono), and for a colour
sensor the cell images form a Bayer mosaic that is interpolated per angle
(bilinearly for ``bilinear``, by the colour stage of the method for ``eari``).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from polcam.errors import FrameReadError, LayoutError, MethodError
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout

__all__ = [
    "DEMOSAIC_METHODS",
    "RESOLUTIONS",
    "demosaic",
    "mosaic_stack",
    "register_demosaic",
    "to_float",
]

DemosaicFn = Callable[[np.ndarray, Layout], np.ndarray]
_REGISTRY: dict[str, DemosaicFn] = {}
_CELL_REGISTRY: dict[str, DemosaicFn] = {}

#: Names of the demosaicing methods (filled by :func:`register_demosaic`).
DEMOSAIC_METHODS: tuple[str, ...] = ()

#: Output resolutions :func:`demosaic` accepts.
RESOLUTIONS: tuple[str, ...] = ("full", "cell")

_BORDER = cv2.BORDER_REFLECT_101


def register_demosaic(
    name: str, *, cell: DemosaicFn | None = None
) -> Callable[[DemosaicFn], DemosaicFn]:
    """Register ``fn(mosaic_float32 (H, W), layout) -> stack`` under ``name``.

    ``cell`` optionally gives the method's own ``resolution="cell"`` path
    (same signature, half-size output); without it the bilinear cell path is used.
    """

    def deco(fn: DemosaicFn) -> DemosaicFn:
        global DEMOSAIC_METHODS
        _REGISTRY[name] = fn
        if cell is not None:
            _CELL_REGISTRY[name] = cell
        DEMOSAIC_METHODS = tuple(_REGISTRY)
        return fn

    return deco


def to_float(raw: np.ndarray | Frame, *, black_level: float = 0.0,
             white_level: float | None = None) -> np.ndarray:
    """A mosaic as linear float32 ``(raw - black) / (white - black)``.

    Integer input without ``white_level`` is scaled by its dtype's full range
    (a 16-bit container is full-range 16-bit); float input is taken as already
    normalised unless levels are given.

    Raises
    ------
    FrameReadError
        Not a 2-D array, NaN or infinite values, a dtype that is neither
        integer nor float, or a white level not above the black level.
    """
    if isinstance(raw, Frame):
        return raw.normalized()
    arr = np.asarray(raw)
    if arr.ndim != 2:
        raise FrameReadError(f"raw mosaic of shape {arr.shape}: expected a 2-D (H, W) array")
    if np.issubdtype(arr.dtype, np.integer):
        white = float(np.iinfo(arr.dtype).max) if white_level is None else float(white_level)
    elif np.issubdtype(arr.dtype, np.floating):
        if not np.all(np.isfinite(arr)):
            raise FrameReadError("raw mosaic contains NaN or infinite values")
        white = 1.0 if white_level is None else float(white_level)
    else:
        raise FrameReadError(f"raw mosaic of dtype {arr.dtype}: expected integers or floats")
    span = white - float(black_level)
    if span <= 0:
        raise FrameReadError(f"white level {white} is not above black level {black_level}")
    if arr.dtype == np.float32 and black_level == 0 and span == 1.0:
        return np.ascontiguousarray(arr)
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
        (H, W halved with ``resolution="cell"``), angles 0, 45, 90, 135; linear,
        on the scale of the normalised input (not clipped).

    Raises
    ------
    LayoutError
        No layout, an unknown one, or a mosaic whose size does not fit it (odd,
        or smaller than two periods of the pattern).
    MethodError
        Unknown ``method`` or ``resolution``.
    FrameReadError
        A raw array that is not a finite 2-D integer or float array.
    """
    if layout is None:
        if isinstance(raw, Frame) and raw.layout is not None:
            layout = raw.layout
        else:
            raise LayoutError("no layout given: pass layout= (e.g. 'imx250mzr' or 'imx250myr')")
    lay = parse_layout(layout)
    if method not in _REGISTRY:
        raise MethodError(
            f"demosaicing method {method!r} is unknown; expected one of {', '.join(DEMOSAIC_METHODS)}"
        )
    if resolution not in RESOLUTIONS:
        raise MethodError(f"resolution {resolution!r}: expected 'full' or 'cell'")
    img = to_float(raw)
    h, w = img.shape
    p = lay.period
    if h < 2 * p or w < 2 * p or h % 2 or w % 2:
        raise LayoutError(
            f"mosaic of {w}x{h} pixels: expected even dimensions of at least {2 * p} "
            f"for layout {lay}"
        )
    if resolution == "cell":
        return _CELL_REGISTRY.get(method, _cell)(img, lay)
    return _REGISTRY[method](img, lay)


def mosaic_stack(stack: np.ndarray, *, layout: str | Layout) -> np.ndarray:
    """Sample a full-resolution stack the way a sensor of ``layout`` does.

    Parameters
    ----------
    stack
        (4, H, W) for a mono layout or (4, H, W, 3) RGB for a colour layout,
        angle order 0, 45, 90, 135.
    layout
        Sensor layout name or :class:`~polcam.mosaic.Layout`.

    Returns
    -------
    numpy.ndarray
        (H, W) mosaic of the stack's dtype: pixel (y, x) holds the stack's value at
        the angle (and colour) the layout puts there.

    Raises
    ------
    MethodError
        A stack whose shape does not match the layout (mono/colour).
    """
    lay = parse_layout(layout)
    arr = np.asarray(stack)
    want = 4 if lay.is_color else 3
    if arr.ndim != want or arr.shape[0] != 4 or (lay.is_color and arr.shape[-1] != 3):
        kind = "(4, H, W, 3) RGB" if lay.is_color else "(4, H, W)"
        raise MethodError(f"stack of shape {arr.shape}: expected {kind} for layout {lay}")
    h, w = arr.shape[1:3]
    ai = lay.angle_index(h, w)
    yy, xx = np.indices((h, w))
    if lay.is_color:
        return arr[ai, yy, xx, lay.channel_index(h, w)]
    return arr[ai, yy, xx]


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


def _sublattices(lay: Layout, angle: int, channel: int) -> list[tuple[int, int]]:
    """Offsets (y, x) within one period of the pixels of (angle, channel)."""
    p = lay.period
    ai = lay.angle_index(p, p)
    ci = lay.channel_index(p, p)
    hit = (ai == angle) & (ci == channel)
    return [(int(y), int(x)) for y, x in zip(*np.nonzero(hit), strict=True)]


def _filter_1d(n: int, offset: int, period: int, kernel: np.ndarray) -> np.ndarray:
    """``kernel`` (centred) applied to the 0/1 indicator of ``offset::period`` along a line of n, BORDER_REFLECT."""
    ind = np.zeros((1, n), np.float32)
    ind[0, offset::period] = 1.0
    return cv2.filter2D(ind, cv2.CV_32F, kernel[None, :], borderType=cv2.BORDER_REFLECT)[0]


def _quincunx_kernel(period: int) -> np.ndarray:
    """Bilinear interpolation kernel of a quincunx lattice whose samples are ``period / 2``
    apart along both diagonals: ``tri((dx + dy) / period) tri((dx - dy) / period)``.

    For ``period`` 2 it is the usual Bayer green kernel ``[0 1 0; 1 4 1; 0 1 0] / 4``.
    """
    r = period - 1
    d = np.arange(-r, r + 1, dtype=np.float64)
    dx, dy = np.meshgrid(d, d)
    along = np.maximum(0.0, 1.0 - np.abs(dx + dy) / period)
    across = np.maximum(0.0, 1.0 - np.abs(dx - dy) / period)
    return (along * across).astype(np.float32)


def _bilinear_lattice(img: np.ndarray, offsets: list[tuple[int, int]], period: int) -> np.ndarray:
    """Bilinear interpolation of the samples at ``offsets`` (mod ``period``), by normalised
    convolution with mirrored borders (BORDER_REFLECT).

    One offset: a rectangular lattice, separable tent of radius ``period`` (the
    same result as :func:`normalized_convolution` with the lattice mask, without
    full-size masks).  Two offsets half a period apart on the diagonal: the
    green quincunx of a colour sensor, bilinear on the diagonals
    (:func:`_quincunx_kernel`).  Both kernels vanish at the other samples of the
    lattice, so known samples are reproduced.
    """
    h, w = img.shape
    sparse = np.zeros((h, w), np.float32)
    if len(offsets) == 1:
        k = _tent(period)
        (oy, ox), = offsets
        sparse[oy::period, ox::period] = img[oy::period, ox::period]
        den = np.outer(_filter_1d(h, oy, period, k), _filter_1d(w, ox, period, k))
        num = cv2.sepFilter2D(sparse, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)
        return num / np.maximum(den, np.float32(1e-12))
    mask = np.zeros((h, w), np.float32)
    for oy, ox in offsets:
        sparse[oy::period, ox::period] = img[oy::period, ox::period]
        mask[oy::period, ox::period] = 1.0
    kq = _quincunx_kernel(period)
    num = cv2.filter2D(sparse, cv2.CV_32F, kq, borderType=cv2.BORDER_REFLECT)
    den = cv2.filter2D(mask, cv2.CV_32F, kq, borderType=cv2.BORDER_REFLECT)
    out = num / np.maximum(den, np.float32(1e-12))
    hole = den < 1e-3
    if np.any(hole):
        # the mirrored border is not a quincunx: a few corner pixels see no sample
        # inside the diagonal kernel; they get the separable tent of radius period
        k = _tent(period)
        num = cv2.sepFilter2D(sparse, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)
        den = cv2.sepFilter2D(mask, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)
        out[hole] = num[hole] / np.maximum(den[hole], np.float32(1e-12))
    return out


def _interleave_rgb(planes: list[np.ndarray], out: np.ndarray) -> None:
    """Write three (H, W) planes into the (H, W, 3) array ``out``."""
    cv2.merge(planes, dst=out)


# ---------------------------------------------------------------------------
# bilinear
# ---------------------------------------------------------------------------

def _bilinear(img: np.ndarray, lay: Layout) -> np.ndarray:
    h, w = img.shape
    p = lay.period
    if not lay.is_color:
        out = np.empty((4, h, w), dtype=np.float32)
        for k in range(4):
            out[k] = _bilinear_lattice(img, _sublattices(lay, k, 0), p)
        return out
    out = np.empty((4, h, w, 3), dtype=np.float32)
    for k in range(4):
        planes = [_bilinear_lattice(img, _sublattices(lay, k, c), p) for c in range(3)]
        _interleave_rgb(planes, out[k])
    return out


def _cell_planes(img: np.ndarray, lay: Layout) -> np.ndarray:
    """(4, H/2, W/2): the sample of each angle in every 2x2 polarizer cell."""
    h, w = img.shape
    ai = lay.angle_index(2, 2)
    planes = np.empty((4, h // 2, w // 2), dtype=np.float32)
    for r in range(2):
        for c in range(2):
            planes[ai[r, c]] = img[r::2, c::2]
    return planes


def _cell(img: np.ndarray, lay: Layout) -> np.ndarray:
    h, w = img.shape
    planes = _cell_planes(img, lay)
    if not lay.is_color:
        return planes
    # the cell images form a Bayer mosaic (one colour per 2x2 cell): bilinear per angle
    pattern = lay.channel_index(4, 4)[::2, ::2]
    offsets = [[(py, px) for py in range(2) for px in range(2) if pattern[py, px] == c] for c in range(3)]
    out = np.empty((4, h // 2, w // 2, 3), dtype=np.float32)
    for k in range(4):
        _interleave_rgb([_bilinear_lattice(planes[k], offsets[c], 2) for c in range(3)], out[k])
    return out


register_demosaic("bilinear")(_bilinear)


# ---------------------------------------------------------------------------
# eari: edge-aware residual interpolation (Morimatsu et al., ICIP 2020)
# ---------------------------------------------------------------------------

#: Parameters of ``eari`` (docs/demosaic.md says how they were chosen).
EARI_PARAMS: dict[str, float | str] = {
    # added to the smoothed edge indicators before inverting them into weights,
    # relative to the mean of the mosaic
    "edge_eps": 1e-3,
    # radius, in samples of one angle's lattice, of the MLRI windows (2: 5x5 samples)
    "window": 2,
    # damping of the MLRI slope's denominator, relative to the squared mean of the guide
    "slope_reg": 1e-2,
    # colour stage: "ratio" (colour-ratio interpolation) or "mhc" (Malvar-He-Cutler)
    "color_stage": "ratio",
    # Gaussian smoothing, in cells, of the colour ratios of the "ratio" stage
    "ratio_sigma": 1.0,
    # offset of the colour ratios, relative to the mean of the mosaic
    "ratio_eps": 1e-2,
}

# directions of the one-sided windows: rows (dy) and columns (dx) they span
_DIRECTIONS: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "n": ((-1, 0), (-1, 0, 1)),
    "s": ((0, 1), (-1, 0, 1)),
    "w": ((-1, 0, 1), (-1, 0)),
    "e": ((-1, 0, 1), (0, 1)),
}

def _relation(dy: int, dx: int) -> str:
    if dy == 0 and dx == 0:
        return "self"
    if dy == 0:
        return "h"
    if dx == 0:
        return "v"
    return "d"


def _partner_relation(lay: Layout) -> str:
    """Where, relative to any pixel, its orthogonal polarizer sits: 'h', 'v' or 'd'."""
    pos = {a: divmod(i, 2) for i, a in enumerate(lay.angles)}
    (r0, c0), (r90, c90) = pos[0], pos[90]
    return _relation(r90 - r0, c90 - c0)


def _eari_kernels(lay: Layout) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per direction: (3x3 intensity kernel giving S0/2, 3x3 edge-indicator kernel)."""
    partner = _partner_relation(lay)
    kernels = {}
    for name, (dys, dxs) in _DIRECTIONS.items():
        rel = {(dy, dx): _relation(dy, dx) for dy in dys for dx in dxs}
        count: dict[str, int] = {}
        for r in rel.values():
            count[r] = count.get(r, 0) + 1
        inten = np.zeros((3, 3), np.float32)
        edge = np.zeros((3, 3), np.float32)
        for (dy, dx), r in rel.items():
            inten[dy + 1, dx + 1] = 1.0 / (4 * count[r])
            sign = 1.0 if r in ("self", partner) else -1.0
            edge[dy + 1, dx + 1] = sign / count[r]
        kernels[name] = (inten, edge)
    return kernels


def _row_kernels(lay: Layout, axis: int) -> tuple[np.ndarray, np.ndarray, float]:
    """1-D kernels along the rows (axis 0) or columns (axis 1) of the one-sided windows.

    Read off the north (axis 0) or west (axis 1) 3x3 kernels of
    :func:`_eari_kernels`: the intensity kernel (the same on both lines of a
    window), the edge kernel of the line through the pixel, and the sign s with
    which that kernel appears on the adjacent line (for every arrangement of
    the cell the two edge lines are equal or opposite).
    """
    inten, edge = _eari_kernels(lay)["n" if axis == 0 else "w"]
    if axis == 0:
        k_int, own, adj = inten[1], edge[1], edge[0]
    else:
        k_int, own, adj = inten[:, 1], edge[:, 1], edge[:, 0]
    sign = 1.0 if np.allclose(adj, own) else -1.0
    if not np.allclose(adj, sign * own):  # pragma: no cover - excluded by construction
        raise AssertionError("edge kernel lines are neither equal nor opposite")
    return np.ascontiguousarray(k_int), np.ascontiguousarray(own), sign


def _line_filter(a: np.ndarray, k: np.ndarray, axis: int) -> np.ndarray:
    """Filter every row (axis 0: along x) or column (axis 1: along y) of ``a`` with the 3-tap ``k``."""
    kernel = k[None, :] if axis == 0 else k[:, None]
    return cv2.filter2D(a, cv2.CV_32F, kernel, borderType=_BORDER)


def _shift(a: np.ndarray, axis: int, start: int, pad: int, size: tuple[int, int]) -> np.ndarray:
    """View of the padded array ``a`` at the image window moved by ``start`` along ``axis``."""
    h, w = size
    if axis == 0:
        return a[pad + start:pad + start + h, pad:pad + w]
    return a[pad:pad + h, pad + start:pad + start + w]


_BOX3 = np.full(3, 1 / 3, np.float32)
_BOX5 = np.full(5, 1 / 5, np.float32)


def _eari_guide(img: np.ndarray, lay: Layout, eps: float) -> np.ndarray:
    """Edge-aware estimate of S0 / 2 at every pixel, (H, W) float32.

    ``eps`` is added to the smoothed edge indicators before they are inverted
    into weights.

    The four one-sided 2x3 windows of a pixel y are pairs of adjacent lines:
    north = lines (y-1, y), south = (y, y+1) (likewise west/east along x).  The
    intensity of a window is the sum of one line filter over its two lines, so
    ``X_s(y) = X_n(y+1)``.  The edge indicator of the north window is
    ``E_n(y) = f(y) + s f(y-1)`` for one line filter f and a sign s, that of the
    south window ``E_s(y) = f(y) + s f(y+1) = s E_n(y+1)``, so the smoothed
    indicators satisfy ``D_s(y) = D_n(y+3)``.  Each axis therefore needs one
    intensity map and one smoothed indicator map, read at two shifts.
    """
    h, w = img.shape
    pad = 4
    padded = cv2.copyMakeBorder(img, pad, pad, pad, pad, _BORDER)
    num = np.zeros((h, w), np.float32)
    den = np.zeros((h, w), np.float32)
    for axis in (0, 1):
        k_int, k_edge, sign = _row_kernels(lay, axis)
        line = _line_filter(padded, k_int, axis)
        f = _line_filter(padded, k_edge, axis)
        if axis == 0:
            pair = line[:-1] + line[1:]  # pair[i] = X_n(i + 1)
            ind = f[1:] + f[:-1] if sign > 0 else f[1:] - f[:-1]  # ind[i] = +-E_n(i + 1)
            box = (_BOX5, _BOX3)  # 5 wide, rows i-1..i+1
        else:
            pair = line[:, :-1] + line[:, 1:]
            ind = f[:, 1:] + f[:, :-1] if sign > 0 else f[:, 1:] - f[:, :-1]
            box = (_BOX3, _BOX5)
        np.abs(ind, out=ind)
        # weight map 1 / (mean |E_n| over the one-sided 5x3 window + eps)
        wmap = cv2.sepFilter2D(ind, cv2.CV_32F, box[0], box[1], delta=float(eps), borderType=_BORDER)
        np.reciprocal(wmap, out=wmap)
        # X_n(y) = pair[y - 1], X_s(y) = pair[y]; D_n(y) = mean |E_n| over y-2..y = box[y - 2],
        # D_s(y) = D_n(y + 3) = box[y + 1]  (indices of the padded arrays, offset by pad)
        for xs, ds in ((-1, -2), (0, 1)):
            wv = _shift(wmap, axis, ds, pad, (h, w))
            cv2.accumulateProduct(wv, _shift(pair, axis, xs, pad, (h, w)), num)
            den += wv
    np.divide(num, den, out=num)
    return num


_LAPLACE = np.array([[0, -1, 0], [-1, 4, -1], [0, -1, 0]], np.float32)


def _mid(plane: np.ndarray, offset: int, axis: int) -> np.ndarray:
    """Linear interpolation halfway between the samples of ``plane`` along ``axis``.

    The samples sit at full-resolution positions ``2 j + offset``; the result holds
    the values at ``2 j + 1 - offset``, the edge sample repeated where the mirrored
    border has no second neighbour.
    """
    a = plane if axis == 1 else plane.T
    out = np.empty_like(a)
    if offset == 0:  # midpoints j + 1/2 for j = 0..n-1; the last one has no right neighbour
        np.add(a[:, :-1], a[:, 1:], out=out[:, :-1])
        out[:, :-1] *= np.float32(0.5)
        out[:, -1] = a[:, -1]
    else:  # midpoints j - 1/2; the first one has no left neighbour
        np.add(a[:, :-1], a[:, 1:], out=out[:, 1:])
        out[:, 1:] *= np.float32(0.5)
        out[:, 0] = a[:, 0]
    return out if axis == 1 else out.T


def _phases(plane: np.ndarray, oy: int, ox: int) -> dict[tuple[int, int], np.ndarray]:
    """Bilinear interpolation of samples at (oy::2, ox::2), split by output phase.

    Returns the interpolated values at the pixels (py::2, px::2) for the four
    phases (py, px); the mirrored border (BORDER_REFLECT_101 of the full grid)
    amounts to repeating the edge samples of the plane.
    """
    mid_x = _mid(plane, ox, 1)
    return {
        (oy, ox): plane,
        (oy, 1 - ox): mid_x,
        (1 - oy, ox): _mid(plane, oy, 0),
        (1 - oy, 1 - ox): _mid(mid_x, oy, 0),
    }


def _eari_angle(img: np.ndarray, guide: np.ndarray, oy: int, ox: int, out: np.ndarray) -> None:
    """Residual interpolation of the angle sampled at (oy::2, ox::2) into ``out`` (H, W)."""
    r = int(EARI_PARAMS["window"])
    ksize = (2 * r + 1, 2 * r + 1)
    reg = np.float32(float(EARI_PARAMS["slope_reg"]))
    samples = np.ascontiguousarray(img[oy::2, ox::2])
    g = np.ascontiguousarray(guide[oy::2, ox::2])
    lap_i = cv2.filter2D(samples, cv2.CV_32F, _LAPLACE, borderType=_BORDER)
    lap_g = cv2.filter2D(g, cv2.CV_32F, _LAPLACE, borderType=_BORDER)
    # MLRI slope (window means), damped towards 0 where the guide has little Laplacian
    # energy relative to its own level, then averaged over the window
    cross = cv2.boxFilter(lap_g * lap_i, cv2.CV_32F, ksize, borderType=_BORDER)
    energy = cv2.boxFilter(lap_g * lap_g, cv2.CV_32F, ksize, borderType=_BORDER)
    mean_g = cv2.boxFilter(g, cv2.CV_32F, ksize, borderType=_BORDER)
    slope = cross / (energy + reg * mean_g * mean_g + np.float32(1e-20))
    slope = cv2.boxFilter(slope, cv2.CV_32F, ksize, borderType=_BORDER)
    resid = samples - slope * g
    slopes = _phases(slope, oy, ox)
    resids = _phases(resid, oy, ox)
    for (py, px), s in slopes.items():
        np.multiply(s, guide[py::2, px::2], out=out[py::2, px::2])
        out[py::2, px::2] += resids[(py, px)]


def _eari_block(block: np.ndarray, lay: Layout, eps: float) -> np.ndarray:
    """Mono EARI of one block (borders mirrored), (4, hb, wb) float32."""
    guide = _eari_guide(block, lay, eps)
    out = np.empty((4,) + block.shape, np.float32)
    ai = lay.angle_index(2, 2)
    for oy in range(2):
        for ox in range(2):
            _eari_angle(block, guide, oy, ox, out[int(ai[oy, ox])])
    return out


#: Rows per strip of the strip-wise evaluation (even).
_STRIP = 256


def _halo() -> int:
    """Rows and columns of context a strip needs on each side (even).

    The guide reaches 4 pixels; an angle's slope reaches 2 r + 2 samples of its
    lattice (Laplacian, two box filters of radius r) and the final bilinear
    step one more, i.e. 2 (2 r + 3) pixels; rounded up to even.
    """
    r = int(EARI_PARAMS["window"])
    need = 4 + 2 * (2 * r + 3)
    return need + need % 2


def _eari_mono_jobs(img: np.ndarray, lay: Layout, out: np.ndarray) -> list[Callable[[], None]]:
    """Jobs that fill ``out`` (4, H, W), possibly a strided view, with the mono EARI of
    ``img``, one per strip of rows.

    The image is mirrored once (BORDER_REFLECT_101, which keeps the phase of
    the 2x2 pattern since the margin is even) and cut into overlapping strips
    that are processed independently: small working sets that stay in cache,
    and jobs a thread pool can run in parallel.  The edge-weight offset is set
    from the whole image, so the result does not depend on the strips.
    """
    h, w = img.shape
    halo = _halo()
    eps = float(EARI_PARAMS["edge_eps"]) * max(float(np.mean(img, dtype=np.float64)), 1e-6)
    padded = cv2.copyMakeBorder(img, halo, halo, halo, halo, _BORDER)

    def job(y0: int, y1: int) -> None:
        res = _eari_block(padded[y0:y1 + 2 * halo], lay, eps)
        out[:, y0:y1] = res[:, halo:halo + y1 - y0, halo:halo + w]

    return [lambda y0=y0: job(y0, min(h, y0 + _STRIP)) for y0 in range(0, h, _STRIP)]


def _run(jobs: list[Callable[[], None]]) -> None:
    """Run jobs on a thread pool (OpenCV and numpy release the GIL in their loops)."""
    workers = max(1, min(4, os.cpu_count() or 1))
    if workers == 1 or len(jobs) == 1:
        for j in jobs:
            j()
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for fut in [pool.submit(j) for j in jobs]:
            fut.result()


def _eari_mono(img: np.ndarray, lay: Layout) -> np.ndarray:
    """Mono EARI: (H, W) mosaic with a 2x2 polarizer cell -> (4, H, W)."""
    out = np.empty((4,) + img.shape, np.float32)
    _run(_eari_mono_jobs(img, lay, out))
    return out


# Malvar, He & Cutler (2004) gradient-corrected bilinear kernels (their Fig. 2), /8
_MHC_G_AT_RB = np.array(
    [[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]],
    np.float32) / 8
_MHC_ROW = np.array(  # at a green pixel, the colour whose samples are left and right of it
    [[0, 0, 0.5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, 0.5, 0, 0]],
    np.float32) / 8
_MHC_COL = np.ascontiguousarray(_MHC_ROW.T)  # ... whose samples are above and below it
_MHC_DIAG = np.array(  # red at blue pixels and blue at red pixels
    [[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0], [0, 0, -1.5, 0, 0]],
    np.float32) / 8


def _bayer_mhc(bayer: np.ndarray, pattern: np.ndarray) -> list[np.ndarray]:
    """Malvar-He-Cutler demosaicking of a Bayer mosaic.

    Parameters
    ----------
    bayer
        (h, w) float32 mosaic.
    pattern
        (2, 2) colour index (0 R, 1 G, 2 B) of the top-left 2x2 block.

    Returns
    -------
    list of numpy.ndarray
        [R, G, B], each (h, w) float32.
    """
    filt = {
        name: cv2.filter2D(bayer, cv2.CV_32F, k, borderType=_BORDER)
        for name, k in (("g", _MHC_G_AT_RB), ("row", _MHC_ROW), ("col", _MHC_COL), ("diag", _MHC_DIAG))
    }
    out = [np.empty_like(bayer) for _ in range(3)]
    for py in range(2):
        for px in range(2):
            own = int(pattern[py, px])
            sl = (slice(py, None, 2), slice(px, None, 2))
            out[own][sl] = bayer[sl]
            if own == 1:
                row_c = int(pattern[py, 1 - px])
                col_c = int(pattern[1 - py, px])
                out[row_c][sl] = filt["row"][sl]
                out[col_c][sl] = filt["col"][sl]
            else:
                out[1][sl] = filt["g"][sl]
                out[2 - own][sl] = filt["diag"][sl]
    return out


_BAYER_RB = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]], np.float32)
_BAYER_G = np.array([[0.0, 0.25, 0.0], [0.25, 1.0, 0.25], [0.0, 0.25, 0.0]], np.float32)


def _bayer_bilinear(bayer: np.ndarray, pattern: np.ndarray) -> list[np.ndarray]:
    """Bilinear demosaicking of a Bayer mosaic: [R, G, B], each (h, w) float32.

    ``pattern`` is the (2, 2) colour index (0 R, 1 G, 2 B) of the top-left block.
    """
    out = []
    for c in range(3):
        sparse = np.zeros_like(bayer)
        for py in range(2):
            for px in range(2):
                if pattern[py, px] == c:
                    sparse[py::2, px::2] = bayer[py::2, px::2]
        kernel = _BAYER_G if c == 1 else _BAYER_RB
        out.append(cv2.filter2D(sparse, cv2.CV_32F, kernel, borderType=_BORDER))
    return out


def _bayer_ratio(bayer: np.ndarray, pattern: np.ndarray, sigma: float) -> list[np.ndarray]:
    """Colour-ratio demosaicking of a Bayer mosaic: [R, G, B], each (h, w) float32.

    ``L_c`` is the bilinear estimate of colour c smoothed by a Gaussian of
    ``sigma`` pixels, ``L_o`` that of a pixel's own colour o.  A missing colour c
    is ``L_c + (x - L_o) (L_c + e) / (L_o + e)`` with x the pixel's own sample: the
    sample's detail (its departure from the smooth own colour) carried over in
    proportion to the local colour ratio.  Where the colours are well above ``e``
    this is the colour-ratio rule ``x L_c / L_o``; in the dark it becomes the
    colour-difference rule ``x + L_c - L_o``.  Known samples are kept, and a
    uniform patch is reproduced exactly whatever ``e``.
    """
    smooth = [
        cv2.GaussianBlur(c, (0, 0), sigma, borderType=_BORDER)
        for c in _bayer_bilinear(bayer, pattern)
    ]
    own_smooth = np.empty_like(bayer)
    for py in range(2):
        for px in range(2):
            own_smooth[py::2, px::2] = smooth[int(pattern[py, px])][py::2, px::2]
    eps = np.float32(float(EARI_PARAMS["ratio_eps"]) * max(float(np.mean(bayer, dtype=np.float64)), 1e-6))
    detail = (bayer - own_smooth) / (own_smooth + eps)
    out = []
    for c in range(3):
        est = smooth[c] + eps
        est *= detail
        est += smooth[c]
        for py in range(2):
            for px in range(2):
                if pattern[py, px] == c:
                    est[py::2, px::2] = bayer[py::2, px::2]
        out.append(est)
    return out


def _eari_color_cells(img: np.ndarray, lay: Layout) -> list[list[np.ndarray]]:
    """Colour stage: per angle, the Bayer mosaic of its cells demosaicked -> [angle][channel] (H/2, W/2)."""
    planes = _cell_planes(img, lay)
    pattern = lay.channel_index(4, 4)[::2, ::2]
    if EARI_PARAMS["color_stage"] == "mhc":
        return [_bayer_mhc(planes[k], pattern) for k in range(4)]
    sigma = float(EARI_PARAMS["ratio_sigma"])
    return [_bayer_ratio(planes[k], pattern, sigma) for k in range(4)]


def _eari(img: np.ndarray, lay: Layout) -> np.ndarray:
    if not lay.is_color:
        return _eari_mono(img, lay)
    h, w = img.shape
    cells = _eari_color_cells(img, lay)
    ai = lay.angle_index(2, 2)
    mono = Layout(lay.angles)
    out = np.empty((4, h, w, 3), np.float32)
    jobs: list[Callable[[], None]] = []
    for c in range(3):
        # the full-resolution mosaic of channel c: each pixel's own angle, in colour c
        mpfa = np.empty((h, w), np.float32)
        for oy in range(2):
            for ox in range(2):
                mpfa[oy::2, ox::2] = cells[int(ai[oy, ox])][c]
        jobs += _eari_mono_jobs(mpfa, mono, out[..., c])
    _run(jobs)
    return out


def _eari_cell(img: np.ndarray, lay: Layout) -> np.ndarray:
    if not lay.is_color:
        return _cell_planes(img, lay)
    h, w = img.shape
    cells = _eari_color_cells(img, lay)
    out = np.empty((4, h // 2, w // 2, 3), np.float32)
    for k in range(4):
        _interleave_rgb(cells[k], out[k])
    return out


register_demosaic("eari", cell=_eari_cell)(_eari)
