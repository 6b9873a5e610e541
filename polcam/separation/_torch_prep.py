"""The tensor method's steps around the IALM in PyTorch, for ``device=`` runs.

With a GPU the IALM of a whole frame takes a fraction of a second, and the
steps before it (illuminant, chromaticity, representations, Yang'10 initial
diffuse, tau, tiling) and after it (blending) become the cost when they run
in numpy on the CPU (about 6 s of a 2448 x 2048 frame on a 16-core machine).
This module runs each of them on the device, as the numpy function of the same
name in :mod:`polcam.separation.tensor`, :mod:`polcam.separation.yang10` and
:mod:`polcam.filters` defines it (same formulas, same order of operations where
it matters, float64 where numpy computes in float64); the tests compare them
with those functions.  The random keys of :func:`representations` come from the
same numpy generator, so the device and numpy pipelines pick the same pixels.

Every function takes and returns ``torch.Tensor`` on the device of its input.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from polcam.filters import _MIN_GRID_SIGMA, _TRUNCATE, _auto_levels, _interp_weights
from polcam.separation._common import EPS

__all__ = [
    "estimate_illuminant",
    "polarization_chromaticity",
    "representations",
    "gather",
    "JointBilateral",
    "yang10",
    "tau_weights",
    "tile_batch",
    "blend",
]


def estimate_illuminant(x: Any, *, significance: float = 5.0) -> np.ndarray:
    """:func:`polcam.separation.tensor.estimate_illuminant` of a (4, H, W, 3) tensor; (3,) numpy."""
    import torch

    x = x.to(torch.float64)
    v = torch.stack([x[0] - x[2], x[1] - x[3]], dim=-1)        # (H, W, 3, 2)
    vs = v.sum(dim=2)                                          # (H, W, 2)
    h, w = vs.shape[:2]
    p = torch.nn.functional.pad(vs.permute(2, 0, 1), (1, 1, 1, 1))  # zeros outside (BORDER_CONSTANT)
    box = sum(p[:, dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3))
    nb = box.permute(1, 2, 0) - vs
    terms = torch.einsum("hwcj,hwj->hwc", v, nb)
    ok = x.amax(dim=(0, 3)) < 0.98
    t = terms[ok]
    if t.numel() == 0:
        return np.full(3, 1 / 3)
    total = t.sum(dim=0).cpu().numpy()
    noise = float(torch.sqrt(torch.sum(t.sum(dim=1) ** 2)))
    if total.sum() <= significance * noise or np.any(total <= 0):
        return np.full(3, 1 / 3)
    return total / total.sum()


def polarization_chromaticity(x: Any) -> Any:
    """:func:`polcam.separation.tensor.polarization_chromaticity` of a (4, H, W, 3) tensor."""
    import torch

    s0 = (x[0] + x[1] + x[2] + x[3]) * 0.5
    ic = s0 * 0.5
    isv = torch.hypot(x[0] - x[2], x[1] - x[3]) * 0.5
    raw_d = torch.clamp_min(ic - 2.0 * isv, 0.0)
    i_min_bar = ic.amin(dim=-1).mean()
    denom = raw_d.sum(dim=-1, keepdim=True) + i_min_bar
    pos = denom > 0
    return torch.where(pos, raw_d / torch.where(pos, denom, torch.ones_like(denom)), torch.zeros_like(raw_d))


def representations(chro: Any, *, n4: int, block: int, threshold: float,
                    rng: np.random.Generator) -> tuple[Any, float]:
    """:func:`polcam.separation.tensor.representations` of an (H, W, 3) tensor.

    The random keys are drawn from ``rng`` exactly as the numpy function draws
    them, so both pick the same neighbours.  Returns (n4, H, W, 2) int64 offsets.
    """
    import torch

    from polcam.separation.tensor import _candidates

    cand = _candidates(n4, block)
    h, w, _ = chro.shape
    dev = chro.device
    r = block // 2
    offsets = torch.zeros((n4, h, w, 2), dtype=torch.int64, device=dev)
    if n4 == 1 or not cand:
        return offsets, 0.0
    pad = torch.nn.functional.pad(chro.permute(2, 0, 1), (r, r, r, r), value=math.inf)
    keys = torch.as_tensor(rng.random((len(cand), h, w)), device=dev)
    for j, (dy, dx) in enumerate(cand):
        q = pad[:, r + dy:r + dy + h, r + dx:r + dx + w].permute(1, 2, 0)
        dist = torch.sqrt(torch.sum((q - chro) ** 2, dim=-1))
        keys[j] = torch.where(dist < threshold, keys[j], math.inf)
    take = min(n4 - 1, len(cand))
    picked, order = torch.sort(keys, dim=0)
    picked, order = picked[:take], order[:take]
    cand_t = torch.tensor(cand, dtype=torch.int64, device=dev)
    valid = torch.isfinite(picked)
    offsets[1:take + 1] = torch.where(valid[..., None], cand_t[order], 0)
    filled = float(valid.to(torch.float64).mean()) * take / (n4 - 1)
    return offsets, filled


def gather(images: Any, offsets: Any) -> Any:
    """:func:`polcam.separation.tensor.gather`: (..., H, W, C) -> (n4, ..., H, W, C)."""
    import torch

    h, w = offsets.shape[1:3]
    lead = images.shape[:-3]
    c = images.shape[-1]
    flat = images.reshape(*lead, h * w, c)
    base = torch.arange(h * w, device=images.device).reshape(h, w)
    out = []
    for off in offsets:
        idx = (base + off[..., 0] * w + off[..., 1]).reshape(-1)
        out.append(flat.index_select(-2, idx).reshape(*lead, h, w, c))
    return torch.stack(out)


def _gauss_matrix(n: int, sigma: float, like: Any) -> Any:
    """(n, n) matrix of scipy's ``gaussian_filter1d`` with mode 'constant' (cval 0), ``truncate``."""
    import torch

    radius = int(_TRUNCATE * sigma + 0.5)
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
        factor = max(1, int(float(sigma_spatial) // _MIN_GRID_SIGMA))
        factor = min(factor, max(h, w))
        self.downsample = factor
        gh, gw = -(-h // factor), -(-w // factor)
        self.grid_shape = (gh, gw)
        grid_sigma = float(sigma_spatial) / factor
        gmin, gmax = float(g.min()), float(g.max())
        n_levels = int(levels) if levels is not None else _auto_levels(gmax - gmin, float(sigma_range))
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
        y0, y1, ty = (torch.as_tensor(v, device=g.device) for v in _interp_weights(h, gh, factor))
        x0, x1, tx = (torch.as_tensor(v, device=g.device) for v in _interp_weights(w, gw, factor))
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


def tau_weights(first: Any, *, alpha: float, beta: float, floor: float) -> Any:
    """:func:`polcam.separation.tensor.tau_weights` of a (4, n1, n2, 3) tensor (``np.gradient``'s edges)."""
    import torch

    def grad(a: Any, dim: int) -> Any:
        n = a.shape[dim]
        if n < 2:
            return torch.zeros_like(a)
        out = torch.empty_like(a)
        sl = [slice(None)] * a.ndim

        def at(s: slice | int) -> tuple[Any, ...]:
            return tuple(sl[:dim] + [s] + sl[dim + 1:])

        out[at(slice(1, -1))] = (a[at(slice(2, None))] - a[at(slice(None, -2))]) * 0.5
        out[at(0)] = a[at(1)] - a[at(0)]
        out[at(-1)] = a[at(-1)] - a[at(-2)]
        return out

    gy, gx = grad(first, 1), grad(first, 2)
    g = torch.sqrt(gx * gx + gy * gy)
    return torch.clamp_min(1.0 - first, floor) * torch.exp(alpha * g ** beta)


def _spans(spans: list[tuple[int, int]], device: Any) -> Any:
    import torch

    return torch.stack([torch.arange(a, b, device=device) for a, b in spans])


def tile_batch(images: Any, ys: list[tuple[int, int]], xs: list[tuple[int, int]]) -> Any:
    """Every tile of (n4, 4, H, W, 3) images unfolded slice-first: (tiles, n4, 4 n1, 3 n2).

    Tiles in :func:`polcam.separation.tensor.tile_windows` order (row by row);
    each is :func:`polcam.separation.tensor.unfold_slices` of its window.
    """
    ry, rx = _spans(ys, images.device), _spans(xs, images.device)
    n4, na = images.shape[:2]
    t = images[:, :, ry[:, None, :, None], rx[None, :, None, :]]      # (n4, 4, ny, nx, n1, n2, 3)
    ny, nx, n1, n2, c = t.shape[2:]
    return t.permute(2, 3, 0, 1, 4, 6, 5).reshape(ny * nx, n4, na * n1, c * n2)


def blend(shape: tuple[int, int], ys: list[tuple[int, int]], xs: list[tuple[int, int]],
          results: Any) -> Any:
    """:func:`polcam.separation.tensor.blend` of (tiles, n1, n2, C) results; (H, W, C) float64."""
    import torch

    from polcam.separation.tensor import _ramps

    dev = results.device
    h, w = shape
    wy = torch.as_tensor(np.stack(_ramps(ys)), device=dev)      # (ny, n1)
    wx = torch.as_tensor(np.stack(_ramps(xs)), device=dev)      # (nx, n2)
    ny, nx = len(ys), len(xs)
    wt = (wy[:, None, :, None] * wx[None, :, None, :]).reshape(ny * nx, wy.shape[1], wx.shape[1], 1)
    ry, rx = _spans(ys, dev), _spans(xs, dev)
    rows = ry[:, None, :, None].expand(ny, nx, ry.shape[1], rx.shape[1]).reshape(ny * nx, ry.shape[1], rx.shape[1])
    cols = rx[None, :, None, :].expand(ny, nx, ry.shape[1], rx.shape[1]).reshape(ny * nx, ry.shape[1], rx.shape[1])
    c = results.shape[-1]
    acc = torch.zeros((h, w, c), dtype=torch.float64, device=dev)
    wsum = torch.zeros((h, w, 1), dtype=torch.float64, device=dev)
    acc.index_put_((rows, cols), wt * results.to(torch.float64), accumulate=True)
    wsum.index_put_((rows, cols), wt.expand(-1, -1, -1, 1), accumulate=True)
    return acc / wsum
