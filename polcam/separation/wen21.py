"""``wen21``: polarization chromaticity clustering + low-rank/sparse decomposition.

After S. Wen, Y. Zheng and F. Lu, "Polarization guided specular reflection
separation", IEEE Transactions on Image Processing 30, 2021 (:data:`REFERENCE`).
docs/methods/wen21.md gives the equations, every choice the paper leaves
open, and the measurements behind the defaults.

Outline (stack ``I`` of shape (4, H, W, 3), angles 0, 45, 90, 135 degrees):

1. Fit ``I(t) = Ic + Isv cos(2t - 2 phi)`` per pixel and channel
   (:func:`polcam.polarimetry.fit_sinusoid`).
2. Polarization chromaticity (Wen'21, restated as eq. 3 of Shakeri & Zhang):
   ``I_rawS = 2 Isv``, ``I_rawD = max(Ic - I_rawS, 0)``,
   ``I_chro = I_rawD / (sum_RGB I_rawD + mean_p min_RGB Ic)``
   (:func:`polarization_chromaticity`).
3. Cluster the pixels by ``I_chro`` with seeded k-means (k-means++ start).
4. In every cluster, split the (n, 3) matrix ``M`` of the pixels' ``Ic`` into a
   low-rank diffuse part ``L`` and a sparse specular part ``S`` by robust PCA,
   solved with the inexact augmented Lagrange multiplier method of Lin, Chen &
   Ma (2010) (:func:`rpca_ialm`), with three polarization priors:

   * the specular reflection carries all the polarized light and diffuse
     reflection none, so per channel ``Isv <= S <= Ic`` (hence
     ``0 <= diffuse <= Ic - Isv``, the polarization minimum);
   * every specular row is a non-negative multiple of the illuminant colour
     (dichromatic model), and that colour is read off the polarized light:
     ``Gamma ~ sum over pixels of Isv`` (diffuse light is unpolarized);
   * a weak quadratic pull of ``S`` towards Wen's raw specular estimate
     ``I_rawS = 2 Isv``.

5. The diffuse layer is ``M - S`` of every cluster, on the scale of one
   polarization image (``Ic`` is the mean over the four angles).

The diffuse layer is never above :func:`polcam.polarimetry.imin`; the low-rank term
removes the unpolarized share of the specular light that ``imin`` leaves in.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from polcam.errors import MethodError
from polcam.parallel import blas_limit, default_workers
from polcam.polarimetry import Sinusoid, maps
from polcam.separation._registry import register
from polcam.separation._rpca import RPCAResult, rpca_direction_t, rpca_ialm

__all__ = [
    "REFERENCE",
    "RPCAResult",
    "polarization_chromaticity",
    "polarization_illuminant",
    "kmeans",
    "rpca_ialm",
    "separate_wen21",
]

REFERENCE = (
    "S. Wen, Y. Zheng and F. Lu, Polarization guided specular reflection separation, "
    "IEEE Transactions on Image Processing 30, 7280-7291, 2021"
)

# k-means is fitted on at most this many pixels (drawn with the seeded generator),
# then every pixel goes to its nearest centre.
_KMEANS_FIT_MAX = 20000
_KMEANS_MAX_ITER = 100
_KMEANS_BLOCK = 1 << 15  # points scored at once
_THREADED_MIN = 1 << 16  # pixels from which the clusters are solved on threads


def polarization_chromaticity(ic: np.ndarray, isv: np.ndarray) -> np.ndarray:
    """Wen'21's polarization chromaticity image.

    ``I_rawD = max(Ic - 2 Isv, 0)`` and
    ``I_chro = I_rawD / (sum over RGB of I_rawD + mean over pixels of min_RGB Ic)``.

    Parameters
    ----------
    ic, isv
        (..., 3) float: the unpolarized mean ``Ic >= 0`` and the amplitude
        ``Isv >= 0`` of the polarization sinusoid, per channel.

    Returns
    -------
    numpy.ndarray
        (..., 3) float64 in [0, 1]; the channels of a pixel sum to less than 1.
        Zero where the denominator is zero (an all-black image).
    """
    ic = np.asarray(ic, dtype=np.float64)
    isv = np.asarray(isv, dtype=np.float64)
    if ic.shape != isv.shape or ic.ndim < 1 or ic.shape[-1] != 3:
        raise MethodError(
            f"Ic of shape {ic.shape} and Isv of shape {isv.shape}: "
            "expected two equal (..., 3) arrays"
        )
    if not ic.size:
        return np.maximum(ic - 2.0 * isv, 0.0)
    ic2, isv2 = (np.ascontiguousarray(a.reshape(-1, 3)) for a in (ic, isv))
    from polcam.separation import _kernels  # numba: imported on first use

    imin_bar = float(_kernels.min_rgb(ic2).mean())
    return _kernels.chromaticity(ic2, isv2, imin_bar).reshape(ic.shape)


def polarization_illuminant(isv: np.ndarray, *, floor: float = 0.05) -> np.ndarray:
    """Illuminant colour estimated from the polarized light.

    Diffuse reflection is unpolarized, so the polarized amplitude ``Isv`` of
    every pixel has the colour of the specular reflection, which is the
    illuminant colour (neutral interface reflection).  The estimate is the sum
    of ``Isv`` over all pixels, scaled to a mean of 1.

    Parameters
    ----------
    isv
        (..., 3) float >= 0.
    floor
        Each channel is kept at least ``floor`` (relative to the mean) so
        that bounds divided by it stay finite.

    Returns
    -------
    numpy.ndarray
        (3,) float64 with mean 1; white ``(1, 1, 1)`` when there is no
        polarized light at all.
    """
    from polcam.separation import _kernels  # numba: imported on first use

    total = _kernels.channel_sums(np.ascontiguousarray(np.reshape(isv, (-1, 3)), dtype=np.float64))
    if not total.sum() > 0:
        return np.ones(3)
    g = np.maximum(total / total.mean(), floor)
    return g / g.mean()


def kmeans(x: np.ndarray, k: int, *, rng: np.random.Generator,
           max_iter: int = _KMEANS_MAX_ITER,
           fit_max: int = _KMEANS_FIT_MAX) -> tuple[np.ndarray, np.ndarray]:
    """Seeded k-means (k-means++ start, Lloyd iterations).

    Parameters
    ----------
    x
        (n, d) float features.
    k
        Number of clusters requested (>= 1).  Fewer come back when ``x`` has
        fewer than ``k`` distinct points.
    rng
        Generator for the k-means++ draws and the fitting subsample.
    max_iter
        Lloyd iterations at most.
    fit_max
        Centres are fitted on at most this many points drawn from ``x``.

    Returns
    -------
    labels : numpy.ndarray
        (n,) int64 in [0, number of centres): the nearest centre of every point.
    centers : numpy.ndarray
        (number of centres, d) float64; every centre has points.
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, x.shape[1]))
    fit = x if n <= fit_max else x[np.sort(rng.choice(n, fit_max, replace=False))]
    m = fit.shape[0]
    chosen = [int(rng.integers(m))]
    d2 = ((fit - fit[chosen[0]]) ** 2).sum(axis=1)
    while len(chosen) < k:
        total = d2.sum()
        if not total > 0:  # fewer distinct points than k
            break
        j = int(rng.choice(m, p=d2 / total))
        chosen.append(j)
        d2 = np.minimum(d2, ((fit - fit[j]) ** 2).sum(axis=1))
    centers = fit[chosen].copy()

    def nearest(pts: np.ndarray, c: np.ndarray) -> np.ndarray:
        # |p - c|^2 = |p|^2 - 2 p.c + |c|^2; |p|^2 does not change the argmin.
        # (k, n) scores from the transposed, contiguous points: the fast layout;
        # in blocks of points, so the scores stay in cache.
        cc = (c * c).sum(axis=1)[:, None]
        out = np.empty(pts.shape[0], dtype=np.int64)
        for a in range(0, pts.shape[0], _KMEANS_BLOCK):
            pts_t = np.ascontiguousarray(pts[a:a + _KMEANS_BLOCK].T)
            scores = c @ pts_t
            scores *= -2.0
            scores += cc
            out[a:a + _KMEANS_BLOCK] = np.argmin(scores, axis=0)
        return out

    for _ in range(max_iter):
        labels = nearest(fit, centers)
        counts = np.bincount(labels, minlength=len(centers))
        sums = np.stack([np.bincount(labels, weights=fit[:, j], minlength=len(centers))
                         for j in range(fit.shape[1])], axis=1)
        new = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], centers)
        moved = np.abs(new - centers).max()
        centers = new
        if moved <= 1e-12:
            break
    labels = nearest(x, centers)
    used = np.unique(labels)  # drop centres no point is nearest to, relabel 0..
    remap = np.zeros(len(centers), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return remap[labels], centers[used]


def _check_options(clusters: Any, seed: Any, lam_scale: Any, beta: Any, illuminant: Any,
                   tol: Any, max_iter: Any) -> None:
    if isinstance(clusters, bool) or not isinstance(clusters, (int, np.integer)) or clusters < 1:
        raise MethodError(f"wen21: clusters={clusters!r}: expected an integer >= 1")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise MethodError(f"wen21: seed={seed!r}: expected an integer >= 0")
    for name, val in (("lam_scale", lam_scale), ("tol", tol)):
        if not (isinstance(val, (int, float, np.number)) and np.isfinite(val) and val > 0):
            raise MethodError(f"wen21: {name}={val!r}: expected a positive number")
    if not (isinstance(beta, (int, float, np.number)) and np.isfinite(beta) and beta >= 0):
        raise MethodError(f"wen21: beta={beta!r}: expected a number >= 0")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise MethodError(f"wen21: max_iter={max_iter!r}: expected an integer >= 1")
    if isinstance(illuminant, str):
        if illuminant not in ("polarization", "white"):
            raise MethodError(
                f"wen21: illuminant={illuminant!r}: expected 'polarization', 'white' "
                "or three positive numbers (R, G, B)"
            )
    else:
        arr = np.asarray(illuminant, dtype=object)
        ok = arr.shape == (3,) and all(
            isinstance(v, (int, float, np.number)) and not isinstance(v, bool)
            and np.isfinite(v) and v > 0 for v in arr)
        if not ok:
            raise MethodError(
                f"wen21: illuminant={illuminant!r}: expected 'polarization', 'white' "
                "or three positive numbers (R, G, B)"
            )


def _fit(arr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float64 ``Ic`` and ``Isv`` of the stack's sinusoid fit, with NaN as 0, +inf as 1 and negatives as 0.

    The two maps of :func:`polcam.polarimetry.fit_sinusoid` (the phase is not needed).
    """
    if arr.dtype in (np.float32, np.float64):
        lo, hi = (float(arr.min()), float(arr.max())) if arr.size else (0.0, 0.0)
        if lo >= 0.0 and np.isfinite(hi):  # clean (what separate passes): no copy of the stack
            m = maps(arr, ("ic", "isv"), dtype=np.float64)
            return m["ic"], m["isv"]
    arr = np.clip(np.nan_to_num(arr.astype(np.float64), nan=0.0, posinf=1.0, neginf=0.0), 0.0, None)
    m = maps(arr, ("ic", "isv"))
    return m["ic"], m["isv"]


@register("wen21", kind="stack", reference=REFERENCE)
def separate_wen21(stack: np.ndarray, *, clusters: int = 8, seed: int = 0,
                   lam_scale: float = 1.0, beta: float = 1.0,
                   illuminant: str | tuple[float, float, float] = "polarization",
                   tol: float = 1e-6, max_iter: int = 500,
                   fit: Sinusoid | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer by polarization-chromaticity clustering and constrained RPCA.

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1]: angles 0, 45, 90, 135 degrees, RGB, linear.
    clusters
        Number of k-means clusters of the polarization chromaticity (fewer when
        the image has fewer distinct chromaticities).
    seed
        Seed of the k-means draws; equal seeds give identical results.
    lam_scale
        The l1 weight of a cluster of n pixels is ``lam_scale / sqrt(n)``.
    beta
        Weight of the pull towards Wen's raw specular ``2 Isv``: the term is
        ``beta * lam / (2 mean(Ic)) * ||S - min(2 Isv, Ic)||^2`` (invariant to
        image size and exposure); 0 turns it off.
    illuminant
        Colour of the specular reflection: ``"polarization"`` (estimated from
        the polarized light, :func:`polarization_illuminant`), ``"white"``, or
        an (R, G, B) triple of positive numbers.
    tol, max_iter
        Stopping rule of each cluster's RPCA (relative residual, iterations).
    fit
        The sinusoid fit of ``stack`` when the caller has it (``ic`` and ``isv``
        (H, W, 3), float64 for identical results:
        ``polcam.polarimetry.fit_sinusoid(stack, dtype=numpy.float64)``; the
        pipeline computes it in the pass that makes a frame's maps); None fits
        it here.

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) float64 with ``0 <= diffuse <= Ic - Isv`` (so within
        ``[0, mean over angles]``).
    info : dict
        ``iterations`` (the most any cluster took), ``converged`` (every
        cluster met ``tol``), ``clusters`` (how many were used) and
        ``illuminant`` (the colour used, mean 1).

    Raises
    ------
    MethodError
        A stack that is not (4, H, W, 3), or a bad option.
    """
    arr = np.asarray(stack)
    if arr.ndim != 4 or arr.shape[0] != 4 or arr.shape[-1] != 3:
        raise MethodError(
            f"wen21: stack of shape {arr.shape}: expected a (4, H, W, 3) colour polarization "
            "stack (angles 0, 45, 90, 135 degrees)"
        )
    _check_options(clusters, seed, lam_scale, beta, illuminant, tol, max_iter)
    # BLAS on one thread: its calls here are small (k-means scores, 3 x 3 Gram matrices), and
    # OpenBLAS' idle threads spin on the cores the cluster threads need (2 cores: 0.75 CPU-s
    # against 1.2 with BLAS threads; docs/benchmarks.md)
    with blas_limit(1):
        return _separate(arr, clusters, seed, lam_scale, beta, illuminant, tol, max_iter, fit)


def _separate(arr: np.ndarray, clusters: int, seed: int, lam_scale: float, beta: float,
              illuminant: str | tuple[float, float, float], tol: float, max_iter: int,
              fit: Sinusoid | None) -> tuple[np.ndarray, dict[str, Any]]:
    """:func:`separate_wen21` on a checked stack with checked options."""
    _, h, w, _ = arr.shape
    if fit is None:
        ic0, isv0 = _fit(arr)
    elif not (np.shape(fit.ic) == np.shape(fit.isv) == (h, w, 3)):
        raise MethodError(f"wen21: fit of shapes {np.shape(fit.ic)}, {np.shape(fit.isv)}: expected "
                          f"Ic and Isv of the stack's ({h}, {w}, 3)")
    else:
        ic0, isv0 = fit.ic, fit.isv
    # Ic >= 0, 0 <= Isv <= Ic; the method is invariant to exposure: work on [0, 1]
    from polcam.separation import _kernels  # numba: imported on first use

    ic, isv, peak = _kernels.normalised(np.asarray(ic0, dtype=np.float64).reshape(-1, 3),
                                        np.asarray(isv0, dtype=np.float64).reshape(-1, 3))
    if not peak > 0:  # all black: no light, no specular
        info0 = {"iterations": 0, "converged": True, "clusters": 0, "illuminant": [1.0, 1.0, 1.0]}
        return np.zeros((h, w, 3)), info0

    if isinstance(illuminant, str):
        gamma = polarization_illuminant(isv) if illuminant == "polarization" else np.ones(3)
    else:
        gamma = np.asarray(illuminant, dtype=np.float64)
        gamma = gamma / gamma.mean()

    chro = polarization_chromaticity(ic, isv)
    labels, _ = kmeans(chro, int(clusters), rng=np.random.default_rng(int(seed)))
    scale = float(ic.mean())
    iterations = 0
    converged = True
    order, bounds = _kernels.cluster_order(labels, int(labels.max()) + 1 if labels.size else 0)

    # pixels as columns, sorted by cluster: each cluster's matrices are contiguous column
    # ranges, gathered once for all
    ic_t, isv_t, raw_t = _kernels.gather_t(ic, isv, order)
    diffuse_t = np.empty_like(ic_t)

    def cluster(k: int, pool: ThreadPoolExecutor | None = None, parts: int = 1) -> tuple[int, bool]:
        a, b = int(bounds[k]), int(bounds[k + 1])
        if b == a:
            return 0, True
        lam = float(lam_scale) / np.sqrt(max(b - a, 3))
        w = float(beta) * lam / scale
        if b - a > 3:  # a wide matrix: the transposed fast path of rpca_ialm
            m = ic_t[:, a:b]
            sp, its, conv = rpca_direction_t(m, isv_t[:, a:b], raw_t[:, a:b], gamma,
                                              lam=lam, beta=w, tol=float(tol), max_iter=int(max_iter),
                                              pool=pool, parts=parts)
            np.subtract(m, sp, out=diffuse_t[:, a:b])
            return its, conv
        m = ic_t[:, a:b].T
        res = rpca_ialm(m, lam=lam, lower=isv_t[:, a:b].T, upper=m, direction=gamma,
                        prior=raw_t[:, a:b].T, beta=w, tol=float(tol), max_iter=int(max_iter))
        diffuse_t[:, a:b] = (m - res.sparse).T
        return res.iterations, res.converged

    # clusters are independent (numpy releases the GIL): a large one at a time with its pixel
    # blocks shared by the threads, then the small ones side by side, one per thread
    ks = sorted(range(len(bounds) - 1), key=lambda k: bounds[k] - bounds[k + 1])
    threads = default_workers(4) if ic.shape[0] >= _THREADED_MIN else 1
    if threads > 1:
        large = [k for k in ks if bounds[k + 1] - bounds[k] >= _THREADED_MIN]
        with ThreadPoolExecutor(max_workers=threads) as pool:
            results = [cluster(k, pool, threads) for k in large]
            results += pool.map(cluster, ks[len(large):])
    else:
        results = [cluster(k) for k in ks]
    for its, conv in results:
        iterations = max(iterations, its)
        converged = converged and conv
    diffuse = _kernels.scatter_clipped(diffuse_t, order, ic, isv, peak)
    info = {
        "iterations": iterations,
        "converged": converged,
        "clusters": int(labels.max() + 1) if labels.size else 0,
        "illuminant": [float(v) for v in gamma],
    }
    return diffuse.reshape(h, w, 3), info
