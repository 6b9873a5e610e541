"""Shared lattice helpers of the demosaicing methods (private).

The sample lattices of a layout (one per angle, and colour), bilinear
interpolation of one lattice by normalised convolution, the per-angle cell
planes, and the thread pool the strip-wise methods run on.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from polcam.mosaic import Layout

#: Border mode of the methods that need the mosaic's phase kept (mirror without
#: repeating the edge pixel).
BORDER = cv2.BORDER_REFLECT_101


def _tent(radius: int) -> np.ndarray:
    k = np.concatenate([np.arange(1, radius + 1), np.arange(radius - 1, 0, -1)]).astype(np.float32)
    return k / radius


def sublattices(lay: Layout, angle: int, channel: int) -> list[tuple[int, int]]:
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


def bilinear_lattice(img: np.ndarray, offsets: list[tuple[int, int]], period: int, *,
                     out: np.ndarray | None = None) -> np.ndarray:
    """Bilinear interpolation of the samples at ``offsets`` (mod ``period``), by normalised
    convolution with mirrored borders (BORDER_REFLECT).

    One offset: a rectangular lattice, separable tent of radius ``period``
    (normalised convolution with the lattice mask, computed without full-size
    masks).  Two offsets half a period apart on the diagonal: the green
    quincunx of a colour sensor, bilinear on the diagonals
    (:func:`_quincunx_kernel`).  Both kernels vanish at the other samples of the
    lattice, so known samples are reproduced.

    Parameters
    ----------
    img
        (H, W) float32 mosaic.
    offsets
        (y, x) offsets of the lattice within one period.
    period
        Period of the pattern in pixels.
    out
        Optional C-contiguous (H, W) float32 array to write the result into.

    Notes
    -----
    Beyond ``period - 1`` pixels from the edges the lattice's kernel weights sum
    to exactly 1 (dyadic values), so there the normalised convolution is the
    convolution itself.  Only bands ``period`` pixels wide at the edges need the
    division (and, at the corners, the tent fallback): they are computed on
    strips 2 to 3 periods wide along each edge, starting on a whole period so
    every lattice keeps its phase, which give the same values as the whole
    image there (a strip's far edge is beyond the kernel's reach).

    Returns
    -------
    numpy.ndarray
        (H, W) float32.
    """
    h, w = img.shape
    p = period
    top, left = _tail_start(h, p), _tail_start(w, p)
    if top is None or left is None:
        res = _bilinear_lattice_whole(img, offsets, p)
        if out is None:
            return res
        out[...] = res
        return out
    sparse = np.zeros((h, w), np.float32)
    for oy, ox in offsets:
        sparse[oy::p, ox::p] = img[oy::p, ox::p]
    if len(offsets) == 1:
        k = _tent(p)
        out = cv2.sepFilter2D(sparse, cv2.CV_32F, k, k, dst=out, borderType=cv2.BORDER_REFLECT)
    else:
        out = cv2.filter2D(sparse, cv2.CV_32F, _quincunx_kernel(p), dst=out, borderType=cv2.BORDER_REFLECT)
    del sparse
    # the edge bands from strips that start on a lattice period (the phase kept) and reach
    # 2p past the band: a strip's far edge is more than the kernel radius (p - 1) away
    out[:p] = _bilinear_lattice_whole(img[:3 * p], offsets, p)[:p]
    out[h - p:] = _bilinear_lattice_whole(img[top:], offsets, p)[h - p - top:]
    out[:, :p] = _bilinear_lattice_whole(img[:, :3 * p], offsets, p)[:, :p]
    out[:, w - p:] = _bilinear_lattice_whole(img[:, left:], offsets, p)[:, w - p - left:]
    return out


def _tail_start(n: int, p: int) -> int | None:
    """Start of the last strip along an axis of ``n``: a multiple of ``p`` at least 2p before
    the end; None where the axis is too short for the band scheme (under 4 periods)."""
    start = ((n - 2 * p) // p) * p
    return start if n >= 4 * p and start >= p else None


def _bilinear_lattice_whole(img: np.ndarray, offsets: list[tuple[int, int]], period: int) -> np.ndarray:
    """:func:`bilinear_lattice` computed on the whole image (normalised convolution everywhere)."""
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


def interleave_rgb(planes: list[np.ndarray], out: np.ndarray) -> None:
    """Write three (H, W) planes into the (H, W, 3) array ``out``."""
    cv2.merge(planes, dst=out)


def cell_planes(img: np.ndarray, lay: Layout) -> np.ndarray:
    """(4, H/2, W/2) float32: the sample of each angle in every 2x2 polarizer cell."""
    h, w = img.shape
    ai = lay.angle_index(2, 2)
    planes = np.empty((4, h // 2, w // 2), dtype=np.float32)
    for r in range(2):
        for c in range(2):
            planes[ai[r, c]] = img[r::2, c::2]
    return planes


def bilinear_cells(img: np.ndarray, lay: Layout) -> np.ndarray:
    """The cell-resolution stack by bilinear interpolation between cells.

    Mono: the cell samples themselves, (4, H/2, W/2).  Colour: the cell images
    form one Bayer mosaic per angle, interpolated bilinearly per colour,
    (4, H/2, W/2, 3).
    """
    h, w = img.shape
    planes = cell_planes(img, lay)
    if not lay.is_color:
        return planes
    pattern = lay.channel_index(4, 4)[::2, ::2]
    offsets = [[(py, px) for py in range(2) for px in range(2) if pattern[py, px] == c] for c in range(3)]
    out = np.empty((4, h // 2, w // 2, 3), dtype=np.float32)
    for k in range(4):
        interleave_rgb([bilinear_lattice(planes[k], offsets[c], 2) for c in range(3)], out[k])
    return out


def run_jobs(jobs: list[Callable[[], None]]) -> None:
    """Run jobs on a thread pool (OpenCV and numpy release the GIL in their loops)."""
    workers = max(1, min(4, os.cpu_count() or 1))
    if workers == 1 or len(jobs) == 1:
        for j in jobs:
            j()
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for fut in [pool.submit(j) for j in jobs]:
            fut.result()


def gauss_kernel(sigma: float) -> np.ndarray:
    """Gaussian kernel of ``sigma`` pixels truncated at 2.5 sigma (at least 3 taps), float32, sum 1."""
    r = max(1, int(np.ceil(2.5 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    return (k / k.sum()).astype(np.float32)


def tent_kernel(period: int, sigma: float) -> np.ndarray:
    """The tent ``tri(d / period)`` convolved with a Gaussian of ``sigma`` pixels (none if
    ``sigma`` is 0), float32, sum 1.

    On a lattice of that period the tent's copies sum to a constant and their first moments
    vanish at every pixel (its spectrum has double zeros at the lattice's non-zero
    frequencies); convolving with any kernel keeps both, so normalised convolution with this
    kernel reproduces affine functions exactly."""
    d = np.arange(-(period - 1), period, dtype=np.float64)
    k = np.maximum(0.0, 1.0 - np.abs(d) / period)
    if sigma > 0:
        k = np.convolve(k, gauss_kernel(sigma).astype(np.float64))
    return (k / k.sum()).astype(np.float32)


def _indicator_blur(n: int, offset: int, period: int, kernel: np.ndarray) -> np.ndarray:
    """``kernel`` applied to the 0/1 indicator of ``offset::period`` along a line of n (BORDER_REFLECT)."""
    ind = np.zeros((1, n), np.float32)
    ind[0, offset::period] = 1.0
    return cv2.sepFilter2D(ind, cv2.CV_32F, kernel, np.ones(1, np.float32), borderType=cv2.BORDER_REFLECT)[0]


def normconv(val: np.ndarray, offsets: list[tuple[int, int]], period: int, kernel: np.ndarray) -> np.ndarray:
    """Normalised convolution of the samples of one lattice.

    Parameters
    ----------
    val
        (H, W) float32; only its values at the lattice's pixels are read.
    offsets
        The lattice: offsets (y, x) within one ``period`` (``offset::period`` in both axes).
    period
        Period of the lattice in pixels.
    kernel
        Odd-length 1-D kernel, applied separably (mirrored borders, OpenCV ``BORDER_REFLECT``).

    Returns
    -------
    numpy.ndarray
        (H, W) float32: ``K * (samples) / K * (mask)``.
    """
    h, w = val.shape
    sparse = np.zeros((h, w), np.float32)
    for oy, ox in offsets:
        sparse[oy::period, ox::period] = val[oy::period, ox::period]
    q = cv2.sepFilter2D(sparse, cv2.CV_32F, kernel, kernel, borderType=cv2.BORDER_REFLECT)
    blurs = [(_indicator_blur(h, oy, period, kernel), _indicator_blur(w, ox, period, kernel)) for oy, ox in offsets]
    if len(blurs) == 1:  # a rectangular lattice: the blurred mask is an outer product
        q *= (1 / np.maximum(blurs[0][0], np.float32(1e-12)))[:, None]
        q *= (1 / np.maximum(blurs[0][1], np.float32(1e-12)))[None, :]
    else:
        q /= np.maximum(sum(np.outer(a, b) for a, b in blurs), np.float32(1e-12))
    return q
