"""The shared-ratio second stage of ``lmmse`` on colour layouts (private; docs/methods/demosaic-lmmse.md).

The ratio stage of :func:`polcam.demosaicing.lmmse.second_stage` interpolates the
polarization ratio ``q = I / (S0 / 2)`` of each (angle, colour) lattice on its own: on a
colour sensor one sample in 4 x 4 pixels (two for green), so the ratio's detail is
interpolated at a quarter of the resolution.  Real colours share most of their
polarization (the angle nearly always, the degree up to a slowly varying factor), so the
samples of one angle in *all* colours (one pixel in 2 x 2) carry the detail four times
more densely.  Using them without mixing the colours' own ratios takes three steps, per
angle k (``T_p`` the normalised convolution of a lattice of period p):

1. **Colour offsets**: each colour's ratio, smoothed on its own lattice (a Gaussian of
   ``offset_sigma`` pixels, then the lattice's bilinear tent), ``S_c``; their mean over
   the colours ``m = sum_c w_c S_c`` (``w_c`` each colour's share of the samples);
   ``o_c = S_c - m``.
2. **Shared ratio**: every sample of angle k, of whatever colour c, less its colour's
   offset, ``q - o_c``, interpolated on the period-2 lattice of angle k (its bilinear tent
   convolved with a Gaussian of ``common_sigma`` pixels): ``U``.
3. **Colour residual**: ``q - U`` on colour c's own samples, smoothed and interpolated
   like the offsets (Gaussian of ``residual_sigma``): ``R_c``.

The estimate is ``q_c = U + R_c``, multiplied back by ``S0_c / 2 + e``; own samples are
kept.  If every colour's ratio is an affine function of x and y (constant: uniform
polarization, different in each colour), the offsets are exact, ``q - o_c`` is the
colours' mean ratio ``m`` at every sample, ``U = m``, and ``R_c = q_c - m``: exact.
Step 1 needs the offsets only at the samples of angle k, so it runs on that angle's
samples alone (a quarter of the pixels: a Bayer mosaic of ratios).  The
smoothing on a lattice (a Gaussian of ``sigma / period`` samples on the lattice's own
grid, then the bilinear tent) keeps affine functions and costs a sixteenth of a
full-resolution filter of that width.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import cv2
import numpy as np

from polcam.demosaicing._lattice import gauss_kernel, run_jobs, sublattices, tent_kernel
from polcam.errors import MethodError
from polcam.mosaic import Layout

__all__ = ["lattice_filter", "lattice_smooth", "shared_ratio_stage"]


def lattice_smooth(val: np.ndarray, offsets: list[tuple[int, int]], period: int, sigma: float) -> np.ndarray:
    """Smooth one lattice's samples on their own grid and interpolate them bilinearly to every pixel.

    Each rectangular sub-lattice ``val[oy::period, ox::period]`` is extended beyond its
    outermost samples point-symmetrically (``v(-i) = 2 v(0) - v(i)``, which keeps affine
    functions affine), filtered by a Gaussian of ``sigma / period`` samples (none if ``sigma``
    is 0) and interpolated bilinearly (linear extrapolation past the outermost samples); a
    lattice of several sub-lattices (the green quincunx) gets the mean of theirs.

    Parameters
    ----------
    val
        (H, W) float32; only the lattice's pixels are read.
    offsets
        The lattice's offsets within one period.
    period
        Its period in pixels.
    sigma
        Gaussian in pixels (>= 0).

    Returns
    -------
    numpy.ndarray
        (H, W) float32.  An affine function of x and y comes back exactly at every pixel; with
        ``sigma`` 0 the samples of a rectangular lattice come back too.
    """
    h, w = val.shape
    g = gauss_kernel(sigma / period) if sigma > 0 else np.ones(1, np.float32)
    r = len(g) // 2 + 1
    tent = np.maximum(0.0, 1.0 - np.abs(np.arange(1 - period, period)) / period).astype(np.float32)
    out = np.zeros((h, w), np.float32)
    for oy, ox in offsets:
        sub = cv2.sepFilter2D(_odd_pad(val[oy::period, ox::period], r), cv2.CV_32F, g, g,
                              borderType=cv2.BORDER_ISOLATED)
        sub = sub[r - 1:sub.shape[0] + 1 - r, r - 1:sub.shape[1] + 1 - r]  # one extra sample on each side
        # the samples (one outside the image on each side) at their pixels, from (oy - period, ox - period)
        canvas = np.zeros(((sub.shape[0] - 1) * period + 1, (sub.shape[1] - 1) * period + 1), np.float32)
        canvas[::period, ::period] = sub
        full = cv2.sepFilter2D(canvas, cv2.CV_32F, tent, tent, borderType=cv2.BORDER_CONSTANT)
        out += full[period - oy:period - oy + h, period - ox:period - ox + w]
    if len(offsets) > 1:
        out *= np.float32(1 / len(offsets))
    return out


def _odd_pad(a: np.ndarray, r: int) -> np.ndarray:
    """``a`` (h, w) extended by ``r`` samples on every side point-symmetrically about its
    outermost samples (``v(-i) = 2 v(0) - v(i)``): affine functions stay affine."""
    return np.pad(a, r, mode="reflect", reflect_type="odd")


def _phases(samples: np.ndarray, offset: tuple[int, int], period: int, sigma: float, h: int, w: int
            ) -> Iterator[tuple[int, int, np.ndarray]]:
    """The pixels of :func:`lattice_filter`, one phase of the lattice at a time.

    Yields ``(y0, x0, values)``: ``values`` are the filtered image at ``[y0::period,
    x0::period]`` (y0, x0 < period), computed on the sample grid with the kernel's taps of
    that phase (polyphase filtering: no full-resolution canvas of zeros)."""
    kern = (tent_kernel(period, sigma) * np.float32(period)).astype(np.float64)
    c = len(kern) // 2
    reach = c // period + 1  # samples on either side that can have a tap
    pad = reach + 1
    grid = _odd_pad(samples, pad)
    oy, ox = offset

    def taps(phi: int) -> np.ndarray:
        # value at y = o + period i + phi is sum_d t[d] s[i + d], t[d] = kern[c + phi - period d]
        t = np.zeros(2 * reach + 1)
        for d in range(-reach, reach + 1):
            j = c + phi - period * d
            if 0 <= j < len(kern):
                t[d + reach] = kern[j]
        return t.astype(np.float32)

    ty = {phi: taps(phi) for phi in range(period)}
    for py in range(period):
        y0 = (oy + py) % period
        iy = (y0 - oy - py) // period + pad  # grid row of the first output row
        ny = len(range(y0, h, period))
        for px in range(period):
            x0 = (ox + px) % period
            ix = (x0 - ox - px) // period + pad
            nx = len(range(x0, w, period))
            part = grid[iy - reach:iy + ny + reach, ix - reach:ix + nx + reach]
            res = cv2.sepFilter2D(part, cv2.CV_32F, ty[px], ty[py], borderType=cv2.BORDER_ISOLATED)
            yield y0, x0, res[reach:reach + ny, reach:reach + nx]


def lattice_filter(val: np.ndarray, offset: tuple[int, int], period: int, sigma: float) -> np.ndarray:
    """Interpolate a rectangular lattice with its bilinear tent convolved with a Gaussian of
    ``sigma`` pixels (:func:`~polcam.demosaicing._lattice.tent_kernel`), at full resolution.

    Beyond its outermost samples the lattice is extended point-symmetrically, so the kernel's
    taps of every phase sum to 1 everywhere and affine functions come back exactly at every
    pixel (what normalised convolution with mirrored borders does not give near the edges).

    Parameters
    ----------
    val
        (H, W) float32; only the lattice's pixels are read.
    offset
        The lattice's offset (y, x) within one period.
    period
        Its period in pixels.
    sigma
        Gaussian in pixels (>= 0).

    Returns
    -------
    numpy.ndarray
        (H, W) float32.
    """
    h, w = val.shape
    oy, ox = offset
    out = np.empty((h, w), np.float32)
    for y0, x0, values in _phases(np.ascontiguousarray(val[oy::period, ox::period]), offset, period, sigma, h, w):
        out[y0::period, x0::period] = values
    return out


def _filter_at_samples(samples: np.ndarray, period: int, sigma: float) -> np.ndarray:
    """:func:`lattice_filter` evaluated at the lattice's own samples only: the kernel's taps at
    multiples of ``period`` applied on the sample grid, (h', w') float32."""
    kern = tent_kernel(period, sigma) * np.float32(period)
    c = len(kern) // 2
    taps = np.ascontiguousarray(kern[c % period::period])
    r = len(taps) // 2
    out = cv2.sepFilter2D(_odd_pad(samples, r), cv2.CV_32F, taps, taps, borderType=cv2.BORDER_ISOLATED)
    return out[r:out.shape[0] - r, r:out.shape[1] - r]


def shared_ratio_stage(img: np.ndarray, stack: np.ndarray, lay: Layout, *, common_sigma: float,
                       offset_sigma: float, residual_sigma: float, eps: float,
                       out: np.ndarray | None = None) -> np.ndarray:
    """Re-estimate every angle of a colour layout from the polarization ratios of all colours.

    Parameters
    ----------
    img
        (H, W) float32 mosaic of a colour layout.
    stack
        (4, H, W, 3) first-stage estimate (its S0 per colour is the guide).
    lay
        The mosaic's layout (colour).
    common_sigma
        Gaussian (pixels) convolved with the period-2 tent of the shared ratio (step 2).
    offset_sigma, residual_sigma
        Gaussians (pixels) of the colour offsets (step 1) and the colour residual (step 3).
    eps
        Offset of the ratio's denominator, relative to the mosaic's mean.
    out
        Array of the stack's shape and dtype for the result; it may be ``stack`` itself (the
        stage reads the stack before it writes), which spares a fresh 4 x H x W x 3 array.

    Returns
    -------
    numpy.ndarray
        (4, H, W, 3) float32; every pixel's own sample kept.

    Raises
    ------
    polcam.errors.MethodError
        For a mono layout.
    """
    if not lay.is_color:
        raise MethodError(f"shared-ratio stage: layout {lay.name} is mono, expected a colour layout")
    h, w = img.shape
    channels = stack.shape[-1]
    period = lay.period
    half = stack.sum(axis=0) * np.float32(0.25)  # S0 / 2 per channel, (H, W, C)
    own = np.empty((h, w), np.float32)  # S0 / 2 of each pixel's own colour
    for c in range(channels):
        for k in range(4):
            for y0, x0 in sublattices(lay, k, c):
                own[y0::period, x0::period] = half[y0::period, x0::period, c]
    e = np.float32(eps * max(float(np.mean(img, dtype=np.float64)), 1e-6))
    # the true ratio I / (S0 / 2) = 1 + DoLP cos(...) lies in [0, 2]; the clip keeps a poor
    # first-stage S0 (near 0 or negative on aliased detail) from blowing it up
    val = np.clip(img / (np.maximum(own, 0) + e), 0, 2)
    base = np.maximum(half, 0) + e  # (H, W, C)
    if out is None:
        out = np.empty_like(stack)
    hh, ww = -(-h // 2), -(-w // 2)
    local = threading.local()  # one ratio buffer per pool thread, reused by its jobs

    def job(k: int) -> None:
        lattices = [sublattices(lay, k, c) for c in range(channels)]
        parity = {(y0 % 2, x0 % 2) for lat in lattices for y0, x0 in lat}
        if len(parity) != 1:  # pragma: no cover - every colour layout repeats its 2x2 polarizer cell
            raise MethodError(f"shared-ratio stage: angle {k} of {lay.name} is not on one period-2 lattice")
        (py, px), = parity
        # all colour work on the samples of angle k: a Bayer mosaic of ratios, colour period 2
        sub = np.ascontiguousarray(val[py::2, px::2])
        sub_lat = [sorted({((y0 - py) // 2 % 2, (x0 - px) // 2 % 2) for y0, x0 in lat}) for lat in lattices]
        share = np.array([len(lat) for lat in lattices], np.float32)
        share /= share.sum()
        # step 1: the colours' offsets from their mean
        smooth = np.stack([lattice_smooth(sub, sub_lat[c], 2, offset_sigma / 2) for c in range(channels)])
        mean = np.tensordot(share, smooth, axes=1)
        u = sub + mean
        for c, lat in enumerate(sub_lat):
            for y0, x0 in lat:
                u[y0::2, x0::2] -= smooth[c, y0::2, x0::2]
        # step 2 at the samples, step 3 there too; then one full-resolution filter per colour:
        # q_c = T(u + R_c) = U + T(R_c), T the shared ratio's filter (R_c smooth: T(R_c) ~ R_c)
        resid = sub - _filter_at_samples(u, 2, common_sigma)
        # the ratios of every colour at every pixel, assembled phase by phase in pixel order
        q = getattr(local, "q", None)
        if q is None:
            q = local.q = np.empty((hh, 2, ww, 2, channels), np.float32)
        for c in range(channels):
            r_c = lattice_smooth(resid, sub_lat[c], 2, residual_sigma / 2)
            r_c += u
            for y0, x0, values in _phases(r_c, (py, px), 2, common_sigma, h, w):
                q[:values.shape[0], y0, :values.shape[1], x0, c] = values
        est = out[k]
        np.multiply(q.reshape(2 * hh, 2 * ww, channels)[:h, :w], base, out=est)
        for c, lat in enumerate(lattices):
            for y0, x0 in lat:  # own samples kept
                est[y0::period, x0::period, c] = img[y0::period, x0::period]

    run_jobs([lambda k=k: job(k) for k in range(4)])
    return out
