"""Robust PCA by inexact ALM with wen21's polarization priors (private; :mod:`polcam.separation.wen21`).

:func:`rpca_ialm` is the general solver (bounds, a direction for the rows of
``S``, a quadratic prior); :func:`rpca_direction_t` is its direction-constrained
case on pixel-major (k, n) matrices, iterated block by block
(:func:`_ialm_direction`), which wen21 runs per cluster.
"""

from __future__ import annotations

from concurrent.futures import Executor
from itertools import pairwise
from typing import Any, NamedTuple

import numpy as np

from polcam.errors import MethodError

__all__ = ["RPCAResult", "rpca_direction_t", "rpca_ialm"]


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


def rpca_direction_t(mt: np.ndarray, lower_t: np.ndarray, prior_t: np.ndarray, g: np.ndarray, *,
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
    peak = float(np.abs(mt).max()) if mt.size else 0.0
    if not peak > 0:
        return np.zeros_like(mt), 0, True
    beta = float(beta) * peak
    from polcam.separation._kernels import scaled_bounds  # numba: imported on first use

    x, p, s_lo, s_hi = scaled_bounds(mt, lower_t, prior_t, np.asarray(g, dtype=np.float64), peak)
    norm_f = float(np.linalg.norm(x))
    norm2 = float(np.sqrt(max(np.linalg.eigvalsh(x @ x.T)[-1], 0.0)))
    y = x / max(norm2, float(np.abs(x).max()) / lam)
    mu = 1.25 / norm2
    _, sp, it, converged = _ialm_direction(x, y, g, s_lo, s_hi, p, lam=float(lam), beta=beta, mu=mu,
                                           mu_max=mu * 1e7, rho=float(rho), tol=float(tol),
                                           max_iter=int(max_iter), norm_f=norm_f, pool=pool, parts=parts,
                                           want_low=False)
    sp *= peak
    return sp, it, converged


_IALM_BLOCK = 8192  # pixels per block: a block's shares of the sums are kept apart (thread-independent)


def _ialm_direction(x: np.ndarray, y: np.ndarray, g: np.ndarray, s_lo: np.ndarray, s_hi: np.ndarray,
                    p: np.ndarray | None, *, lam: float, beta: float, mu: float, mu_max: float,
                    rho: float, tol: float, max_iter: int, norm_f: float,
                    pool: Executor | None = None, parts: int = 1, want_low: bool = True
                    ) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """The iterations of :func:`rpca_ialm` with a direction, for a wide (3, n) matrix.

    The same steps as the general loop, element by element, in one compiled pass
    over the pixels per iteration (:func:`polcam.separation._kernels.ialm_pass`): the Gram matrix the next
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
        (3, n) float64 (``low`` (3, 0) unless ``want_low``).
    iterations : int
    converged : bool
    """
    k, n = x.shape
    if k != 3:
        raise MethodError(f"_ialm_direction: matrix of shape {x.shape}: expected 3 rows")
    x, y, g = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, y, g))
    s_lo, s_hi = (np.ascontiguousarray(a, dtype=np.float64) for a in (s_lo, s_hi))
    from polcam.separation._kernels import ialm_pass  # numba: imported on first use

    use_p = beta > 0 and p is not None
    pp = np.ascontiguousarray(p, dtype=np.float64) if use_p else x
    sc, low = np.zeros(n), np.empty((k, n if want_low else 0))
    edges = np.arange(0, n + _IALM_BLOCK, _IALM_BLOCK, dtype=np.int64)
    edges[-1] = n
    nb = len(edges) - 1
    parts = max(1, min(parts if pool is not None else 1, nb))
    cuts = [nb * i // parts for i in range(parts + 1)]
    grams, rrs = np.empty((nb, k, k)), np.empty(nb)
    # the Gram matrix of the first thresholding's argument x - S + Y / mu (S = 0)
    gram = np.zeros((k, k))
    for a, b in pairwise(edges):
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
            ialm_pass(x, y, sc, low, g, s_lo, s_hi, pp, use_p, proj, edges[a:b + 1], coef,
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
