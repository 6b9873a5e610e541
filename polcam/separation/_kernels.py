"""Compiled loops of wen21, its RPCA solver and polcam.separate (private; numba, imported on first use).

Each loop does the element operations of the numpy expression its docstring gives, in the
same order, so results match that expression (the sums' order is stated where it matters).
All run without the GIL and are cached on disk (the package's ``__pycache__``, else numba's
user cache).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["channel_sums", "chromaticity", "cluster_order", "finish_layers", "gather_t", "ialm_pass",
           "min_rgb", "normalised", "scaled_bounds", "scatter_clipped"]


@numba.njit(cache=True, nogil=True, fastmath=False)
def scaled_bounds(mt: np.ndarray, lower_t: np.ndarray, prior_t: np.ndarray, g: np.ndarray,
                  peak: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``x = mt / peak``, ``p = prior_t / peak`` and the row-scale bounds of (3, n) matrices.

    Per pixel j: ``s_hi = max(min_i x_ij / g_i, 0)`` (``s g <= m``, ``s >= 0``) and
    ``s_lo = min(max(max_i (lower_ij / peak) / g_i, 0), s_hi)`` (``s g >= lower``).
    """
    n = mt.shape[1]
    x, p = np.empty((3, n)), np.empty((3, n))
    s_lo, s_hi = np.empty(n), np.empty(n)
    for j in range(n):
        hi, lo = np.inf, -np.inf
        for i in range(3):
            xv = mt[i, j] / peak
            x[i, j] = xv
            p[i, j] = prior_t[i, j] / peak
            hi = min(hi, xv / g[i])
            lo = max(lo, (lower_t[i, j] / peak) / g[i])
        hi = max(hi, 0.0)
        s_hi[j] = hi
        s_lo[j] = min(max(lo, 0.0), hi)
    return x, p, s_lo, s_hi


@numba.njit(cache=True, nogil=True, fastmath={"contract"}, error_model="numpy")
def ialm_pass(x: np.ndarray, y: np.ndarray, sc: np.ndarray, low: np.ndarray, g: np.ndarray,
              s_lo: np.ndarray, s_hi: np.ndarray, p: np.ndarray, use_p: bool, proj: np.ndarray,
              bounds: np.ndarray, coef: np.ndarray, gram_out: np.ndarray,
              rr_out: np.ndarray) -> None:  # pragma: no cover - compiled
    """One IALM iteration over the pixel blocks ``bounds[i]:bounds[i + 1]`` of (3, n) matrices.

    Per pixel column j, with ``coef = (1/mu, c1, c2, t, mu, 1/mu_next, sum(g), g.g)``
    (``c1 = mu/(mu+beta)``, ``c2 = beta/(mu+beta)``, ``t = lam/(mu+beta)``)::

        a    = (x - g sc) + y / mu          L = proj a          d = x - L
        v    = (d + y / mu) c1 + p c2       sc = clip((g.v - t sum(g)) / g.g, s_lo, s_hi)
        r    = d - g sc                     y += r mu
        next = (y / mu_next + x) - g sc     (the next thresholding's argument)

    ``sc``, ``y`` and ``low`` (when it has n columns) are written in place (``p`` is read only
    when ``use_p``);
    block i's Gram matrix of ``next`` and its ``|r|^2``, summed over the columns in order,
    go to ``gram_out[i]`` and ``rr_out[i]``.

    The arithmetic is that of the expressions above up to rounding: products and sums may be
    fused (``fastmath={"contract"}``: one rounding for ``a * b + c``, where the CPU has FMA), and
    the division by ``g.g`` is a product with its reciprocal.  Sums are never reordered, so the
    result does not depend on the vector width or on how the blocks are spread over threads.
    """
    inv, c1, t, mu, inv_next, gsum, gg = coef[0], coef[1], coef[3], coef[4], coef[5], coef[6], coef[7]
    c2 = coef[2] if use_p else 0.0
    pr = p if use_p else x  # read, times 0, when there is no prior: one loop for both
    tg = t * gsum
    igg = 1.0 / gg
    keep_low = low.shape[1] == x.shape[1]
    g0, g1, g2 = g[0], g[1], g[2]
    p00, p01, p02 = proj[0, 0], proj[0, 1], proj[0, 2]
    p10, p11, p12 = proj[1, 0], proj[1, 1], proj[1, 2]
    p20, p21, p22 = proj[2, 0], proj[2, 1], proj[2, 2]
    x0r, x1r, x2r = x[0], x[1], x[2]
    y0r, y1r, y2r = y[0], y[1], y[2]
    q0r, q1r, q2r = pr[0], pr[1], pr[2]
    for blk in range(bounds.shape[0] - 1):
        s00 = s10 = s11 = s20 = s21 = s22 = rs = 0.0
        for j in range(bounds[blk], bounds[blk + 1]):
            x0, x1, x2 = x0r[j], x1r[j], x2r[j]
            s0 = sc[j]
            yi0, yi1, yi2 = y0r[j] * inv, y1r[j] * inv, y2r[j] * inv
            a0, a1, a2 = (x0 - g0 * s0) + yi0, (x1 - g1 * s0) + yi1, (x2 - g2 * s0) + yi2
            l0 = p00 * a0 + p01 * a1 + p02 * a2
            l1 = p10 * a0 + p11 * a1 + p12 * a2
            l2 = p20 * a0 + p21 * a1 + p22 * a2
            if keep_low:
                low[0, j], low[1, j], low[2, j] = l0, l1, l2
            d0, d1, d2 = x0 - l0, x1 - l1, x2 - l2
            v0 = (d0 + yi0) * c1 + q0r[j] * c2
            v1 = (d1 + yi1) * c1 + q1r[j] * c2
            v2 = (d2 + yi2) * c1 + q2r[j] * c2
            q = ((g0 * v0 + g1 * v1 + g2 * v2) - tg) * igg
            lo, hi = s_lo[j], s_hi[j]  # lo <= hi
            q = lo if q < lo else q
            q = hi if q > hi else q
            sc[j] = q
            r0, r1, r2 = d0 - g0 * q, d1 - g1 * q, d2 - g2 * q
            y0, y1, y2 = y0r[j] + r0 * mu, y1r[j] + r1 * mu, y2r[j] + r2 * mu
            y0r[j], y1r[j], y2r[j] = y0, y1, y2
            n0 = (y0 * inv_next + x0) - g0 * q
            n1 = (y1 * inv_next + x1) - g1 * q
            n2 = (y2 * inv_next + x2) - g2 * q
            s00 += n0 * n0
            s10 += n1 * n0
            s11 += n1 * n1
            s20 += n2 * n0
            s21 += n2 * n1
            s22 += n2 * n2
            rs += r0 * r0 + r1 * r1 + r2 * r2
        gram = gram_out[blk]
        gram[0, 0], gram[1, 1], gram[2, 2] = s00, s11, s22
        gram[1, 0] = gram[0, 1] = s10
        gram[2, 0] = gram[0, 2] = s20
        gram[2, 1] = gram[1, 2] = s21
        rr_out[blk] = rs


@numba.njit(cache=True, nogil=True, fastmath=False)
def channel_sums(a: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """(3,) sums over the rows of an (n, 3) array, row by row in order (as numpy's ``sum(axis=0)``)."""
    t0 = t1 = t2 = 0.0
    for i in range(a.shape[0]):
        t0 += a[i, 0]
        t1 += a[i, 1]
        t2 += a[i, 2]
    return np.array([t0, t1, t2])


@numba.njit(cache=True, nogil=True, fastmath=False)
def gather_t(ic: np.ndarray, isv: np.ndarray, order: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Pixels as columns in ``order``: ``Ic``, ``Isv`` and the raw specular ``min(2 Isv, Ic)``.

    ``ic``, ``isv``: (n, 3); returns three (3, n) arrays with column j = row ``order[j]``.
    """
    n = order.shape[0]
    ic_t, isv_t, raw_t = np.empty((3, n)), np.empty((3, n)), np.empty((3, n))
    for j in range(n):
        o = order[j]
        for c in range(3):
            a, s = ic[o, c], isv[o, c]
            ic_t[c, j] = a
            isv_t[c, j] = s
            raw_t[c, j] = min(2.0 * s, a)
    return ic_t, isv_t, raw_t


@numba.njit(cache=True, nogil=True, fastmath=False)
def scatter_clipped(diffuse_t: np.ndarray, order: np.ndarray, ic: np.ndarray, isv: np.ndarray,
                    peak: float) -> np.ndarray:  # pragma: no cover - compiled
    """(n, 3) ``peak * clip(D, 0, max(Ic - Isv, 0))`` with row ``order[j]`` from column j of D."""
    n = order.shape[0]
    out = np.empty((n, 3))
    for j in range(n):
        o = order[j]
        for c in range(3):
            top = max(ic[o, c] - isv[o, c], 0.0)
            out[o, c] = min(max(diffuse_t[c, j], 0.0), top) * peak
    return out


@numba.njit(cache=True, nogil=True)
def cluster_order(labels: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """The stable sort of ``labels`` in [0, k) by counting: ``order`` (n,) and ``bounds`` (k + 1,).

    Cluster c's pixels are ``order[bounds[c]:bounds[c + 1]]``, in increasing index.
    """
    bounds = np.zeros(k + 1, dtype=np.int64)
    for lab in labels:
        bounds[lab + 1] += 1
    for c in range(k):
        bounds[c + 1] += bounds[c]
    nxt = bounds[:-1].copy()
    order = np.empty(labels.shape[0], dtype=np.int64)
    for i in range(labels.shape[0]):
        lab = labels[i]
        order[nxt[lab]] = i
        nxt[lab] += 1
    return order, bounds


@numba.njit(cache=True, nogil=True, fastmath=False)
def min_rgb(ic: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """(n,) ``min over RGB of max(Ic, 0)`` of an (n, 3) array."""
    out = np.empty(ic.shape[0])
    for i in range(ic.shape[0]):
        out[i] = min(min(max(ic[i, 0], 0.0), max(ic[i, 1], 0.0)), max(ic[i, 2], 0.0))
    return out


@numba.njit(cache=True, nogil=True, fastmath=False)
def chromaticity(ic: np.ndarray, isv: np.ndarray, imin_bar: float) -> np.ndarray:  # pragma: no cover
    """(n, 3) ``I_rawD / (sum over RGB of I_rawD + imin_bar)``, 0 where that sum is not > 0."""
    n = ic.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        r0 = max(ic[i, 0] - isv[i, 0] * 2.0, 0.0)
        r1 = max(ic[i, 1] - isv[i, 1] * 2.0, 0.0)
        r2 = max(ic[i, 2] - isv[i, 2] * 2.0, 0.0)
        den = ((r0 + r1) + r2) + imin_bar
        if den > 0:
            out[i, 0], out[i, 1], out[i, 2] = r0 / den, r1 / den, r2 / den
        else:
            out[i, 0] = out[i, 1] = out[i, 2] = 0.0
    return out


@numba.njit(cache=True, nogil=True, fastmath=False)
def normalised(ic: np.ndarray, isv: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:  # pragma: no cover
    """``max(Ic, 0) / peak``, ``max(min(Isv, Ic), 0) / peak`` (n, 3) and ``peak = max(max(Ic, 0))``.

    Undivided when ``peak`` is not > 0 (NaN propagates to ``peak``, as numpy's max does).
    """
    n = ic.shape[0]
    a, s = np.empty((n, 3)), np.empty((n, 3))
    peak = 0.0
    for i in range(n):
        for c in range(3):
            v = np.maximum(ic[i, c], 0.0)
            a[i, c] = v
            s[i, c] = np.maximum(np.minimum(isv[i, c], ic[i, c]), 0.0)
            peak = np.maximum(peak, v)
    if peak > 0:
        for i in range(n):
            for c in range(3):
                a[i, c] /= peak
                s[i, c] /= peak
    return a, s, peak


@numba.njit(cache=True, nogil=True, fastmath=False)
def finish_layers(diffuse: np.ndarray, reference: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """float32 ``D = clip(nan_to_num(diffuse, nan=0, posinf=0, neginf=0), 0, reference)`` and
    ``reference - D`` (the difference taken in float64) of flat float64 arrays."""
    n = diffuse.shape[0]
    d32, s32 = np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)
    for i in range(n):
        v = diffuse[i]
        if not np.isfinite(v):
            v = 0.0
        r = reference[i]
        v = min(max(v, 0.0), r)
        d32[i] = np.float32(v)
        s32[i] = np.float32(r - v)
    return d32, s32
