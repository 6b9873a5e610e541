"""The numpy backend: its spectral norm and its t-SVTs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.linalg import svds

from polcam.separation._tsvt import tsvt
from polcam.separation.tensor.numpy_backend import chunks, make_tsvt, spectral_norm, spectral_norms


def _arpack(D):
    """||bcirc(D)||_2 of a (k, m, n3) tensor: ARPACK's largest singular value of every Fourier slice."""
    df = np.fft.rfft(D, axis=2)
    best = 0.0
    for i in range(df.shape[2]):
        a = df[:, :, i]
        v = float(np.linalg.norm(a, 2)) if min(a.shape) <= 2 else float(
            svds(a, k=1, return_singular_vectors=False, random_state=0)[0])
        best = max(best, v)
    return best


def test_spectral_norm_of_slices_matches_arpack():
    rng = np.random.default_rng(14)
    for shape in [(40, 30, 4), (30, 50, 5), (8, 8, 3), (60, 45, 4)]:
        D = rng.normal(size=shape)
        if shape[0] == 60:
            D = np.abs(D)                                  # a dominant DC slice, as images have
        want = _arpack(D)
        assert spectral_norm(np.moveaxis(D, 2, 0)) == pytest.approx(want, rel=1e-10)
    z = np.moveaxis(rng.normal(size=(2, 10, 12, 4)), 3, 1)
    np.testing.assert_allclose(spectral_norms(z), [spectral_norm(x) for x in z])


@pytest.mark.parametrize("solver", ["exact", "fast"])
def test_batched_tsvt_is_the_tsvt_of_each_problem(solver):
    rng = np.random.default_rng(15)
    z = rng.normal(size=(2, 3, 20, 15))
    t = np.array([0.5, 2.0])
    op = make_tsvt(solver, n4=3, batch=2, dtype=np.float64)
    got, ranks = op(z, t)
    for b in range(2):
        want, r = tsvt(np.moveaxis(z[b], 0, 2), t[b], solver="exact")
        np.testing.assert_allclose(got[b], np.moveaxis(want, 2, 0), atol=1e-8)
        assert ranks[b] == r
    op.keep([1])
    got1, _ = op(z[1:], t[1:])
    np.testing.assert_allclose(got1[0], got[1], atol=1e-8)
    with pytest.raises(ValueError, match="solver"):
        make_tsvt("magic", n4=3, batch=1, dtype=np.float64)


def test_chunks_cover_the_slices_once():
    a = np.zeros((1, 7, 3))
    for threads in (1, 3):
        with chunks(7, threads) as each:
            def add(c):
                a[c] += 1
                return 1
            assert sum(each(add)) == min(threads, 7)
    assert np.all(a == 2)
