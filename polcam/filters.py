"""Edge-preserving filters: a constant-time joint bilateral filter.

The joint (cross) bilateral filter of an image ``f`` guided by ``g`` is

    BF[f](p) = sum_q G_s(|p - q|) G_r(g(p) - g(q)) w(q) f(q)
               / sum_q G_s(|p - q|) G_r(g(p) - g(q)) w(q),

with Gaussian spatial and range kernels ``G_s`` (sigma ``sigma_spatial``, in
pixels) and ``G_r`` (sigma ``sigma_range``, in guide units), optional
per-pixel confidence weights ``w`` (0 removes a pixel from every average),
and the sum over the whole image (pixels outside it contribute nothing).

It is computed with the constant-time approximation of Yang, Tan & Ahuja,
"Real-time O(1) bilateral filtering", CVPR 2009, the filter Yang, Wang &
Ahuja use for highlight removal (ECCV 2010): for a handful of range levels
``L_0 < ... < L_{K-1}`` spanning the guide's values, each "principle bilateral
filtered image component"

    J_k = (G_s * (G_r(L_k - g) w f)) / (G_s * (G_r(L_k - g) w))

is a ratio of two Gaussian-blurred images (``*`` is spatial convolution), and
the output at ``p`` interpolates linearly between the two levels that bracket
``g(p)``.  At a guide value equal to a level the result is exact; between
levels it is a piecewise-linear interpolation in the range variable.  As in
Yang et al.'s implementation, the blurred images are computed on a grid
coarser than the image when the spatial sigma is large (a Gaussian of sigma
s pixels is smooth on a grid of spacing s / 6) and interpolated back
bilinearly; unlike their point subsampling, polcam sums the weighted image
over each grid cell (area splatting), so every pixel contributes.

opencv-python-headless has no ``cv2.ximgproc``, hence this module.

The filter is written once over the array namespace of :mod:`polcam._xp`: a
numpy guide gives numpy results, a ``torch.Tensor`` guide runs on its device
(float64).  The one step that differs is the Gaussian blur of the coarse
grid (:func:`_grid_blur`): ``scipy.ndimage.gaussian_filter`` in numpy, the
same operator as two banded matrices on a torch device.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import ndimage

from polcam._xp import namespace
from polcam.errors import MethodError

__all__ = ["MAX_AUTO_LEVELS", "MIN_GRID_SIGMA", "TRUNCATE", "JointBilateral", "auto_levels", "gaussian_matrix",
           "interp_weights", "joint_bilateral"]

#: Smallest spatial sigma, in grid cells, the coarse grid may leave.
MIN_GRID_SIGMA = 6.0
#: Gaussian kernels are truncated at this many sigmas.
TRUNCATE = 4.0
#: Most range levels chosen automatically (memory: levels x H x W doubles).
MAX_AUTO_LEVELS = 64


def auto_levels(span: float, sigma_range: float) -> int:
    """Levels spaced at most ``sigma_range`` apart over ``span`` (2 to MAX_AUTO_LEVELS)."""
    return min(MAX_AUTO_LEVELS, max(2, int(math.ceil(span / sigma_range - 1e-9)) + 1))


def interp_weights(n_full: int, n_grid: int, factor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear interpolation from cell centres of a coarse grid to pixels.

    Cell ``i`` covers pixels ``[i f, (i + 1) f)``; its centre is at
    ``i f + (f - 1) / 2`` (the last, possibly partial, cell is treated as a
    full one: its centre is clamped into the image).
    """
    x = np.arange(n_full, dtype=np.float64)
    centres = np.minimum(np.arange(n_grid) * factor + (factor - 1) / 2.0, n_full - 1.0)
    if n_grid == 1:
        zeros = np.zeros(n_full, dtype=np.intp)
        return zeros, zeros, np.zeros(n_full)
    i1 = np.clip(np.searchsorted(centres, x, side="right"), 1, n_grid - 1)
    i0 = i1 - 1
    span = centres[i1] - centres[i0]
    t = np.clip((x - centres[i0]) / span, 0.0, 1.0)
    return i0.astype(np.intp), i1.astype(np.intp), t


def gaussian_matrix(n: int, sigma: float) -> np.ndarray:
    """(n, n) matrix of scipy's ``gaussian_filter1d`` (mode 'constant', cval 0, :data:`TRUNCATE`).

    Row ``i`` holds the weights of the samples ``j`` that output ``i`` sums:
    the normalised Gaussian of ``j - i``, zero beyond ``int(TRUNCATE sigma +
    0.5)`` and outside ``[0, n)``.
    """
    radius = int(TRUNCATE * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 / (sigma * sigma) * x * x)
    k /= k.sum()
    d = np.arange(n)[None, :] - np.arange(n)[:, None]
    return np.where(np.abs(d) <= radius, k[np.clip(d + radius, 0, 2 * radius)], 0.0)


def _grid_blur(xp: Any, grid_shape: tuple[int, int], sigma: float, like: Any) -> Callable[[Any], Any]:
    """The spatial Gaussian of a (K, gh, gw) stack of grid levels, zero outside the grid.

    The one per-backend kernel of the filter.  numpy: scipy's separable
    ``gaussian_filter`` on each level, in place (its cost grows with the
    kernel's radius, not the grid's side).  torch: ``M_y s M_x^T`` with the
    banded matrices of :func:`gaussian_matrix`, one batched product (what a
    device runs fast; the coarse grid keeps them small).  The two agree to
    rounding (tests/test_filters.py).
    """
    if xp.name == "numpy":
        def blur(s: np.ndarray) -> np.ndarray:
            for k in range(s.shape[0]):
                s[k] = ndimage.gaussian_filter(s[k], sigma, mode="constant", cval=0.0, truncate=TRUNCATE)
            return s
        return blur
    my = xp.asarray(gaussian_matrix(grid_shape[0], sigma), like=like, dtype=like.dtype)
    mxt = xp.asarray(gaussian_matrix(grid_shape[1], sigma).T, like=like, dtype=like.dtype)
    return lambda s: my @ s @ mxt


def _checked(xp: Any, guide: Any, weights: Any, *, sigma_spatial: float, sigma_range: float, levels: int | None,
             downsample: int | None) -> tuple[Any, Any]:
    """The guide (H, W) float64 and the weights (1 when None), checked with the options (MethodError)."""
    g = xp.asarray(guide, dtype=xp.float64)
    if g.ndim != 2 or 0 in g.shape:
        raise MethodError(f"joint bilateral guide of shape {tuple(g.shape)}: expected a non-empty (H, W) image")
    if not bool(xp.isfinite(g).all()):
        raise MethodError("joint bilateral guide contains NaN or infinite values")
    if not (np.isfinite(sigma_spatial) and sigma_spatial > 0):
        raise MethodError(f"sigma_spatial={sigma_spatial!r}: expected a positive number of pixels")
    if not (np.isfinite(sigma_range) and sigma_range > 0):
        raise MethodError(f"sigma_range={sigma_range!r}: expected a positive number in guide units")
    if levels is not None and (int(levels) != levels or levels < 2):
        raise MethodError(f"levels={levels!r}: expected an integer >= 2")
    if downsample is not None and (int(downsample) != downsample or downsample < 1):
        raise MethodError(f"downsample={downsample!r}: expected an integer >= 1")
    h, w = g.shape
    if weights is None:
        wts = xp.zeros((h, w), like=g) + 1.0
    else:
        wts = xp.asarray(weights, like=g, dtype=xp.float64)
        if wts.shape != g.shape:
            raise MethodError(f"weights of shape {tuple(wts.shape)}: expected the guide's shape {(h, w)}")
        if not bool(xp.isfinite(wts).all()) or float(wts.min()) < 0:
            raise MethodError("weights must be finite and non-negative")
    return g, wts


class JointBilateral:
    """A joint bilateral filter bound to one guide image.

    The range weights, the coarse grid and the interpolation indices depend
    on the guide only; build the object once and call it on several images
    (Yang et al.'s highlight removal filters a changing image with a fixed
    guide).

    Parameters
    ----------
    guide
        (H, W) float, finite: a numpy array, or a ``torch.Tensor`` to filter
        on its device (every array the object makes and returns is then a
        float64 tensor there; the range levels, ``.levels``, stay a numpy
        array).
    sigma_spatial
        Spatial Gaussian sigma in pixels, > 0.
    sigma_range
        Range Gaussian sigma in guide units, > 0.
    levels
        Number of range levels K >= 2 (None: levels spaced at most
        ``sigma_range`` apart over the guide's span, at most
        :data:`MAX_AUTO_LEVELS`).  Yang et al. use 8 to
        10; more levels approach the exact filter.
    weights
        Optional (H, W) non-negative confidence per pixel (0 excludes it).
    downsample
        Integer grid spacing for the blurred components (None: the largest
        spacing that keeps ``sigma_spatial / downsample >= 6``; 1 computes
        them at full resolution).

    Raises
    ------
    MethodError
        Shapes, non-finite values or non-positive parameters.
    """

    def __init__(
        self,
        guide: Any,
        *,
        sigma_spatial: float,
        sigma_range: float,
        levels: int | None = None,
        weights: Any = None,
        downsample: int | None = None,
    ) -> None:
        self.xp = xp = namespace(guide)
        g, wts = _checked(xp, guide, weights, sigma_spatial=sigma_spatial, sigma_range=sigma_range, levels=levels,
                          downsample=downsample)
        h, w = g.shape
        self.shape = (h, w)
        self.sigma_spatial = float(sigma_spatial)
        self.sigma_range = float(sigma_range)
        factor = int(downsample) if downsample is not None else max(
            1, int(self.sigma_spatial // MIN_GRID_SIGMA))
        factor = min(factor, max(h, w))
        self.downsample = factor
        self.grid_shape = (-(-h // factor), -(-w // factor))
        self.grid_sigma = self.sigma_spatial / factor

        gmin, gmax = float(g.min()), float(g.max())
        n_levels = int(levels) if levels is not None else auto_levels(gmax - gmin, self.sigma_range)
        if gmax - gmin <= 0:
            n_levels = 1
        self.levels = np.linspace(gmin, gmax, n_levels) if n_levels > 1 else np.array([gmin])
        levels_a = xp.asarray(self.levels, like=g)

        self._range_w = self._range_weights(g, wts, levels_a)
        self._blur = _grid_blur(xp, self.grid_shape, self.grid_sigma, g)
        den = self._blur(self._splat(None))
        self._den_ok = den > 1e-300
        self._den = xp.where(self._den_ok, den, 1.0)

        self._slicing(g, gmin, gmax, n_levels)

    def _range_weights(self, g: Any, wts: Any, levels_a: Any) -> Any:
        """``exp(-((L_k - g) / sigma_range)^2 / 2) w`` of every level k, (K, H, W) or, with a coarse grid,
        laid out cell by cell (cells, K, factor^2) for the splatting product (the image zero-padded to
        whole cells; the padding has weight 0)."""
        xp, factor = self.xp, self.downsample
        h, w = self.shape
        gh, gw = self.grid_shape
        self._pad = (gh * factor - h, gw * factor - w)
        inv = 1.0 / self.sigma_range
        if factor == 1:
            rw = levels_a[:, None, None] - g[None]
            wb = wts[None]
        else:
            rw = levels_a[None, :, None] - self._cells(g)[:, None, :]
            wb = self._cells(wts)[:, None, :]
        # In place: exp(-((L_k - g) / sigma_range)^2 / 2) * w.
        rw *= inv
        rw *= rw
        rw *= -0.5
        xp.exp(rw, out=rw)
        rw *= wb
        return rw

    def _slicing(self, g: Any, gmin: float, gmax: float, n_levels: int) -> None:
        """Trilinear slicing tables: each pixel blends two levels x four grid corners of the (small,
        cache-resident) table of components (``_idx``, ``_slice_w``, ``_slice_ok``)."""
        xp, factor = self.xp, self.downsample
        h, w = self.shape
        gh, gw = self.grid_shape
        if n_levels > 1:
            kf = (g - gmin) * ((n_levels - 1) / (gmax - gmin))
            k0 = xp.astype(xp.clip(xp.floor(kf), 0, n_levels - 2), xp.index)
            a = xp.clip(kf - k0, 0.0, 1.0)
        else:
            k0 = xp.zeros((h, w), like=g, dtype=xp.index)
            a = xp.zeros((h, w), like=g)
        y0, y1, ty = (xp.asarray(v, like=g) for v in interp_weights(h, gh, factor))
        x0, x1, tx = (xp.asarray(v, like=g) for v in interp_weights(w, gw, factor))
        idx = xp.zeros((8, h, w), like=k0)
        wgt = xp.zeros((8, h, w), like=g)
        j = 0
        for k_idx, k_w in ((k0, 1.0 - a), (xp.clip(k0 + 1, 0, n_levels - 1), a)):
            k_base = k_idx * (gh * gw)
            for yy, wy in ((y0, 1.0 - ty), (y1, ty)):
                for xx, wx in ((x0, 1.0 - tx), (x1, tx)):
                    xp.add(k_base, (yy * gw)[:, None] + xx[None, :], out=idx[j])
                    xp.mul(k_w, wy[:, None] * wx[None, :], out=wgt[j])
                    j += 1
        self._idx = idx
        # Components with no weight within reach are undefined: those corners
        # are dropped and the remaining interpolation weights renormalised.
        # _slice_ok: the pixels with a defined result (None: all of them).
        self._slice_ok = None
        if not bool(self._den_ok.all()):
            wgt *= self._den_ok.reshape(-1)[idx]
            total = xp.sum(wgt, 0)
            self._slice_ok = total > 1e-12
            wgt /= xp.where(self._slice_ok, total, 1.0)
        self._slice_w = wgt

    def _cells(self, a: Any) -> Any:
        """(H, W) -> (cells, factor^2), zero-padded to whole cells."""
        factor = self.downsample
        gh, gw = self.grid_shape
        h, w = self.shape
        if self._pad != (0, 0):
            ap = self.xp.zeros((gh * factor, gw * factor), like=a)
            ap[:h, :w] = a
            a = ap
        cells = self.xp.permute(a.reshape(gh, factor, gw, factor), (0, 2, 1, 3))
        return cells.reshape(gh * gw, factor * factor)

    def _splat(self, f: Any) -> Any:
        """``sum over each grid cell of range_w_k * f`` (f = 1 when None): (K, gh, gw)."""
        factor = self.downsample
        gh, gw = self.grid_shape
        if factor == 1:
            return self.xp.copy(self._range_w) if f is None else self._range_w * f[None]
        if f is None:
            sums = self.xp.sum(self._range_w, 2)
        else:
            sums = (self._range_w @ self._cells(f)[:, :, None])[..., 0]
        return self.xp.copy(sums.T).reshape(-1, gh, gw)

    def __call__(self, image: Any) -> Any:
        """Filter ``image`` (H, W) or (H, W, C); returns float64 of its shape.

        An array of the guide's kind (a numpy array, or a tensor on the
        guide's device).  Where no pixel with non-zero weight lies within the
        kernel's support the input value is returned unchanged.
        """
        xp = self.xp
        f = xp.asarray(image, like=self._den, dtype=xp.float64)
        if tuple(f.shape[:2]) != self.shape or f.ndim not in (2, 3):
            raise MethodError(
                f"joint bilateral image of shape {tuple(f.shape)}: expected (H, W) or (H, W, C) "
                f"with (H, W) = {self.shape}, the guide's shape"
            )
        if not bool(xp.isfinite(f).all()):
            raise MethodError("joint bilateral image contains NaN or infinite values")
        if f.ndim == 3:
            return xp.stack([self(f[..., c]) for c in range(f.shape[2])], axis=-1)
        num = self._blur(self._splat(f))
        comp = xp.where(self._den_ok, num / self._den, 0.0)
        out = xp.einsum("khw,khw->hw", comp.reshape(-1)[self._idx], self._slice_w)
        return out if self._slice_ok is None else xp.where(self._slice_ok, out, f)


def joint_bilateral(
    image: Any,
    guide: Any,
    *,
    sigma_spatial: float,
    sigma_range: float,
    levels: int | None = None,
    weights: Any = None,
    downsample: int | None = None,
) -> np.ndarray:
    """Joint bilateral filter of ``image`` guided by ``guide`` (constant time).

    Parameters
    ----------
    image
        (H, W) or (H, W, C) float, finite.
    guide
        (H, W) float, finite (the range kernel compares its values).
    sigma_spatial
        Spatial Gaussian sigma in pixels, > 0.
    sigma_range
        Range Gaussian sigma in guide units, > 0.
    levels
        Number of range levels (None: spaced at most ``sigma_range`` apart,
        at most :data:`MAX_AUTO_LEVELS`).
    weights
        Optional (H, W) non-negative per-pixel confidences.
    downsample
        Grid spacing of the blurred components (None: automatic, see
        :class:`JointBilateral`).

    Returns
    -------
    numpy.ndarray or torch.Tensor
        float64 of ``image``'s shape, of the guide's kind (see
        :class:`JointBilateral`).  Where every weight within reach is 0, the
        input value.

    Raises
    ------
    MethodError
        Mismatched shapes, non-finite values, non-positive sigmas.
    """
    return JointBilateral(
        guide,
        sigma_spatial=sigma_spatial,
        sigma_range=sigma_range,
        levels=levels,
        weights=weights,
        downsample=downsample,
    )(image)
