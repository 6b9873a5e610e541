"""Image filters over numpy (OpenCV) and PyTorch: the kernels that differ between the two backends.

``polarized-residual`` (:mod:`polcam.separation.polarized_residual`) and its helpers are
written once over :mod:`polcam._xp`; the neighbourhood operations they use are here, one
function per operation.  A numpy array goes through the OpenCV call the method always used
(so the numpy path is unchanged); a ``torch.Tensor`` is filtered on its device with the same
kernel and the same border rule, so the two agree to float32 rounding (tested in
tests/test_imageops.py against the OpenCV calls):

* :func:`gaussian` - ``cv2.GaussianBlur(a, (k, k), 0)``: OpenCV's kernel for ``sigma = 0``
  (``cv2.getGaussianKernel``), border reflected without repeating the edge pixel
  (``BORDER_REFLECT_101``);
* :func:`box` - ``cv2.boxFilter`` (sum or mean over ``k x k``), the same border;
* :func:`median` - ``cv2.medianBlur`` (``k`` = 3 or 5), border replicated;
* :func:`dilate`, :func:`erode` - with a ``k x k`` square; outside the image does not count;
* :func:`sobel` - ``cv2.Sobel(a, CV_32F, dx, dy, ksize=3)``, ``BORDER_REFLECT_101``;
* :func:`resize` - ``cv2.resize`` with ``INTER_AREA`` (shrinking only) or ``INTER_LINEAR``: on
  torch, as two resampling matrices built with OpenCV's weights (``M_y a M_x^T``).
* :func:`shrunk` - any of these at a coarser scale: the array shrunk by an integer factor
  (``resize``, area), filtered, and brought back (``resize``, bilinear).

Arrays are (H, W) or (H, W, C); every function returns the input's shape and dtype.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from polcam._xp import namespace

__all__ = ["gaussian", "box", "median", "dilate", "erode", "sobel", "resize", "shrunk"]


def _reflect101(n: int, r: int) -> np.ndarray:
    """Indices of ``range(-r, n + r)`` folded into ``[0, n)`` as OpenCV's ``BORDER_REFLECT_101``."""
    p = np.arange(-r, n + r)
    if n == 1:
        return np.zeros_like(p)
    period = 2 * n - 2
    p = np.mod(p, period)
    return np.where(p >= n, period - p, p)


def _nchw(a: Any) -> tuple[Any, bool]:
    """(H, W) or (H, W, C) tensor as (C, 1, H, W) for torch's 1-channel convolutions."""
    if a.ndim == 2:
        return a[None, None], False
    return a.permute(2, 0, 1)[:, None], True


def _back(x: Any, had_c: bool) -> Any:
    return x[:, 0].permute(1, 2, 0).contiguous() if had_c else x[0, 0]


def _separable(a: Any, ky: np.ndarray, kx: np.ndarray) -> Any:
    """Correlate a tensor with ``ky`` (rows) then ``kx`` (columns), border ``BORDER_REFLECT_101``.

    As a weighted sum of shifted copies (the kernels are short): one elementwise pass per tap, which
    runs well on any device, where a one-channel convolution does not on a CPU.
    """
    import torch

    x = a
    for dim, kern in ((0, ky), (1, kx)):
        n = x.shape[dim]
        r = len(kern) // 2
        padded = x.index_select(dim, torch.as_tensor(_reflect101(n, r), device=x.device))
        out = None
        for j, wj in enumerate(kern):
            if wj == 0:
                continue
            term = float(wj) * padded.narrow(dim, j, n)
            out = term if out is None else out + term
        x = out
    return x


def gaussian(a: Any, k: int) -> Any:
    """``k x k`` Gaussian blur with OpenCV's default sigma for ``k`` (odd), as ``cv2.GaussianBlur(a, (k, k), 0)``."""
    if namespace(a).name == "numpy":
        return cv2.GaussianBlur(a, (k, k), 0)
    g = cv2.getGaussianKernel(k, 0).ravel()
    return _separable(a, g, g)


def box(a: Any, k: int, *, normalize: bool = True) -> Any:
    """``k x k`` box sum (``normalize=False``) or mean, as ``cv2.boxFilter(a, -1, (k, k), normalize=...)``.

    torch: a difference of cumulative sums in float64 (a wide box's sum stays exact to float32).
    """
    if namespace(a).name == "numpy":
        return cv2.boxFilter(a, -1, (k, k), normalize=normalize)
    import torch

    x, had_c = _nchw(a)
    h, w = x.shape[-2:]
    r = k // 2
    dtype = x.dtype
    x = x.to(torch.float64)
    for dim, n in ((-2, h), (-1, w)):
        x = x.index_select(dim, torch.as_tensor(_reflect101(n, r), device=x.device))
        c = torch.nn.functional.pad(x.cumsum(dim), (0, 0, 1, 0) if dim == -2 else (1, 0))
        x = c.narrow(dim, k, n) - c.narrow(dim, 0, n)
    if normalize:
        x = x / float(k * k)
    return _back(x.to(dtype), had_c)


def median(a: Any, k: int) -> Any:
    """``k x k`` median (``k`` = 3 or 5), border replicated, as ``cv2.medianBlur(a, k)`` (float32)."""
    if namespace(a).name == "numpy":
        return cv2.medianBlur(a, k)
    import torch

    x, had_c = _nchw(a)
    r = k // 2
    x = torch.nn.functional.pad(x, (r, r, r, r), mode="replicate")
    patches = x.unfold(-2, k, 1).unfold(-2, k, 1)               # (C, 1, H, W, k, k)
    return _back(patches.reshape(*patches.shape[:4], k * k).median(dim=-1).values, had_c)


def dilate(a: Any, k: int) -> Any:
    """Maximum over a ``k x k`` square (``k`` odd), as ``cv2.dilate(a, np.ones((k, k), np.uint8))``."""
    if namespace(a).name == "numpy":
        return cv2.dilate(a, np.ones((k, k), np.uint8))
    return _max_pool(a, k)


def erode(a: Any, k: int) -> Any:
    """Minimum over a ``k x k`` square (``k`` odd), as ``cv2.erode(a, np.ones((k, k), np.uint8))``."""
    if namespace(a).name == "numpy":
        return cv2.erode(a, np.ones((k, k), np.uint8))
    if a.dtype.is_floating_point:
        return -_max_pool(-a, k)
    return 1 - _max_pool(1 - a, k)                              # a 0/1 mask (bool or integer)


def _max_pool(a: Any, k: int) -> Any:
    import torch

    dtype = a.dtype
    x, had_c = _nchw(a if dtype.is_floating_point else a.to(torch.float32))
    x = _running_max(x, k).transpose(-1, -2)
    x = _running_max(x, k).transpose(-1, -2)
    return _back(x.contiguous(), had_c).to(dtype)


def _running_max(x: Any, k: int) -> Any:
    """Maximum over the centred window of ``k`` (odd) samples along the last axis; outside never wins.

    van Herk's (1992) and Gil & Werman's (1993) method: the padded row is cut into blocks of ``k``,
    and each window, which spans at most two blocks, is the larger of a suffix maximum of one and a
    prefix maximum of the next (two cumulative maxima), so the cost does not grow with ``k``.
    """
    import torch

    n = x.shape[-1]
    r = k // 2
    length = -(-(n + 2 * r) // k) * k
    p = torch.nn.functional.pad(x, (r, length - n - r), value=float("-inf"))
    blocks = p.reshape(*p.shape[:-1], length // k, k)
    pre = blocks.cummax(dim=-1).values.reshape(p.shape)
    suf = blocks.flip(-1).cummax(dim=-1).values.flip(-1).reshape(p.shape)
    return torch.maximum(suf[..., :n], pre[..., k - 1:k - 1 + n])


#: Sobel kernels by size: (smoothing, derivative), OpenCV's.
_SOBEL = {3: (np.array([1.0, 2.0, 1.0]), np.array([-1.0, 0.0, 1.0])),
          5: (np.array([1.0, 4.0, 6.0, 4.0, 1.0]), np.array([-1.0, -2.0, 0.0, 2.0, 1.0]))}


def sobel(a: Any, dx: int, dy: int, ksize: int = 3) -> Any:
    """Sobel derivative (``(dx, dy)`` = (1, 0) or (0, 1)), as ``cv2.Sobel(a, cv2.CV_32F, dx, dy, ksize=ksize)``.

    ``ksize`` 3 or 5.  Not normalised, as OpenCV's are not: on a ramp of slope 1 per pixel the
    3 x 3 gives 8 and the 5 x 5 gives 128.
    """
    if ksize not in _SOBEL:
        raise ValueError(f"ksize {ksize}: expected 3 or 5")
    if namespace(a).name == "numpy":
        return cv2.Sobel(a, cv2.CV_32F, dx, dy, ksize=ksize)
    s, d = _SOBEL[ksize]
    return _separable(a, s, d) if dx else _separable(a, d, s)


def resize(a: Any, size: tuple[int, int], *, interpolation: str) -> Any:
    """``a`` resampled to ``size`` = (width, height), as ``cv2.resize`` with ``INTER_AREA`` or ``INTER_LINEAR``.

    ``interpolation``: ``"area"`` (the mean over each output pixel's footprint; only for shrinking,
    as the method uses it) or ``"linear"`` (bilinear, pixel centres aligned as OpenCV does).
    """
    if interpolation not in ("area", "linear"):
        raise ValueError(f"interpolation {interpolation!r}: expected 'area' or 'linear'")
    w_out, h_out = size
    h, w = a.shape[:2]
    if namespace(a).name == "numpy":
        flag = cv2.INTER_AREA if interpolation == "area" else cv2.INTER_LINEAR
        return cv2.resize(a, (w_out, h_out), interpolation=flag)
    import torch

    make = _area_matrix if interpolation == "area" else _linear_matrix
    my = torch.as_tensor(make(h, h_out), dtype=a.dtype, device=a.device)
    mx = torch.as_tensor(make(w, w_out), dtype=a.dtype, device=a.device)
    if a.ndim == 2:
        return my @ a @ mx.T
    return torch.einsum("ih,hwc,jw->ijc", my, a, mx)


def shrunk(a: Any, factor: int, fn: Any) -> Any:
    """``fn`` applied to ``a`` shrunk by the integer ``factor`` (area), brought back to ``a``'s size (bilinear).

    A neighbourhood measure at a coarser scale costs what it costs there; ``fn`` maps an (h, w, ...)
    array to one of the same shape.
    """
    h, w = a.shape[:2]
    small = resize(a, (max(w // factor, 1), max(h // factor, 1)), interpolation="area")
    return resize(fn(small), (w, h), interpolation="linear")


def _area_matrix(n: int, m: int) -> np.ndarray:
    """(m, n) weights of OpenCV's ``INTER_AREA`` from n samples to m <= n: each output averages its footprint."""
    if m > n:
        raise ValueError(f"area resampling from {n} to {m} samples: only shrinking is supported")
    scale = n / m
    out = np.zeros((m, n))
    for i in range(m):
        f1 = i * scale
        f2 = f1 + scale
        cell = min(scale, n - f1)
        s1, s2 = int(np.ceil(f1)), int(np.floor(f2))
        s2 = min(s2, n)
        if s1 - f1 > 1e-3:
            out[i, s1 - 1] = (s1 - f1) / cell
        out[i, s1:s2] = 1.0 / cell
        if s2 < n and f2 - s2 > 1e-3:
            out[i, s2] = min(min(f2 - s2, 1.0), cell) / cell
    return out


def _linear_matrix(n: int, m: int) -> np.ndarray:
    """(m, n) weights of OpenCV's ``INTER_LINEAR`` from n samples to m (half-pixel centres, edges clamped)."""
    scale = n / m
    out = np.zeros((m, n))
    for i in range(m):
        f = (i + 0.5) * scale - 0.5
        j = int(np.floor(f))
        t = f - j
        if j < 0:
            j, t = 0, 0.0
        if j >= n - 1:
            j, t = n - 1, 0.0
        out[i, j] += 1.0 - t
        if t > 0:
            out[i, j + 1] += t
    return out
