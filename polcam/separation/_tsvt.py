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

``solver="exact"`` computes a full SVD of every slice (LAPACK gesdd through
numpy); it is the reference the faster solvers are checked against.
"""

from __future__ import annotations

import numpy as np

__all__ = ["tsvt", "tensor_nuclear_norm", "SOLVERS"]

#: t-SVT solvers available.
SOLVERS: tuple[str, ...] = ("exact",)


def _slice_svt(a: np.ndarray, t: float) -> tuple[np.ndarray, int]:
    """SVT of one (complex) matrix: U max(S - t, 0) V^H and the kept rank."""
    u, s, vh = np.linalg.svd(a, full_matrices=False)
    s = s - t
    r = int(np.count_nonzero(s > 0))
    if r == 0:
        return np.zeros_like(a), 0
    return (u[:, :r] * s[:r]) @ vh[:r], r


def tsvt(y: np.ndarray, t: float, *, solver: str = "exact") -> tuple[np.ndarray, list[int]]:
    """Proximal operator of ``t * ||.||_*`` (tensor nuclear norm with 1/n3).

    Parameters
    ----------
    y
        Real tensor (n1, n2, n3).
    t
        Threshold >= 0.
    solver
        ``"exact"``: full SVD of each of the n3 // 2 + 1 Fourier slices.

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
