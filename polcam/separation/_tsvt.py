"""Tensor singular value thresholding (t-SVT) and the tensor nuclear norm.

For a real tensor ``X`` of shape (n1, n2, n3) the t-product framework (Kilmer &
Martin 2011; Lu et al., "Tensor robust principal component analysis with a new
tensor nuclear norm", IEEE TPAMI 42(4), 2020) works in the Fourier domain along
the third mode: ``Xf = fft(X, axis=2)``, whose frontal slices ``Xf[:, :, i]``
are the diagonal blocks of the block-diagonalised block-circulant matrix
``bcirc(X)``.

Tensor nuclear norm, *with* the 1/n3 factor (Lu et al. 2020, Def. 3.3)::

    ||X||_* = (1 / n3) * sum_i ||Xf[:, :, i]||_*  =  ||bcirc(X)||_* / n3

With that normalisation the proximal operator of ``t * ||.||_*`` is the t-SVT
that shrinks the singular values of every Fourier slice by the same ``t``
(Lu et al. 2020, Thm. 4.2)::

    tsvt(Y, t) = ifft( U_i  max(S_i - t, 0)  V_i^H  for every slice i )

For real input only ``n3 // 2 + 1`` slices are independent (slice ``n3 - i`` is
the complex conjugate of slice ``i``), so the transform is ``rfft`` and only
those slices are decomposed.

Solvers
-------
``"exact"``
    A full SVD of every slice (LAPACK gesdd through numpy), in the input's
    precision; the reference the fast solver is checked against.
``"fast"``
    The same operator computed from the Gram matrix ``G = A^H A`` of each slice
    ``A`` (on its smaller side) and only the eigenpairs of ``G`` above ``t^2``:
    ``SVT(A) = (A V_r) diag(1 - t / s_r) V_r^H`` with ``s_r^2`` the kept
    eigenvalues.  When the rank expected above the threshold is small, the
    eigenpairs come from a Rayleigh-Ritz step on a subspace of ``G``
    (randomized subspace iteration, Halko, Martinsson & Tropp, SIAM Review
    53(2), 2011, Alg. 4.4, warm-started with the previous call's subspace); the
    subspace grows until it holds ``oversample`` more directions than the kept
    rank.  Otherwise ``G`` is formed (herk for complex slices) and decomposed
    whole (LAPACK syevd; heevd, or heevr from size 512).  The slices
    of the 0th and (for even n3) the n3/2-th frequency are real, so their
    arithmetic is real.  :class:`FastTSVT` keeps the per-slice state (subspace,
    predicted rank) between calls, as the IALM iterations need; :func:`tsvt`
    with ``solver="fast"`` starts from no state.

    Accuracy: the Gram matrix squares the singular values, so those below
    ``sqrt(eps) * s_max`` of a slice (``eps`` of the working precision:
    about 3e-4 in float32, 1e-8 in float64) are resolved only to that level;
    their contribution to the result is bounded by it.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.linalg as sla

from polcam.separation import _lapack

__all__ = [
    "tsvt",
    "tensor_nuclear_norm",
    "SOLVERS",
    "packed_dft",
    "randomized_svd",
    "SliceSVT",
    "FastTSVT",
]

#: t-SVT solvers available.
SOLVERS: tuple[str, ...] = ("exact", "fast")


def _slice_svt(a: np.ndarray, t: float) -> tuple[np.ndarray, int]:
    """SVT of one (complex) matrix: U max(S - t, 0) V^H and the kept rank."""
    u, s, vh = np.linalg.svd(a, full_matrices=False)
    s = s - t
    r = int(np.count_nonzero(s > 0))
    if r == 0:
        return np.zeros_like(a), 0
    return (u[:, :r] * s[:r]) @ vh[:r], r


def tsvt(y: np.ndarray, t: float, *, solver: str = "exact",
         dtype: type | None = None) -> tuple[np.ndarray, list[int]]:
    """Proximal operator of ``t * ||.||_*`` (tensor nuclear norm with 1/n3).

    Parameters
    ----------
    y
        Real tensor (n1, n2, n3).
    t
        Threshold >= 0.
    solver
        ``"exact"``: full SVD of each of the n3 // 2 + 1 Fourier slices;
        ``"fast"``: :class:`FastTSVT` started from no state (see the module
        docstring).
    dtype
        Working precision of the fast solver (default float32); the exact
        solver works in the input's precision.

    Returns
    -------
    x : numpy.ndarray
        Real tensor (n1, n2, n3), the minimiser of
        ``t ||X||_* + 1/2 ||X - Y||_F^2``.
    ranks : list of int
        Rank kept in each Fourier slice (0 .. n3 // 2).
    """
    if solver not in SOLVERS:
        raise ValueError(f"t-SVT solver {solver!r}: expected one of {', '.join(SOLVERS)}")
    if y.ndim != 3:
        raise ValueError(f"t-SVT of an array of shape {y.shape}: expected a 3-way tensor")
    n3 = y.shape[2]
    if solver == "fast":
        op = FastTSVT(n3, dtype=dtype or np.float32)
        x, ranks = op(np.moveaxis(y, 2, 0), t)
        return np.ascontiguousarray(np.moveaxis(x, 0, 2)).astype(y.dtype, copy=False), ranks
    yf = np.fft.rfft(y, axis=2)
    xf = np.empty_like(yf)
    ranks = []
    for i in range(yf.shape[2]):
        xf[:, :, i], r = _slice_svt(yf[:, :, i], t)
        ranks.append(r)
    return np.fft.irfft(xf, n=n3, axis=2).astype(y.dtype, copy=False), ranks


def tensor_nuclear_norm(x: np.ndarray) -> float:
    """``(1 / n3) sum_i ||fft(x)[:, :, i]||_*`` over all n3 slices."""
    n3 = x.shape[2]
    xf = np.fft.fft(x, axis=2)
    return float(sum(np.linalg.svd(xf[:, :, i], compute_uv=False).sum() for i in range(n3)) / n3)


# ---------------------------------------------------------------------------
# the real ("packed") DFT along the third mode
# ---------------------------------------------------------------------------

def packed_dft(n3: int) -> tuple[np.ndarray, np.ndarray, list[tuple[int, ...]]]:
    """Real matrices of the DFT along the third mode, packed like FFTPACK's real transform.

    ``Z = F @ X`` (X: n3 rows, one per frontal slice) holds the independent part
    of ``rfft(X, axis=0)`` in n3 real rows: ``Re F_0``, then ``Re F_j, Im F_j``
    for ``j = 1 .. (n3 - 1) // 2``, then ``Re F_{n3/2}`` for even n3 (the
    imaginary parts of F_0 and F_{n3/2} are zero for real input).
    ``X = Finv @ Z``.  Applied as a matrix product over the flattened slices, the
    transform is a single pass over the tensor, in real arithmetic.

    Returns
    -------
    F, Finv : numpy.ndarray
        (n3, n3) float64.
    slices : list of tuple
        For each frequency 0 .. n3 // 2, the rows of Z holding it: ``(row,)`` for
        a real frequency, ``(re_row, im_row)`` for a complex one.
    """
    r = np.arange(n3)
    rows = [np.ones(n3)]
    slices: list[tuple[int, ...]] = [(0,)]
    for j in range(1, (n3 - 1) // 2 + 1):
        ang = 2 * np.pi * j * r / n3
        rows += [np.cos(ang), -np.sin(ang)]        # rfft convention: exp(-2 pi i j r / n3)
        slices.append((len(rows) - 2, len(rows) - 1))
    if n3 % 2 == 0 and n3 > 1:
        rows.append(np.cos(np.pi * r))
        slices.append((len(rows) - 1,))
    f = np.array(rows)
    return f, np.linalg.inv(f), slices


# ---------------------------------------------------------------------------
# eigenpairs of a Gram matrix: whole, or on a randomized subspace
# ---------------------------------------------------------------------------

def _gram(b: np.ndarray) -> tuple[np.ndarray, bool]:
    """``B^H B`` and whether it is conjugated, for :func:`_eigh` (upper triangle read).

    Complex: BLAS herk on ``B^T`` (its Fortran view) gives ``conj(B^H B)`` in its
    upper triangle at half the cost of a full product (19 against 35 ms at
    1024 x 768 in complex64 here); the eigenvectors of the conjugate are the
    conjugates.  Real: the plain product.
    """
    if np.iscomplexobj(b):
        herk = sla.blas.get_blas_funcs("herk", (b,))
        return herk(1.0, b.T, trans=0), True
    return b.T @ b, False


def _gershgorin(g: np.ndarray, *, upper: bool) -> float:
    """Gershgorin bound on the largest eigenvalue of a Hermitian matrix: the largest absolute row sum.

    ``upper``: only the upper triangle of ``g`` holds the matrix (:func:`_gram`'s herk).
    """
    a = np.abs(g)
    if upper:
        a = np.triu(a)
        return float((a.sum(axis=1) + a.sum(axis=0) - np.diagonal(a)).max())
    return float(a.sum(axis=1).max())


def _eigh(g: np.ndarray, lower: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Eigenpairs of a Hermitian matrix, ascending (``g`` is overwritten).

    LAPACK syevd (real) and heevd (complex, divide and conquer), except heevr
    (MRRR) for complex matrices of size 512 and more, where it took 140-174 ms
    against heevd's 236-250 ms at size 768 on the development machine (OpenBLAS
    0.3.31, one thread; at 96 heevd is faster); asking heevr for only the
    eigenvalues above the threshold was slower still when most of them pass it.
    All run through :mod:`polcam.separation._lapack`, which releases the GIL
    (``scipy.linalg.eigh`` is the fallback).
    """
    # through scipy's Cython LAPACK pointers, without the GIL, so the Fourier slices of one
    # tile really are decomposed in parallel threads (scipy's wrappers hold the GIL: two
    # 768 x 768 complex problems took 362 ms in two threads, 190 ms like this)
    big_complex = np.iscomplexobj(g) and g.shape[0] >= 512
    got = _lapack.eigh(g, upper=not lower, driver="evr" if big_complex else "evd")
    if got is not None:
        return got
    if big_complex:
        return sla.eigh(g, lower=lower, driver="evr", check_finite=False, overwrite_a=True)
    return sla.eigh(g, lower=lower, driver="evd", check_finite=False, overwrite_a=True)


def _orth(z: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the columns of z (Householder QR)."""
    return np.linalg.qr(z)[0]


def _random(rng: np.random.Generator, shape: tuple[int, int], dtype: np.dtype) -> np.ndarray:
    real = np.finfo(dtype).dtype
    out = rng.standard_normal(shape, dtype=real if real in (np.float32, np.float64) else np.float64)
    if np.issubdtype(dtype, np.complexfloating):
        out = out + 1j * rng.standard_normal(shape, dtype=out.dtype)
    return out.astype(dtype, copy=False)


def _ritz(b: np.ndarray, q: int, *, basis: np.ndarray | None, power_iter: int,
          rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rayleigh-Ritz pairs of ``G = B^H B`` on a q-dimensional randomized subspace.

    The subspace is the span of ``G^(1 + power_iter) Omega`` (re-orthonormalised
    after every product; G is applied as ``B^H (B z)``, never formed), Omega
    being the columns of ``basis`` (a warm start) completed with Gaussian
    columns.

    Returns
    -------
    lam : numpy.ndarray
        (q,) Ritz values, ascending (squared singular values of B).
    v : numpy.ndarray
        (n, q) Ritz vectors (right singular vectors of B).
    bv : numpy.ndarray
        (k, q) ``B v``.
    """
    n = b.shape[1]
    used = 0 if basis is None else min(basis.shape[1], q)
    z = _random(rng, (n, q), b.dtype)
    if used:
        z[:, :used] = basis[:, :used]
    bh = b.conj().T
    for _ in range(power_iter + 1):
        z = _orth(bh @ (b @ z))
    y = b @ z
    c = y.conj().T @ y
    c = 0.5 * (c + c.conj().T)
    lam, w = _eigh(c)
    return lam, z @ w, y @ w


def randomized_svd(a: np.ndarray, rank: int, *, oversample: int = 8, power_iter: int = 2,
                   basis: np.ndarray | None = None, seed: int | np.random.Generator = 0
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leading singular triplets of a matrix by randomized subspace iteration.

    The right singular subspace is found as a Rayleigh-Ritz subspace of
    ``G = A^H A`` (the computation :class:`SliceSVT` uses): Halko, Martinsson &
    Tropp (2011), Alg. 4.4 with ``rank + oversample`` columns.

    Parameters
    ----------
    a
        (k, m) real or complex matrix.
    rank
        Number of triplets wanted, 1 .. min(k, m).
    oversample, power_iter
        Extra columns of the test matrix, and products with G after the first.
    basis
        (m, p) columns to start the subspace with (a warm start), or None.
    seed
        Seed or generator of the Gaussian test matrix.

    Returns
    -------
    u : numpy.ndarray
        (k, rank) orthonormal columns.
    s : numpy.ndarray
        (rank,) singular values, descending.
    vh : numpy.ndarray
        (rank, m) orthonormal rows.
    """
    k, m = a.shape
    if not 1 <= rank <= min(k, m):
        raise ValueError(f"rank {rank} of a {k} x {m} matrix: expected 1 .. {min(k, m)}")
    rng = np.random.default_rng(seed)
    q = min(m, rank + oversample)
    lam, v, av = _ritz(a, q, basis=basis, power_iter=power_iter, rng=rng)
    lam, v, av = lam[::-1][:rank], v[:, ::-1][:, :rank], av[:, ::-1][:, :rank]
    s = np.sqrt(np.maximum(lam, 0.0))
    u = np.zeros_like(av)
    np.divide(av, s, out=u, where=s > 0)
    return u, s, v.conj().T


# ---------------------------------------------------------------------------
# the fast SVT of one matrix, with state between calls
# ---------------------------------------------------------------------------

class SliceSVT:
    """Adaptive-rank singular value thresholding of one matrix, warm-started between calls.

    Each call computes ``U max(S - t, 0) V^H`` of a (k, m) matrix ``A`` from the
    eigenpairs above ``t^2`` of its Gram matrix ``G`` on the smaller side (size n).
    When the predicted rank ``q`` is below ``full_fraction * n`` they are Ritz
    pairs of a randomized subspace of dimension q seeded with the previous
    call's kept vectors (:func:`_ritz`, cost about ``2 (2 + power_iter) k n q``);
    if more than ``q - oversample`` Ritz values pass the threshold the subspace
    is judged too small and grown (by half, plus ``oversample``).  Otherwise G is
    formed and decomposed.  The next call predicts ``growth * rank + oversample``.

    Parameters
    ----------
    full_fraction
        Decompose G whole when the subspace would exceed this share of its size.
    oversample
        Subspace directions beyond the kept rank (also the first guess).
    growth
        Predicted rank growth between calls (IALM's kept ranks grow as mu does).
    power_iter
        Products with G after the first (subspace iteration).
    seed
        Seed of the Gaussian test vectors (results repeat).
    """

    def __init__(self, *, full_fraction: float = 0.5, oversample: int = 8, growth: float = 1.25,
                 power_iter: int = 1, seed: int | tuple[int, ...] = 0) -> None:
        self.full_fraction = float(full_fraction)
        self.oversample = int(oversample)
        self.growth = float(growth)
        self.power_iter = int(power_iter)
        self.rng = np.random.default_rng(seed)
        self.basis: np.ndarray | None = None
        self.predicted = self.oversample
        self.counts = {"zero": 0, "subspace": 0, "full": 0, "regrow": 0}

    def reset(self) -> None:
        """Forget the subspace and the predicted rank."""
        self.basis = None
        self.predicted = self.oversample

    def __call__(self, a: np.ndarray, t: float) -> tuple[np.ndarray, int]:
        """SVT of ``a`` (k, m) at threshold ``t``; returns the result and the kept rank."""
        tall = a.shape[0] >= a.shape[1]
        b = a if tall else a.conj().T
        n = b.shape[1]
        t2 = float(t) * float(t)
        flat = b.reshape(-1) if b.flags.c_contiguous else b.ravel()
        if float(np.vdot(flat, flat).real) <= t2:  # ||A||_F <= t: every singular value is
            self.counts["zero"] += 1                 # at most t
            self.reset()
            return np.zeros_like(a), 0
        q = min(n, max(self.predicted, 1))
        while True:
            if q >= self.full_fraction * n or q >= n:
                g, conjugated = _gram(b)
                if self.predicted <= self.oversample and _gershgorin(g, upper=conjugated) <= t2:
                    self.counts["zero"] += 1         # every eigenvalue of G is at most t^2
                    self.reset()
                    return np.zeros_like(a), 0
                lam, v = _eigh(g, lower=False)
                if conjugated:
                    v = v.conj()
                keep = lam > t2
                v = v[:, keep]
                bv = b @ v
                lam = lam[keep]
                self.counts["full"] += 1
                break
            lam, v, bv = _ritz(b, q, basis=self.basis, power_iter=self.power_iter, rng=self.rng)
            self.counts["subspace"] += 1
            keep = lam > t2
            if int(np.count_nonzero(keep)) <= q - self.oversample:
                lam, v, bv = lam[keep], v[:, keep], bv[:, keep]
                break
            self.counts["regrow"] += 1
            q = min(n, int(1.5 * q) + self.oversample)
        r = lam.size
        if r == 0:
            self.reset()
            return np.zeros_like(a), 0
        s = np.sqrt(lam)
        f = (1.0 - t / s).astype(b.real.dtype)
        x = (bv * f) @ v.conj().T
        self.basis = v[:, ::-1]                      # descending: the strongest first
        self.predicted = min(n, int(math.ceil(self.growth * r)) + self.oversample)
        return (x if tall else x.conj().T), r


class FastTSVT:
    """The t-SVT with per-slice state, for repeated calls on tensors of one shape.

    Works on tensors laid out slice-first, (n3, k, m): the DFT along the first
    axis is the real matrix product of :func:`packed_dft` (one pass), each
    independent frequency is thresholded by its own :class:`SliceSVT`, and the
    inverse product returns the real result.

    Parameters
    ----------
    n3
        Length of the transformed mode.
    dtype
        Working precision, float32 (default) or float64.
    workers
        Threads thresholding the frequencies at once.
    seed
        Seed of the random test vectors (frequency i uses ``(seed, i)``).
    **options
        Passed to every :class:`SliceSVT`.
    """

    def __init__(self, n3: int, *, dtype: type = np.float32, workers: int = 1, seed: int = 0,
                 **options) -> None:
        self.n3 = int(n3)
        self.dtype = np.dtype(dtype)
        self.workers = int(workers)
        f, finv, slices = packed_dft(self.n3)
        self.f = f.astype(self.dtype)
        self.finv = finv.astype(self.dtype)
        self.slices = slices
        self.solvers = [SliceSVT(seed=(seed, i), **options) for i in range(len(slices))]

    @property
    def counts(self) -> dict[str, int]:
        """How often each path ran, summed over the slices."""
        out: dict[str, int] = {}
        for s in self.solvers:
            for k, v in s.counts.items():
                out[k] = out.get(k, 0) + v
        return out

    def forward(self, y: np.ndarray) -> np.ndarray:
        """Packed real spectrum (n3, k, m) of a slice-first tensor (n3, k, m)."""
        n3, k, m = y.shape
        return (self.f @ y.reshape(n3, k * m)).reshape(n3, k, m)

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`forward`."""
        n3, k, m = z.shape
        return (self.finv @ z.reshape(n3, k * m)).reshape(n3, k, m)

    def threshold_packed(self, z: np.ndarray, t: float) -> list[int]:
        """Threshold every frequency of a packed spectrum in place; the kept ranks.

        With ``workers > 1`` the frequencies run in that many threads (LAPACK and
        BLAS release the GIL), the complex ones first.
        """
        def one(i: int) -> int:
            rows, svt = self.slices[i], self.solvers[i]
            if len(rows) == 1:
                x, r = svt(z[rows[0]], t)
                z[rows[0]] = x
            else:
                re, im = z[rows[0]], z[rows[1]]
                fr, fi = re.reshape(-1), im.reshape(-1)
                if float(np.dot(fr, fr)) + float(np.dot(fi, fi)) <= float(t) * float(t):
                    svt.counts["zero"] += 1           # ||A||_F <= t, without forming A
                    svt.reset()
                    re[...] = 0
                    im[...] = 0
                    return 0
                a = re + 1j * im
                x, r = svt(a, t)
                re[...] = x.real
                im[...] = x.imag
            return r

        order = sorted(range(len(self.slices)), key=lambda i: -len(self.slices[i]))
        if self.workers > 1 and len(order) > 1:
            with ThreadPoolExecutor(max_workers=min(self.workers, len(order))) as pool:
                got = dict(zip(order, pool.map(one, order)))
        else:
            got = {i: one(i) for i in order}
        return [got[i] for i in range(len(self.slices))]

    def __call__(self, y: np.ndarray, t: float) -> tuple[np.ndarray, list[int]]:
        """t-SVT of a slice-first real tensor (n3, k, m); the result in the working dtype."""
        if y.ndim != 3 or y.shape[0] != self.n3:
            raise ValueError(f"t-SVT of an array of shape {y.shape}: expected ({self.n3}, k, m)")
        z = self.forward(np.asarray(y, dtype=self.dtype))
        ranks = self.threshold_packed(z, t)
        return self.inverse(z), ranks
