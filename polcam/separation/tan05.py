"""``tan05``: iterative specular-to-diffuse mechanism of Tan & Ikeuchi.

R. T. Tan and K. Ikeuchi, "Separating reflection components of textured
surfaces using a single image", IEEE TPAMI 27(2), pp. 178-193, 2005.

Model: dichromatic reflection under a white (white-balanced) illuminant,
``I_c = m_d Lambda_c + m_s / 3``.  Notation: ``T = sum_c I_c`` the total
intensity, ``I_max = max_c I_c``, ``sigma_c = I_c / T`` the chromaticity and
``sigma_max = I_max / T`` the maximum chromaticity.

Equations as implemented:

1. Specular-to-diffuse mechanism.  Given the maximum diffuse
   chromaticity ``Lambda_max`` of a pixel, ``m_d = I_max (3 sigma_max - 1) /
   (sigma_max (3 Lambda_max - 1)) = (3 I_max - T) / (3 Lambda_max - 1)`` and
   the diffuse pixel is ``I_c - (T - m_d) / 3``: the pixel moves along its
   curve in maximum-chromaticity/intensity space until its maximum
   chromaticity is ``Lambda_max``.
2. Specular-free image: the same shift with one arbitrary
   ``Lambda_max`` for every pixel (``sf_max_chromaticity``).  Its total
   intensity is ``T_sf = (3 I_max - T) / (3 Lambda_sf - 1)``, i.e. ``m_d``
   up to a factor that is constant over a surface colour.
3. Intensity logarithmic differentiation: for neighbouring pixels ``x`` and
   ``x + 1`` (right, and below), ``Delta = |(log T(x+1) - log T(x)) -
   (log T_sf(x+1) - log T_sf(x))|``.  It is 0 between diffuse pixels of one
   colour; a pair with ``Delta > epsilon`` holds a specular pixel or a colour
   discontinuity.  Because ``T_sf`` enters through a difference of logs, the
   choice of ``Lambda_sf`` cancels exactly.
4. Colour discontinuity: a flagged pair with ``|Delta sigma_r| >
   chroma_threshold`` and ``|Delta sigma_g| > chroma_threshold`` is a boundary
   and is left alone.
5. Noise: a flagged pair whose maximum chromaticities differ by
   less than ``noise_threshold`` is left alone; so is a pixel whose shift
   would drive a channel to zero or below; pixels with every channel below
   ``dark_threshold`` are never processed (camera noise dominates their
   chromaticity).
6. Otherwise the pixel of the pair with the smaller ``sigma_max`` is shifted
   (step 1) to the other pixel's ``sigma_max``.
7. Iterative framework: for ``epsilon`` from ``epsilon_start`` down to 0 in
   steps of ``epsilon_step``, repeat sweeps of steps 3-6 over the whole image
   while the number of flagged pixels decreases; boundary and noise labels
   hold for one ``epsilon`` level.

Defaults and their sources: ``epsilon_start = 0.5``, ``epsilon_step = 0.01``,
``chroma_threshold = 0.1`` (thR = thG), ``noise_threshold = 0.01``,
``dark_threshold = 20/255`` and ``sf_max_chromaticity = 0.6`` are the values
of the authors' released C++ code (as transliterated in the SIHR toolbox,
V. S. Ramos, Zenodo 3381328, whose results are the reference table of
polcam's SIHR benchmark).  The paper's text could not be consulted while
this module was written; the equations above are the published method as
known from the literature and from the authors' code.

Departures:

* Vectorised sweeps.  The authors' code scans the image in raster order and,
  after processing a pair, marks both pixels as done for the rest of the
  sweep.  Here each sweep processes the flagged pairs as a matching, in four
  whole-image passes (horizontal pairs starting at even columns, at odd
  columns, vertical pairs starting at even rows, at odd rows), each pixel
  taking part in at most one processed pair per sweep.  The result differs
  from the raster scan's in the order in which pairs are visited, not in the
  rule applied to a pair.
* The logarithmic differentiation is the paper's difference of logarithms
  (step 3).  The released code takes ``log |T(x+1) - T(x)|`` instead, which is
  not invariant to the scale factor between ``T`` and ``T_sf``.  Measured on
  the Shen & Zheng images (PSNR in dB, animals / cups / fruit / masks;
  reference 30.4 / 31.6 / 30.4 / 25.8) with a prototype of this
  implementation that also clipped the specular-free image like the released
  code: 31.8 / 32.8 / 31.0 / 26.2 with the released form, 32.1 / 31.9 / 31.8
  / 25.8 with the paper's; this module gives 31.7 / 32.1 / 31.5 / 25.7.
  The specular-free image is not clipped to [0, 1] here (the released code
  stores it in 8 bits), so ``Lambda_sf`` does not matter; it is kept as an
  option only to document the construction.
* The released code runs the first ``epsilon`` level twice; here every level
  runs once.
* Achromatic pixels (``3 I_max - T <= 1e-12``, where ``T_sf = 0`` and the
  logarithm is undefined) are never flagged, like dark pixels: their
  maximum chromaticity is 1/3 whatever their specular part, so chromaticity
  cannot separate them.
* ``max_sweeps`` (default 10000) bounds the total number of sweeps; the
  paper's loop always terminates, so the bound only guards pathological input.

``info`` holds ``iterations`` (sweeps over the image), ``levels`` (epsilon
levels run), ``remaining`` (pixels still flagged at the last level) and
``converged`` (True when the schedule ran to ``epsilon = 0`` within
``max_sweeps``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam.errors import MethodError
from polcam.separation._common import as_rgb_image, finish_diffuse
from polcam.separation._registry import register

REFERENCE = (
    "R. T. Tan and K. Ikeuchi, Separating reflection components of textured surfaces "
    "using a single image, IEEE TPAMI 27(2), pp. 178-193, 2005"
)

__all__ = ["REFERENCE", "separate_tan05", "specular_free_image", "shift_max_chromaticity"]

#: ``3 I_max - T`` (relative to ``T``) at or under which a pixel is achromatic: its maximum chromaticity
#: is 1/3 whatever its specular part, ``T_sf = 0`` and the logarithm is undefined; the same bound on
#: ``3 Lambda_max - 1`` keeps the shift's denominator away from 0.
_ACHROMATIC = 1e-12
#: Added to ``epsilon_start / epsilon_step`` before it is floored, so that a schedule meant to land on 0
#: (0.5 / 0.01) is not cut one level short by floating-point rounding.
_LEVEL_ROUNDING = 1e-9


def shift_max_chromaticity(pixels: np.ndarray, target: np.ndarray | float) -> np.ndarray:
    """Tan & Ikeuchi's specular-to-diffuse shift, without any guard.

    Parameters
    ----------
    pixels
        (..., 3) float64 intensities.
    target
        Maximum diffuse chromaticity ``Lambda_max``, scalar or (...), with
        ``3 Lambda_max - 1 > 0``.

    Returns
    -------
    numpy.ndarray
        (..., 3) ``I - (T - m_d) / 3`` with ``m_d = (3 I_max - T) /
        (3 Lambda_max - 1)``; may hold negative values (the caller decides).
    """
    total = pixels[..., 0] + pixels[..., 1] + pixels[..., 2]
    i_max = np.maximum(np.maximum(pixels[..., 0], pixels[..., 1]), pixels[..., 2])
    m_d = (3.0 * i_max - total) / (3.0 * np.asarray(target, dtype=np.float64) - 1.0)
    return pixels - ((total - m_d) / 3.0)[..., None]


def specular_free_image(image: np.ndarray, *, sf_max_chromaticity: float = 0.6) -> np.ndarray:
    """Tan & Ikeuchi's specular-free image, unclipped.

    Parameters
    ----------
    image
        (H, W, 3) float in [0, 1].
    sf_max_chromaticity
        The arbitrary maximum diffuse chromaticity given to every pixel, in
        (1/3, 1].

    Returns
    -------
    numpy.ndarray
        (H, W, 3) float64; channels may leave [0, 1] (the paper's
        construction; only its total intensity is used).
    """
    _check_range("sf_max_chromaticity", sf_max_chromaticity, 1.0 / 3.0, 1.0, low_open=True)
    return shift_max_chromaticity(np.asarray(image, dtype=np.float64), sf_max_chromaticity)


def _check_range(name: str, value: float, lo: float, hi: float, *, low_open: bool = False) -> None:
    ok = (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, bool)
        and np.isfinite(value)
        and (value > lo if low_open else value >= lo)
        and value <= hi
    )
    if not ok:
        bracket = "(" if low_open else "["
        raise MethodError(f"method 'tan05': {name}={value!r}: expected a number in {bracket}{lo:.4g}, {hi:.4g}]")


def _log_ratio(flat: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
    """``log T - log(3 I_max - T)`` per pixel (NaN where undefined)."""
    px = flat if idx is None else flat[idx]
    total = px[:, 0] + px[:, 1] + px[:, 2]
    chroma_part = 3.0 * np.maximum(np.maximum(px[:, 0], px[:, 1]), px[:, 2]) - total
    ok = (total > 0.0) & (chroma_part > _ACHROMATIC * np.maximum(total, 1.0))
    out = np.full(total.shape, np.nan)
    safe_t = np.where(ok, total, 1.0)
    safe_c = np.where(ok, chroma_part, 1.0)
    out[ok] = np.log(safe_t[ok]) - np.log(safe_c[ok])
    return out


@register("tan05", kind="single", reference=REFERENCE)
def separate_tan05(
    image: np.ndarray,
    *,
    epsilon_start: float = 0.5,
    epsilon_step: float = 0.01,
    chroma_threshold: float = 0.1,
    noise_threshold: float = 0.01,
    dark_threshold: float = 20.0 / 255.0,
    sf_max_chromaticity: float = 0.6,
    max_sweeps: int = 10000,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer by Tan & Ikeuchi's specular-to-diffuse iteration.

    Parameters
    ----------
    image
        (H, W, 3) float64 RGB in [0, 1], white-balanced (specular colour
        white).
    epsilon_start, epsilon_step
        Schedule of the threshold on the logarithmic differentiation:
        ``epsilon_start, epsilon_start - epsilon_step, ..., 0``.
    chroma_threshold
        Colour-discontinuity threshold on both ``|Delta sigma_r|`` and
        ``|Delta sigma_g|``.
    noise_threshold
        Pairs whose maximum chromaticities differ by less are left alone.
    dark_threshold
        Pixels with every channel below this are never processed.
    sf_max_chromaticity
        ``Lambda_max`` of the specular-free image, in (1/3, 1]; it cancels
        in the logarithmic differentiation.
    max_sweeps
        Bound on the total number of sweeps.

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) float64 with ``0 <= diffuse <= image``.
    info : dict
        ``iterations``, ``levels``, ``remaining``, ``converged``.

    Raises
    ------
    MethodError
        Bad image or option values.
    """
    img = as_rgb_image(image, method="tan05")
    _check_options(epsilon_start, epsilon_step, chroma_threshold, noise_threshold, dark_threshold,
                   sf_max_chromaticity, max_sweeps)
    h, w, _ = img.shape
    flat = img.reshape(h * w, 3).copy()
    dark = np.all(flat < dark_threshold, axis=1)
    grid = _Grid(flat, h, w)
    sweeps = 0
    levels_run = 0
    remaining = 0
    exhausted = False
    for eps in _levels(epsilon_start, epsilon_step):
        levels_run += 1
        sweeps, remaining, exhausted = _run_level(flat, grid, eps, dark.copy(), sweeps, max_sweeps,
                                                  chroma_threshold, noise_threshold)
        if exhausted:
            break
    diffuse = finish_diffuse(flat.reshape(h, w, 3), img)
    info = {
        "iterations": sweeps,
        "levels": levels_run,
        "remaining": remaining,
        "converged": not exhausted,
    }
    return diffuse, info


def _check_options(epsilon_start: float, epsilon_step: float, chroma_threshold: float, noise_threshold: float,
                   dark_threshold: float, sf_max_chromaticity: float, max_sweeps: int) -> None:
    _check_range("epsilon_start", epsilon_start, 0.0, np.inf)
    _check_range("epsilon_step", epsilon_step, 0.0, np.inf, low_open=True)
    _check_range("chroma_threshold", chroma_threshold, 0.0, 1.0)
    _check_range("noise_threshold", noise_threshold, 0.0, 1.0)
    _check_range("dark_threshold", dark_threshold, 0.0, 1.0)
    _check_range("sf_max_chromaticity", sf_max_chromaticity, 1.0 / 3.0, 1.0, low_open=True)
    if isinstance(max_sweeps, bool) or not isinstance(max_sweeps, (int, np.integer)) or max_sweeps < 1:
        raise MethodError(f"method 'tan05': max_sweeps={max_sweeps!r}: expected a positive integer")


def _levels(epsilon_start: float, epsilon_step: float) -> list[float]:
    """Step 7's schedule: ``epsilon_start, epsilon_start - epsilon_step, ..., 0``."""
    n_levels = int(np.floor(epsilon_start / epsilon_step + _LEVEL_ROUNDING)) + 1
    levels = [max(epsilon_start - k * epsilon_step, 0.0) for k in range(n_levels)]
    if levels[-1] > 0.0:
        levels.append(0.0)
    return levels


class _Grid:
    """The image's pixels in raster order, their log ratio and step 3's flags on neighbouring pairs."""

    def __init__(self, flat: np.ndarray, h: int, w: int) -> None:
        self.n, self.w = h * w, w
        self.col = np.arange(self.n) % w
        self.row = np.arange(self.n) // w
        self.has_right = self.col < w - 1
        self.has_below = self.row < h - 1
        # log T - log T_sf up to a constant (Lambda_sf cancels; see module docstring).
        self.ld = _log_ratio(flat)

    def deltas(self, p: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Delta of the pairs (p, p + 1) and (p, p + w) (all pixels if None); NaN where no pair."""
        ld, n, w = self.ld, self.n, self.w
        if p is None:
            dx = np.full(n, np.nan)
            dy = np.full(n, np.nan)
            dx[:-1] = np.abs(ld[1:] - ld[:-1])
            dx[~self.has_right] = np.nan
            dy[: n - w] = np.abs(ld[w:] - ld[: n - w])
            return dx, dy
        dx = np.full(p.shape, np.nan)
        dy = np.full(p.shape, np.nan)
        r = self.has_right[p]
        dx[r] = np.abs(ld[p[r] + 1] - ld[p[r]])
        b = self.has_below[p]
        dy[b] = np.abs(ld[p[b] + w] - ld[p[b]])
        return dx, dy

    def flags(self, p: np.ndarray | None, eps: float, excluded: np.ndarray) -> np.ndarray:
        """0 none, 1 specular pair to the right, 2 specular pair below (right first)."""
        dx, dy = self.deltas(p)
        live = ~excluded if p is None else ~excluded[p]
        with np.errstate(invalid="ignore"):
            fx = live & (dx > eps)
            fy = live & ~fx & (dy > eps)
        return np.where(fx, 1, np.where(fy, 2, 0)).astype(np.int8)

    def update(self, flat: np.ndarray, changed: np.ndarray, flag: np.ndarray, eps: float,
               excluded: np.ndarray) -> None:
        """New log ratios of the ``changed`` pixels, and new flags of every pair they belong to."""
        self.ld[changed] = _log_ratio(flat, changed)
        # Pairs whose Delta or exclusion may have changed: (c, c+1), (c-1, c), (c, c+w), (c-w, c).
        aff = np.concatenate([changed, changed[self.col[changed] > 0] - 1, changed[self.row[changed] > 0] - self.w])
        flag[aff] = self.flags(aff, eps, excluded)


def _run_level(flat: np.ndarray, grid: _Grid, eps: float, excluded: np.ndarray, sweeps: int, max_sweeps: int,
               chroma_threshold: float, noise_threshold: float) -> tuple[int, int, bool]:
    """Sweeps at one ``epsilon`` while the number of flagged pixels decreases (``flat`` updated in place).

    Returns the total number of sweeps so far, the pixels still flagged, and whether
    ``max_sweeps`` was reached.
    """
    flag = grid.flags(None, eps, excluded)
    count = int(np.count_nonzero(flag))
    while count:
        if sweeps >= max_sweeps:
            return sweeps, count, True
        sweeps += 1
        changed = _sweep(flat, grid, flag, excluded, chroma_threshold, noise_threshold)
        if changed.size:
            grid.update(flat, changed, flag, eps, excluded)
        previous, count = count, int(np.count_nonzero(flag))
        if count >= previous:
            break
    return sweeps, count, False


def _sweep(flat: np.ndarray, grid: _Grid, flag: np.ndarray, excluded: np.ndarray, chroma_threshold: float,
           noise_threshold: float) -> np.ndarray:
    """One sweep of steps 4-6 over the flagged pairs, as a matching in four passes (module docstring).

    Returns the indices of the pixels that changed or were processed (with repeats, which are harmless).
    """
    w = grid.w
    done = np.zeros(grid.n, dtype=bool)
    touched: list[np.ndarray] = []
    for code, offset in ((1, 1), (2, w)):
        pos = np.flatnonzero(flag == code)
        parity = (pos % w if code == 1 else pos // w) % 2
        for par in (0, 1):
            p = pos[parity == par]
            q = p + offset
            free = ~done[p] & ~done[q]
            p, q = p[free], q[free]
            if p.size == 0:
                continue
            touched.append(_process_pairs(flat, p, q, excluded, done, chroma_threshold, noise_threshold))
            touched.append(p)
    return np.concatenate(touched) if touched else np.empty(0, dtype=np.int64)


def _process_pairs(
    flat: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    excluded: np.ndarray,
    done: np.ndarray,
    chroma_threshold: float,
    noise_threshold: float,
) -> np.ndarray:
    """Apply steps 4-6 to disjoint flagged pairs (p, q) in place.

    Returns the indices of the pixels whose values changed.
    """
    a = flat[p]
    b = flat[q]
    ta = a[:, 0] + a[:, 1] + a[:, 2]
    tb = b[:, 0] + b[:, 1] + b[:, 2]
    ca = np.zeros_like(a)
    cb = np.zeros_like(b)
    np.divide(a, ta[:, None], out=ca, where=ta[:, None] > 0)
    np.divide(b, tb[:, None], out=cb, where=tb[:, None] > 0)
    boundary = (np.abs(ca[:, 0] - cb[:, 0]) > chroma_threshold) & (
        np.abs(ca[:, 1] - cb[:, 1]) > chroma_threshold
    )
    ma = ca.max(axis=1)
    mb = cb.max(axis=1)
    noise = ~boundary & (np.abs(ma - mb) < noise_threshold)
    excluded[p[boundary | noise]] = True
    proc = ~boundary & ~noise
    done[p[proc]] = True
    done[q[proc]] = True
    lower_a = proc & (ma < mb)
    lower_b = proc & ~(ma < mb)
    # The target exceeds the shifted pixel's sigma_max by >= noise_threshold >= 0,
    # and a pixel's sigma_max is >= 1/3, so 3 target - 1 > 0 unless both are grey
    # and noise_threshold is 0; guard that case.
    changed = []
    for sel, src, idx, target in ((lower_a, a, p, mb), (lower_b, b, q, ma)):
        ok = sel & (3.0 * target - 1.0 > _ACHROMATIC)
        if not ok.any():
            continue
        new = shift_max_chromaticity(src[ok], target[ok])
        valid = np.all(new > 0.0, axis=1)
        if valid.any():
            rows = idx[ok][valid]
            flat[rows] = new[valid]
            changed.append(rows)
    return np.concatenate(changed) if changed else np.empty(0, dtype=np.int64)
