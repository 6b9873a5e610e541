"""The numpy backend of the tensor method: its t-SVTs, its spectral norm, its threads.

:func:`polcam.separation.tensor.ialm.ialm` asks a backend for three things:

* :func:`make_tsvt`: the t-SVT of a batch of slice-first tensors, ``"exact"``
  (:func:`polcam.separation._tsvt.tsvt`, a full SVD of every Fourier slice, in
  float64: the reference) or ``"fast"`` (one
  :class:`polcam.separation._tsvt.FastTSVT` per problem, warm-started between
  iterations);
* :func:`spectral_norms`: ``||bcirc(D)||_2`` of each problem (mu0);
* :func:`chunks`: how the element-wise updates are split (groups of frontal
  slices in threads: numpy releases the GIL on large arrays).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from polcam.separation._tsvt import FastTSVT, packed_dft, tsvt

__all__ = ["make_tsvt", "spectral_norms", "spectral_norm", "top_singular_value", "chunks"]


class _ExactTSVT:
    """Full-SVD t-SVT of each problem of a batch (B, n4, k, m)."""

    def __init__(self, batch: int) -> None:
        self.batch = batch

    def __call__(self, z: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, list[list[int]]]:
        out = np.empty_like(z)
        ranks = []
        for b in range(z.shape[0]):
            x, r = tsvt(np.moveaxis(z[b], 0, 2), float(t[b]), solver="exact")
            out[b] = np.moveaxis(x, 2, 0)
            ranks.append(r)
        return out, ranks

    def keep(self, idx: list[int]) -> None:
        self.batch = len(idx)

    def counts(self, j: int) -> dict[str, int]:
        return {}


class _FastTSVT:
    """One warm-started :class:`~polcam.separation._tsvt.FastTSVT` per problem of a batch."""

    def __init__(self, n4: int, batch: int, dtype: Any, threads: int, options: dict[str, Any]) -> None:
        self.ops = [FastTSVT(n4, dtype=dtype, workers=threads, **options) for _ in range(batch)]

    def __call__(self, z: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, list[list[int]]]:
        if z.shape[0] == 1:
            x, r = self.ops[0](z[0], float(t[0]))
            return x[None], [r]
        out = np.empty_like(z)
        ranks = []
        for b, op in enumerate(self.ops):
            out[b], r = op(z[b], float(t[b]))
            ranks.append(r)
        return out, ranks

    def keep(self, idx: list[int]) -> None:
        self.ops = [self.ops[i] for i in idx]

    def counts(self, j: int) -> dict[str, int]:
        return self.ops[j].counts


def make_tsvt(solver: str, *, n4: int, batch: int, dtype: Any, threads: int = 1,
              options: dict[str, Any] | None = None) -> Any:
    """The t-SVT of ``solver`` for a batch of ``batch`` problems with ``n4`` frontal slices.

    The returned object maps ((B, n4, k, m), (B,) thresholds) to the thresholded
    tensors and the kept rank of every Fourier slice of every problem; ``keep``
    drops the problems that stopped; ``counts(j)`` tells how often each path of
    problem j's fast t-SVT ran.
    """
    if solver == "exact":
        return _ExactTSVT(batch)
    if solver == "fast":
        return _FastTSVT(n4, batch, np.dtype(dtype), threads, options or {})
    raise ValueError(f"t-SVT solver {solver!r}: expected 'exact' or 'fast'")


def top_singular_value(a: np.ndarray, *, block: int = 4, rtol: float = 1e-13, max_iter: int = 500) -> float:
    """Largest singular value of a matrix by block subspace iteration on its Gram matrix.

    ``block`` vectors (seeded), multiplied by ``A^H A`` and re-orthonormalised
    until the largest Rayleigh-Ritz value changes by less than ``rtol``
    relatively; its error then falls as ``(s_{block+1} / s_1)^(4 i)``, which for
    image data (a dominant first singular value) takes a few steps, each two
    thin products.
    """
    b = a if a.shape[0] >= a.shape[1] else a.conj().T
    n = b.shape[1]
    rng = np.random.default_rng(0)
    z = np.linalg.qr(rng.standard_normal((n, min(block, n))).astype(b.dtype))[0]
    prev = -1.0
    lam = 0.0
    for _ in range(max_iter):
        y = b @ z
        c = y.conj().T @ y
        lam = float(np.linalg.eigvalsh(0.5 * (c + c.conj().T))[-1])
        if lam <= 0 or abs(lam - prev) <= rtol * lam:
            break
        prev = lam
        z = np.linalg.qr(b.conj().T @ y)[0]
    return math.sqrt(max(lam, 0.0))


def spectral_norm(z: np.ndarray) -> float:
    """``||bcirc||_2`` of a slice-first tensor (n4, k, m), in float64.

    The largest singular value over the independent Fourier slices, each by
    :func:`top_singular_value` (agrees with ARPACK to about 1e-13), visiting the
    slices by decreasing Frobenius norm and stopping when that bound falls below
    the best so far: for image data only the DC slice is decomposed.
    """
    z64 = np.asarray(z, dtype=np.float64)
    n4, k, m = z64.shape
    f, _, slices = packed_dft(n4)
    zf = (f @ z64.reshape(n4, -1)).reshape(n4, k, m)
    mats = [zf[rows[0]] if len(rows) == 1 else zf[rows[0]] + 1j * zf[rows[1]] for rows in slices]
    fro = [float(np.linalg.norm(a)) for a in mats]
    best = 0.0
    for i in np.argsort(fro)[::-1]:
        if fro[i] <= best:            # s_1 <= ||A||_F: this slice cannot hold the maximum
            break
        best = max(best, top_singular_value(mats[i]))
    return best


def spectral_norms(d: np.ndarray) -> np.ndarray:
    """:func:`spectral_norm` of each problem of a batch (B, n4, k, m): (B,) float64."""
    return np.array([spectral_norm(x) for x in d])


@contextlib.contextmanager
def chunks(n4: int, threads: int) -> Iterator[Callable[[Callable[[Any], Any]], list[Any]]]:
    """``each(fn)``: ``fn(c)`` for index tuples ``c`` splitting (B, n4, ...) arrays along the slices.

    With ``threads > 1`` the groups of frontal slices run in that many threads.
    """
    nch = max(1, min(int(threads), n4))
    bounds = np.linspace(0, n4, nch + 1).astype(int)
    parts = [(slice(None), slice(int(a), int(b))) for a, b in zip(bounds[:-1], bounds[1:])]
    if nch == 1:
        yield lambda fn: [fn(c) for c in parts]
        return
    with ThreadPoolExecutor(max_workers=nch) as pool:
        yield lambda fn: list(pool.map(fn, parts))
