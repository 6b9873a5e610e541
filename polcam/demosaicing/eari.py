"""``eari``: edge-aware residual interpolation.

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

Departures from the paper (docs/methods/demosaic-eari.md has the details and the
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

``resolution="cell"``: the colour stage's cell images (mono: the cell samples).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from polcam.demosaicing._lattice import BORDER, cell_planes, interleave_rgb, run_jobs
from polcam.demosaicing._registry import register
from polcam.mosaic import Layout

__all__ = ["EARI_PARAMS", "REFERENCE", "eari"]

#: The paper this method follows.
REFERENCE = ("M. Morimatsu, Y. Monno, M. Tanaka, M. Okutomi, \"Monochrome and Color Polarization "
             "Demosaicking Using Edge-Aware Residual Interpolation\", IEEE ICIP 2020 (arXiv:2007.14292)")

#: Parameters of ``eari`` (docs/methods/demosaic-eari.md says how they were chosen).
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
    return cv2.filter2D(a, cv2.CV_32F, kernel, borderType=BORDER)


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
    padded = cv2.copyMakeBorder(img, pad, pad, pad, pad, BORDER)
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
        wmap = cv2.sepFilter2D(ind, cv2.CV_32F, box[0], box[1], delta=float(eps), borderType=BORDER)
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
    lap_i = cv2.filter2D(samples, cv2.CV_32F, _LAPLACE, borderType=BORDER)
    lap_g = cv2.filter2D(g, cv2.CV_32F, _LAPLACE, borderType=BORDER)
    # MLRI slope (window means), damped towards 0 where the guide has little Laplacian
    # energy relative to its own level, then averaged over the window
    cross = cv2.boxFilter(lap_g * lap_i, cv2.CV_32F, ksize, borderType=BORDER)
    energy = cv2.boxFilter(lap_g * lap_g, cv2.CV_32F, ksize, borderType=BORDER)
    mean_g = cv2.boxFilter(g, cv2.CV_32F, ksize, borderType=BORDER)
    slope = cross / (energy + reg * mean_g * mean_g + np.float32(1e-20))
    slope = cv2.boxFilter(slope, cv2.CV_32F, ksize, borderType=BORDER)
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
    padded = cv2.copyMakeBorder(img, halo, halo, halo, halo, BORDER)

    def job(y0: int, y1: int) -> None:
        res = _eari_block(padded[y0:y1 + 2 * halo], lay, eps)
        out[:, y0:y1] = res[:, halo:halo + y1 - y0, halo:halo + w]

    return [lambda y0=y0: job(y0, min(h, y0 + _STRIP)) for y0 in range(0, h, _STRIP)]


def _eari_mono(img: np.ndarray, lay: Layout) -> np.ndarray:
    """Mono EARI: (H, W) mosaic with a 2x2 polarizer cell -> (4, H, W)."""
    out = np.empty((4,) + img.shape, np.float32)
    run_jobs(_eari_mono_jobs(img, lay, out))
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
        name: cv2.filter2D(bayer, cv2.CV_32F, k, borderType=BORDER)
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
        out.append(cv2.filter2D(sparse, cv2.CV_32F, kernel, borderType=BORDER))
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
        cv2.GaussianBlur(c, (0, 0), sigma, borderType=BORDER)
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
    planes = cell_planes(img, lay)
    pattern = lay.channel_index(4, 4)[::2, ::2]
    if EARI_PARAMS["color_stage"] == "mhc":
        return [_bayer_mhc(planes[k], pattern) for k in range(4)]
    sigma = float(EARI_PARAMS["ratio_sigma"])
    return [_bayer_ratio(planes[k], pattern, sigma) for k in range(4)]


def eari(img: np.ndarray, lay: Layout) -> np.ndarray:
    """EARI demosaicing of a float32 (H, W) mosaic: (4, H, W) mono, (4, H, W, 3) colour."""
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
    run_jobs(jobs)
    return out


def _eari_cell(img: np.ndarray, lay: Layout) -> np.ndarray:
    if not lay.is_color:
        return cell_planes(img, lay)
    h, w = img.shape
    cells = _eari_color_cells(img, lay)
    out = np.empty((4, h // 2, w // 2, 3), np.float32)
    for k in range(4):
        interleave_rgb(cells[k], out[k])
    return out


register("eari", cell=_eari_cell, reference=REFERENCE)(eari)
