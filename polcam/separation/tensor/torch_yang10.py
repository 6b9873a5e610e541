"""Yang'10's single-image separation on a PyTorch device: the initial diffuse of ``device=`` runs.

With a GPU the IALM of a whole frame takes a fraction of a second, and the
initial diffuse (Yang, Wang & Ahuja 2010, four runs on the angle images) would
become the cost in numpy on the CPU.  :func:`yang10` is
:func:`polcam.separation.yang10.separate_yang10` with its default options and
:class:`JointBilateral` is :class:`polcam.filters.JointBilateral`, written for
``torch.Tensor`` (same formulas, float64, the same grid and truncation
constants from :mod:`polcam.filters`); the tests compare them with those
functions to 1e-10.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam.filters import MIN_GRID_SIGMA, TRUNCATE, auto_levels, interp_weights
from polcam.separation._common import EPS

__all__ = ["JointBilateral", "yang10"]


def _gauss_matrix(n: int, sigma: float, like: Any) -> Any:
    """(n, n) matrix of scipy's ``gaussian_filter1d`` with mode 'constant' (cval 0), ``truncate``."""
    import torch

    radius = int(TRUNCATE * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 / (sigma * sigma) * x * x)
    k /= k.sum()
    d = np.arange(n)[None, :] - np.arange(n)[:, None]              # column index minus row index
    m = np.where(np.abs(d) <= radius, k[np.clip(d + radius, 0, 2 * radius)], 0.0)
    return torch.as_tensor(m, dtype=like.dtype, device=like.device)


class JointBilateral:
    """:class:`polcam.filters.JointBilateral` on a device (float64), bound to one (H, W) guide.

    The same constant-time filter: range levels, area splatting onto the
    coarse grid, a Gaussian blur of each level (as scipy's ``gaussian_filter``
    with zeros outside, applied as two banded matrices), and trilinear slicing.
    """

    def __init__(self, guide: Any, *, sigma_spatial: float, sigma_range: float,
                 levels: int | None = None, weights: Any = None) -> None:
        import torch

        g = guide.to(torch.float64)
        h, w = g.shape
        wts = torch.ones_like(g) if weights is None else weights.to(torch.float64)
        self.shape = (h, w)
        factor = max(1, int(float(sigma_spatial) // MIN_GRID_SIGMA))
        factor = min(factor, max(h, w))
        self.downsample = factor
        gh, gw = -(-h // factor), -(-w // factor)
        self.grid_shape = (gh, gw)
        grid_sigma = float(sigma_spatial) / factor
        gmin, gmax = float(g.min()), float(g.max())
        n_levels = int(levels) if levels is not None else auto_levels(gmax - gmin, float(sigma_range))
        if gmax - gmin <= 0:
            n_levels = 1
        lv = np.linspace(gmin, gmax, n_levels) if n_levels > 1 else np.array([gmin])
        self._pad = (gh * factor - h, gw * factor - w)
        levels_t = torch.as_tensor(lv, device=g.device)
        rw = (levels_t[None, :, None] - self._cells(g)[:, None, :]) * (1.0 / float(sigma_range))
        self._range_w = torch.exp(-0.5 * rw * rw) * self._cells(wts)[:, None, :]    # (cells, K, f^2)
        self._my = _gauss_matrix(gh, grid_sigma, g)
        self._mx = _gauss_matrix(gw, grid_sigma, g)
        den = self._blur(self._splat(None))
        self._den_ok = den > 1e-300
        self._den = torch.where(self._den_ok, den, torch.ones_like(den))
        if n_levels > 1:
            kf = (g - gmin) * ((n_levels - 1) / (gmax - gmin))
            k0 = torch.clamp(torch.floor(kf), 0, n_levels - 2).to(torch.int64)
            a = torch.clamp(kf - k0, 0.0, 1.0)
        else:
            k0 = torch.zeros(g.shape, dtype=torch.int64, device=g.device)
            a = torch.zeros_like(g)
        y0, y1, ty = (torch.as_tensor(v, device=g.device) for v in interp_weights(h, gh, factor))
        x0, x1, tx = (torch.as_tensor(v, device=g.device) for v in interp_weights(w, gw, factor))
        idx, wgt = [], []
        for k_idx, k_w in ((k0, 1.0 - a), (torch.clamp_max(k0 + 1, n_levels - 1), a)):
            k_base = k_idx * (gh * gw)
            for yy, wy in ((y0, 1.0 - ty), (y1, ty)):
                for xx, wx in ((x0, 1.0 - tx), (x1, tx)):
                    idx.append(k_base + ((yy * gw)[:, None] + xx[None, :]))
                    wgt.append(k_w * (wy[:, None] * wx[None, :]))
        self._idx = torch.stack(idx)
        wgt_t = torch.stack(wgt)
        if not bool(self._den_ok.all()):
            wgt_t = wgt_t * self._den_ok.reshape(-1)[self._idx]
            total = wgt_t.sum(dim=0)
            self._slice_ok = total > 1e-12
            wgt_t = wgt_t / torch.where(self._slice_ok, total, torch.ones_like(total))
        else:
            self._slice_ok = None
        self._slice_w = wgt_t

    def _cells(self, a: Any) -> Any:
        import torch

        f = self.downsample
        gh, gw = self.grid_shape
        ap = torch.nn.functional.pad(a, (0, self._pad[1], 0, self._pad[0]))
        return ap.reshape(gh, f, gw, f).permute(0, 2, 1, 3).reshape(gh * gw, f * f)

    def _splat(self, f: Any) -> Any:
        gh, gw = self.grid_shape
        if f is None:
            sums = self._range_w.sum(dim=2)
        else:
            sums = (self._range_w @ self._cells(f)[:, :, None])[..., 0]
        return sums.T.reshape(-1, gh, gw)

    def _blur(self, s: Any) -> Any:
        return self._my @ s @ self._mx.T

    def __call__(self, f: Any) -> Any:
        """Filter an (H, W) float64 tensor."""
        import torch

        num = self._blur(self._splat(f))
        comp = torch.where(self._den_ok, num / self._den, torch.zeros_like(num))
        out = (comp.reshape(-1)[self._idx] * self._slice_w).sum(dim=0)
        return out if self._slice_ok is None else torch.where(self._slice_ok, out, f)


def _safe_divide(num: Any, den: Any, fill: float, eps: float = EPS) -> Any:
    import torch

    ok = den.abs() > eps
    return torch.where(ok, num / torch.where(ok, den, torch.ones_like(den)), torch.full_like(num, fill))


def yang10(image: Any, *, sigma_range: float = 0.04, threshold: float = 0.03,
           dark: float = 20.0 / 255.0, max_iter: int = 50) -> Any:
    """:func:`polcam.separation.yang10.separate_yang10` (default options) of an (H, W, 3) tensor.

    The image is taken as float64 in [0, 1]; returns the diffuse layer, float64,
    in [0, image].
    """
    import torch

    img = image.to(torch.float64).clamp(0.0, 1.0)
    h, w, _ = img.shape
    i_max = img.amax(dim=-1)
    total = img.sum(dim=-1)
    sigma_max = _safe_divide(i_max, total, 1.0 / 3.0)
    bright = i_max > dark
    if not bool(bright.any()):
        return img
    free = img - img.amin(dim=-1, keepdim=True)
    ftot = free.sum(dim=-1, keepdim=True)
    ok = ftot > torch.clamp_min(1e-9 * total[..., None], EPS)
    lam_guide = torch.where(ok, free / torch.where(ok, ftot, torch.ones_like(ftot)),
                            torch.full_like(free, 1.0 / 3.0)).amax(dim=-1)
    filt = JointBilateral(lam_guide, sigma_spatial=0.25 * min(h, w), sigma_range=sigma_range,
                          weights=bright.to(torch.float64))
    for _ in range(max_iter):
        filtered = filt(sigma_max)
        changed = bool(((filtered - sigma_max > threshold) & bright).any())
        sigma_max = torch.where(bright, torch.maximum(sigma_max, filtered), sigma_max)
        if not changed:
            break
    # diffuse_from_max_chromaticity
    sig = _safe_divide(i_max, total, 1.0 / 3.0)
    lam = torch.maximum(sigma_max.clamp(1.0 / 3.0, 1.0), sig)
    spec = _safe_divide(total * (lam - sig), 3.0 * lam - 1.0, 0.0, eps=1e-6)
    diffuse = torch.nan_to_num(img - spec[..., None], nan=0.0, posinf=0.0, neginf=0.0)
    diffuse = torch.minimum(diffuse.clamp_min(0.0), img)
    return torch.where(bright[..., None], diffuse, img)
