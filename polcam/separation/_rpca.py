"""Robust PCA by inexact ALM with wen21's polarization priors (private; :mod:`polcam.separation.wen21`).

:func:`rpca_ialm` is the general solver (bounds, a direction for the rows of
``S``, a quadratic prior); :func:`_rpca_direction_t` is its direction-constrained
case on pixel-major (k, n) matrices, iterated block by block
(:func:`_ialm_direction`), which wen21 runs per cluster.
"""

from __future__ import annotations

from concurrent.futures import Executor
from typing import Any, NamedTuple

import numba
import numpy as np

from polcam.errors import MethodError

__all__ = ["RPCAResult", "rpca_ialm"]


def _svt(x: np.ndarray, tau: float) -> np.ndarray:
    """Singular value thresholding ``U max(s - tau, 0) V^T`` of a 2-D matrix.

    Through the eigen-decomposition of the small Gram matrix: for the 3-column
    pixel matrices here that costs O(9 n) instead of a full SVD.  Fastest for
    a C-contiguous wide matrix (rows <= columns), the layout rpca_ialm uses.
    """
    wide = x.shape[0] <= x.shape[1]
    w, v = np.linalg.eigh(x @ x.T if wide else x.T @ x)
    s = np.sqrt(np.maximum(w, 0.0))
    keep = s > tau
    f = np.zeros_like(s)
    f[keep] = (s[keep] - tau) / s[keep]
    proj = (v * f) @ v.T
    return proj @ x if wide else x @ proj


class RPCAResult(NamedTuple):
    """Result of :func:`rpca_ialm`: ``m ~ low_rank + sparse``."""

    low_rank: np.ndarray
    sparse: np.ndarray
    iterations: int
    converged: bool


def rpca_ialm(m: np.ndarray, *, lam: float | None = None,
              lower: np.ndarray | None = None, upper: np.ndarray | None = None,
              direction: np.ndarray | None = None,
              prior: np.ndarray | None = None, beta: float = 0.0,
              tol: float = 1e-7, max_iter: int = 500, rho: float = 1.5) -> RPCAResult:
    """Robust PCA by the inexact augmented Lagrange multiplier method.

    Solves ::

        min_{L,S} ||L||_* + lam ||S||_1 + beta/2 ||S - prior||_F^2
        s.t. m = L + S,  lower <= S <= upper,  rows of S in {s g : s >= 0}

    (the last constraint only when ``direction`` g is given) by Lin, Chen & Ma,
    "The augmented Lagrange multiplier method for exact recovery of corrupted
    low-rank matrices" (2010), Algorithm 5: ``Y0 = m / J(m)`` with
    ``J(m) = max(||m||_2, ||m||_inf / lam)`` and ``mu0 = 1.25 / ||m||_2`` as there;
    ``mu <- min(rho mu, 1e7 mu0)`` (polcam's cap); each iteration takes the singular value
    thresholding step for ``L`` and then the closed-form proximal step for
    ``S`` (soft thresholding, or its one-dimensional version along ``g``,
    then the box, which is exact for these separable convex terms).
    Without bounds, direction and prior this is the plain RPCA of that paper.

    Parameters
    ----------
    m
        (n1, n2) float matrix.
    lam
        Weight of the l1 term; default ``1 / sqrt(max(n1, n2))`` (Candes, Li,
        Ma & Wright 2011).
    lower, upper
        (n1, n2) bounds on ``S`` (broadcastable), or None.
    direction
        (n2,) positive vector g: every row of ``S`` is ``s g`` with ``s >= 0``;
        then ``||S||_1 = s sum(g)`` and the bounds apply to ``s g``.
    prior, beta
        (n1, n2) target of the quadratic term and its weight (>= 0).
    tol
        Stop when ``||m - L - S||_F / ||m||_F < tol``.
    max_iter
        Iteration limit.
    rho
        Growth factor of the penalty ``mu`` (> 1).

    Returns
    -------
    RPCAResult
        ``low_rank`` and ``sparse`` (n1, n2) float64 (``sparse`` within the
        bounds), the iteration count and whether ``tol`` was reached.
    """
    m = np.asarray(m, dtype=np.float64)
    if m.ndim != 2:
        raise MethodError(f"rpca_ialm: matrix of shape {m.shape}: expected 2-D")
    n1, n2 = m.shape
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise MethodError(f"rpca_ialm: max_iter={max_iter!r}: expected an integer >= 1")
    if not (np.isfinite(beta) and beta >= 0 and np.isfinite(rho) and rho > 1):
        raise MethodError(f"rpca_ialm: beta={beta!r}, rho={rho!r}: expected beta >= 0 and rho > 1")
    if lam is None:
        lam = 1.0 / np.sqrt(max(n1, n2, 1))
    peak = float(np.abs(m).max()) if m.size else 0.0
    if not peak > 0:
        z = np.zeros_like(m)
        return RPCAResult(z, z.copy(), 0, True)
    # The problem is homogeneous: solve it for m / peak (beta scales by peak) so
    # that tiny (even subnormal) or large inputs cannot overflow mu or 1 / mu.
    beta = float(beta) * peak
    g = None
    if direction is not None:
        g = np.asarray(direction, dtype=np.float64).reshape(-1)
        if g.shape != (n2,) or not np.all(g > 0):
            raise MethodError(f"rpca_ialm: direction {g}: expected {n2} positive values")
    # Work on a C-contiguous wide matrix (rows <= columns): the products with
    # the small side are then fast.
    flip = n1 > n2

    def orient(a: Any) -> np.ndarray:
        b = np.broadcast_to(np.asarray(a, dtype=np.float64) / peak, (n1, n2))
        return np.ascontiguousarray(b.T if flip else b)

    x = orient(m)
    norm_f = float(np.linalg.norm(x))
    p = None if prior is None else orient(prior)
    if g is not None:
        gg = float(g @ g)
        gb = g[:, None] if flip else g[None, :]
        # bounds on the row scale s: s g >= lower, s g <= upper, s >= 0 (row by row of m:
        # the bounds need not be oriented)
        def row_scale(bound: Any, reduce: Any) -> np.ndarray:
            b = np.broadcast_to(np.asarray(bound, dtype=np.float64) / peak, (n1, n2))
            return reduce(b / g[None, :], axis=1)

        s_hi = np.full(n1, np.inf) if upper is None else row_scale(upper, np.min)
        s_hi = np.maximum(s_hi, 0.0)
        s_lo = np.zeros(n1) if lower is None else np.maximum(row_scale(lower, np.max), 0.0)
        s_lo = np.minimum(s_lo, s_hi)
        lo = hi = None
    else:
        lo = None if lower is None else orient(lower)
        hi = None if upper is None else orient(upper)
    norm2 = float(np.sqrt(max(np.linalg.eigvalsh(x @ x.T)[-1], 0.0)))
    y = x / max(norm2, float(np.abs(x).max()) / lam)
    mu = 1.25 / norm2
    mu_max = mu * 1e7
    if g is not None and flip and n2 == 3:
        low, s, it, converged = _ialm_direction(x, y, g, s_lo, s_hi, p, lam=float(lam), beta=beta,
                                                mu=mu, mu_max=mu_max, rho=float(rho), tol=float(tol),
                                                max_iter=int(max_iter), norm_f=norm_f)
        return RPCAResult(low.T * peak, s.T * peak, it, converged)
    s = np.zeros_like(x)
    converged, it = False, 0
    for it in range(1, max_iter + 1):
        inv = 1.0 / mu
        yi = inv * y
        low = x - s
        low += yi
        low = _svt(low, inv)
        d = x - low
        v = d + yi  # S minimises its terms + mu/2 |S - v|^2
        if beta > 0:  # ... + beta/2 |S - p|^2: the target becomes a weighted mean
            v *= mu / (mu + beta)
            if p is not None:
                v += (beta / (mu + beta)) * p
        t = lam / (mu + beta)
        if g is None:
            s = np.sign(v) * np.maximum(np.abs(v) - t, 0.0)
            if lo is not None or hi is not None:
                s = np.clip(s, lo, hi)
        else:
            # argmin_s lam s sum(g) + (mu + beta)/2 |s g - v|^2 = (g.v - t sum(g)) / g.g, boxed
            num = g @ v if flip else v @ g
            sc = np.clip((num - t * g.sum()) / gg, s_lo, s_hi)
            s = gb * (sc[None, :] if flip else sc[:, None])
        r = d
        r -= s  # the constraint's residual m - L - S
        y += mu * r
        mu = min(mu * rho, mu_max)
        if np.linalg.norm(r) / norm_f < tol:
            converged = True
            break
    if flip:
        low, s = low.T, s.T
    return RPCAResult(low * peak, s * peak, it, converged)


@numba.njit(cache=True, nogil=True, fastmath=False)
def _scaled_bounds(mt: np.ndarray, lower_t: np.ndarray, prior_t: np.ndarray, g: np.ndarray,
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


def _rpca_direction_t(mt: np.ndarray, lower_t: np.ndarray, prior_t: np.ndarray, g: np.ndarray, *,
                     lam: float, beta: float, tol: float, max_iter: int, rho: float = 1.5,
                     pool: Executor | None = None, parts: int = 1) -> tuple[np.ndarray, int, bool]:
    """``rpca_ialm(mt.T, lam=lam, lower=lower_t.T, upper=mt.T, direction=g, prior=prior_t.T,
    beta=beta, ...)``'s sparse part, transposed, for matrices given as C-contiguous (k, n)
    with n > k = 3: the same arithmetic without transposing copies (wen21's clusters).  ``pool``
    and ``parts``: the iterations' blocks on threads (:func:`_ialm_direction`; same result).

    Returns
    -------
    sparse_t : numpy.ndarray
        (k, n) float64.
    iterations : int
    converged : bool
    """
    k, n = mt.shape
    peak = float(np.abs(mt).max()) if mt.size else 0.0
    if not peak > 0:
        return np.zeros_like(mt), 0, True
    beta = float(beta) * peak
    x, p, s_lo, s_hi = _scaled_bounds(mt, lower_t, prior_t, np.asarray(g, dtype=np.float64), peak)
    norm_f = float(np.linalg.norm(x))
    norm2 = float(np.sqrt(max(np.linalg.eigvalsh(x @ x.T)[-1], 0.0)))
    y = x / max(norm2, float(np.abs(x).max()) / lam)
    mu = 1.25 / norm2
    _, sp, it, converged = _ialm_direction(x, y, g, s_lo, s_hi, p, lam=float(lam), beta=beta, mu=mu,
                                           mu_max=mu * 1e7, rho=float(rho), tol=float(tol),
                                           max_iter=int(max_iter), norm_f=norm_f, pool=pool, parts=parts)
    sp *= peak
    return sp, it, converged


_IALM_BLOCK = 8192  # pixels per block: a block's shares of the sums are kept apart (thread-independent)


@numba.njit(cache=True, nogil=True, fastmath=False)
def _ialm_pass(x: np.ndarray, y: np.ndarray, sc: np.ndarray, low: np.ndarray, g: np.ndarray,
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

    ``low``, ``sc`` and ``y`` are written in place (``p`` is read only when ``use_p``);
    block i's Gram matrix of ``next`` and its ``|r|^2``, summed over the columns in order,
    go to ``gram_out[i]`` and ``rr_out[i]``.
    """
    inv, c1, c2, t, mu, inv_next, gsum, gg = (coef[0], coef[1], coef[2], coef[3], coef[4],
                                              coef[5], coef[6], coef[7])
    tg = t * gsum
    g0, g1, g2 = g[0], g[1], g[2]
    p00, p01, p02 = proj[0, 0], proj[0, 1], proj[0, 2]
    p10, p11, p12 = proj[1, 0], proj[1, 1], proj[1, 2]
    p20, p21, p22 = proj[2, 0], proj[2, 1], proj[2, 2]
    for blk in range(bounds.shape[0] - 1):
        s00 = s10 = s11 = s20 = s21 = s22 = rs = 0.0
        for j in range(bounds[blk], bounds[blk + 1]):
            x0, x1, x2 = x[0, j], x[1, j], x[2, j]
            s0 = sc[j]
            yi0, yi1, yi2 = y[0, j] * inv, y[1, j] * inv, y[2, j] * inv
            a0, a1, a2 = (x0 - g0 * s0) + yi0, (x1 - g1 * s0) + yi1, (x2 - g2 * s0) + yi2
            l0 = p00 * a0 + p01 * a1 + p02 * a2
            l1 = p10 * a0 + p11 * a1 + p12 * a2
            l2 = p20 * a0 + p21 * a1 + p22 * a2
            low[0, j], low[1, j], low[2, j] = l0, l1, l2
            d0, d1, d2 = x0 - l0, x1 - l1, x2 - l2
            v0, v1, v2 = (d0 + yi0) * c1, (d1 + yi1) * c1, (d2 + yi2) * c1
            if use_p:
                v0, v1, v2 = v0 + p[0, j] * c2, v1 + p[1, j] * c2, v2 + p[2, j] * c2
            q = ((g0 * v0 + g1 * v1 + g2 * v2) - tg) / gg
            q = min(max(q, s_lo[j]), s_hi[j])  # s_lo <= s_hi
            sc[j] = q
            r0, r1, r2 = d0 - g0 * q, d1 - g1 * q, d2 - g2 * q
            y0, y1, y2 = y[0, j] + r0 * mu, y[1, j] + r1 * mu, y[2, j] + r2 * mu
            y[0, j], y[1, j], y[2, j] = y0, y1, y2
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


def _ialm_direction(x: np.ndarray, y: np.ndarray, g: np.ndarray, s_lo: np.ndarray, s_hi: np.ndarray,
                    p: np.ndarray | None, *, lam: float, beta: float, mu: float, mu_max: float,
                    rho: float, tol: float, max_iter: int, norm_f: float,
                    pool: Executor | None = None, parts: int = 1
                    ) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """The iterations of :func:`rpca_ialm` with a direction, for a wide (3, n) matrix.

    The same steps as the general loop, element by element, in one compiled pass
    over the pixels per iteration (:func:`_ialm_pass`): the Gram matrix the next
    singular value thresholding needs is accumulated in the pass that updates
    ``S`` and ``Y``, and ``S`` is kept as its row scales ``sc`` (``S = g sc``).
    ``y`` is updated in place.

    The pixels run in blocks of ``_IALM_BLOCK``; with a ``pool``, each iteration's blocks run
    as ``parts`` contiguous runs on it.  Every block's share of the Gram matrix and of the
    residual is kept and the shares are summed in block order, so the result is the same,
    bit for bit, for any ``pool`` and ``parts``.

    Returns
    -------
    low, sparse : numpy.ndarray
        (3, n) float64.
    iterations : int
    converged : bool
    """
    k, n = x.shape
    if k != 3:
        raise MethodError(f"_ialm_direction: matrix of shape {x.shape}: expected 3 rows")
    x, y, g = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, y, g))
    s_lo, s_hi = (np.ascontiguousarray(a, dtype=np.float64) for a in (s_lo, s_hi))
    use_p = beta > 0 and p is not None
    pp = np.ascontiguousarray(p, dtype=np.float64) if use_p else x
    sc, low = np.zeros(n), np.empty_like(x)
    edges = np.arange(0, n + _IALM_BLOCK, _IALM_BLOCK, dtype=np.int64)
    edges[-1] = n
    nb = len(edges) - 1
    parts = max(1, min(parts if pool is not None else 1, nb))
    cuts = [nb * i // parts for i in range(parts + 1)]
    grams, rrs = np.empty((nb, k, k)), np.empty(nb)
    # the Gram matrix of the first thresholding's argument x - S + Y / mu (S = 0)
    gram = np.zeros((k, k))
    for a, b in zip(edges[:-1], edges[1:]):
        arg = y[:, a:b] * (1.0 / mu)
        arg += x[:, a:b]
        gram += arg @ arg.T
    converged, it = False, 0
    for it in range(1, max_iter + 1):
        inv = 1.0 / mu
        w, v = np.linalg.eigh(gram)
        sv = np.sqrt(np.maximum(w, 0.0))
        keep = sv > inv
        f = np.zeros_like(sv)
        f[keep] = (sv[keep] - inv) / sv[keep]
        proj = np.ascontiguousarray((v * f) @ v.T)
        mu_next = min(mu * rho, mu_max)
        c1, c2 = (mu / (mu + beta), beta / (mu + beta)) if beta > 0 else (1.0, 0.0)
        coef = np.array([inv, c1, c2, lam / (mu + beta), mu, 1.0 / mu_next, g.sum(), g @ g])

        def run(r: int, proj: np.ndarray = proj, coef: np.ndarray = coef) -> None:
            a, b = cuts[r], cuts[r + 1]
            _ialm_pass(x, y, sc, low, g, s_lo, s_hi, pp, use_p, proj, edges[a:b + 1], coef,
                       grams[a:b], rrs[a:b])

        if parts > 1:
            assert pool is not None
            list(pool.map(run, range(parts)))
        else:
            run(0)
        gram, rr = np.zeros((k, k)), 0.0
        for i in range(nb):  # in block order, whatever ran them
            gram += grams[i]
            rr += float(rrs[i])
        mu = mu_next
        if np.sqrt(rr) / norm_f < tol:
            converged = True
            break
    return low, g[:, None] * sc[None, :], it, converged
