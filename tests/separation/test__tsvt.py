"""The exact t-SVT against independent references."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.separation._tsvt import tensor_nuclear_norm, tsvt


def bcirc(x: np.ndarray) -> np.ndarray:
    """Block-circulant matrix of a (n1, n2, n3) tensor, built directly from its definition."""
    n1, n2, n3 = x.shape
    out = np.zeros((n1 * n3, n2 * n3))
    for i in range(n3):
        for j in range(n3):
            out[i * n1:(i + 1) * n1, j * n2:(j + 1) * n2] = x[:, :, (i - j) % n3]
    return out


def matrix_svt(a: np.ndarray, t: float) -> np.ndarray:
    u, s, vh = np.linalg.svd(a, full_matrices=False)
    return (u * np.maximum(s - t, 0)) @ vh


@pytest.mark.parametrize("shape", [(6, 5, 3), (5, 7, 4), (8, 4, 5), (3, 3, 1)])
@pytest.mark.parametrize("t", [0.0, 0.3, 2.0])
def test_tsvt_is_the_svt_of_the_block_circulant_matrix(shape, t):
    rng = np.random.default_rng(sum(shape))
    y = rng.normal(size=shape)
    x, ranks = tsvt(y, t)
    np.testing.assert_allclose(bcirc(x), matrix_svt(bcirc(y), t), atol=1e-10)
    assert len(ranks) == shape[2] // 2 + 1


def test_tensor_nuclear_norm_carries_the_1_over_n3_factor():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(5, 6, 4))
    s = np.linalg.svd(bcirc(x), compute_uv=False)
    assert np.isclose(tensor_nuclear_norm(x), s.sum() / 4)


def test_tsvt_minimises_the_prox_objective():
    rng = np.random.default_rng(7)
    y = rng.normal(size=(6, 5, 4))
    t = 0.7
    x, _ = tsvt(y, t)

    def objective(z):
        return t * tensor_nuclear_norm(z) + 0.5 * np.sum((z - y) ** 2)

    best = objective(x)
    for _ in range(50):
        assert objective(x + 1e-2 * rng.normal(size=x.shape)) >= best - 1e-12


def test_zero_threshold_is_identity_and_large_threshold_is_zero():
    rng = np.random.default_rng(8)
    y = rng.normal(size=(4, 4, 3))
    np.testing.assert_allclose(tsvt(y, 0.0)[0], y, atol=1e-12)
    x, ranks = tsvt(y, 1e6)
    assert np.all(x == 0) and ranks == [0, 0]


def test_bad_arguments():
    with pytest.raises(ValueError, match="3-way"):
        tsvt(np.zeros((3, 3)), 1.0)
    with pytest.raises(ValueError, match="solver"):
        tsvt(np.zeros((3, 3, 3)), 1.0, solver="magic")


# ---------------------------------------------------------------------------
# the fast solver
# ---------------------------------------------------------------------------

from polcam.separation._tsvt import FastTSVT, SliceSVT, packed_dft, randomized_svd  # noqa: E402


@pytest.mark.parametrize("n3", [1, 2, 3, 4, 5, 6])
def test_packed_dft_holds_the_independent_part_of_rfft(n3):
    rng = np.random.default_rng(n3)
    x = rng.normal(size=(n3, 7))
    f, finv, slices = packed_dft(n3)
    z = f @ x
    want = np.fft.rfft(x, axis=0)
    assert len(slices) == n3 // 2 + 1
    for j, rows in enumerate(slices):
        got = z[rows[0]] if len(rows) == 1 else z[rows[0]] + 1j * z[rows[1]]
        np.testing.assert_allclose(got, want[j], atol=1e-12)
        if len(rows) == 1:                           # the real frequencies: 0 and n3 / 2
            np.testing.assert_allclose(want[j].imag, 0, atol=1e-12)
    np.testing.assert_allclose(finv @ z, x, atol=1e-12)


@pytest.mark.parametrize("shape", [(6, 5, 3), (5, 7, 4), (8, 4, 5), (3, 3, 1), (30, 40, 4)])
@pytest.mark.parametrize("t", [0.0, 0.3, 2.0])
def test_fast_tsvt_in_float64_equals_the_exact_one(shape, t):
    """Same operator: Gram eigenpairs in float64 resolve these well-conditioned slices to ~1e-12."""
    rng = np.random.default_rng(sum(shape) + int(10 * t))
    y = rng.normal(size=shape)
    xe, re = tsvt(y, t)
    xf, rf = tsvt(y, t, solver="fast", dtype=np.float64)
    assert rf == re
    np.testing.assert_allclose(xf, xe, atol=1e-10)


def test_fast_tsvt_in_float32_is_within_float32_accuracy():
    """float32 Gram matrices: singular values are resolved to sqrt(eps32) ~ 2.4e-4 of the largest."""
    rng = np.random.default_rng(3)
    y = rng.normal(size=(40, 30, 4))
    t = 0.5
    xe, re = tsvt(y, t)
    xf, rf = tsvt(y, t, solver="fast")
    assert xf.dtype == y.dtype and rf == re
    smax = max(np.linalg.svd(s, compute_uv=False)[0] for s in np.moveaxis(np.fft.rfft(y, axis=2), 2, 0))
    assert np.abs(xf - xe).max() < 2.4e-4 * smax / 4      # /n3: the inverse DFT averages the slices


def _low_rank(rng, k, m, r, dtype=float):
    """A (k, m) matrix of rank r, real or complex."""
    if np.issubdtype(dtype, np.complexfloating):
        left = rng.normal(size=(k, r)) + 1j * rng.normal(size=(k, r))
        right = rng.normal(size=(r, m)) + 1j * rng.normal(size=(r, m))
        return left @ right
    return rng.normal(size=(k, r)) @ rng.normal(size=(r, m))


@pytest.mark.parametrize("dtype", [float, complex])
def test_randomized_svd_matches_numpy_on_a_low_rank_matrix(dtype):
    rng = np.random.default_rng(4)
    a = _low_rank(rng, 120, 90, 6, dtype)
    u, s, vh = randomized_svd(a, 6)
    u0, s0, vh0 = np.linalg.svd(a, full_matrices=False)
    np.testing.assert_allclose(s, s0[:6], rtol=1e-10)
    np.testing.assert_allclose((u * s) @ vh, a, atol=1e-9 * s0[0])
    np.testing.assert_allclose(u.conj().T @ u, np.eye(6), atol=1e-10)
    np.testing.assert_allclose(vh @ vh.conj().T, np.eye(6), atol=1e-10)
    # the same subspaces as LAPACK's: projectors agree
    np.testing.assert_allclose(u @ u.conj().T, u0[:, :6] @ u0[:, :6].conj().T, atol=1e-9)
    # fewer triplets than the rank: the leading ones
    _, s3, _ = randomized_svd(a, 3)
    np.testing.assert_allclose(s3, s0[:3], rtol=1e-8)
    with pytest.raises(ValueError, match="rank"):
        randomized_svd(a, 0)


def test_slice_svt_subspace_path_grows_and_warm_starts():
    """Low rank above the threshold, noise below it: the subspace path equals the exact SVT."""
    rng = np.random.default_rng(5)
    signal = _low_rank(rng, 150, 100, 20)
    noise = 0.01 * rng.normal(size=(150, 100))        # singular values ~0.2, threshold 1
    svt = SliceSVT(oversample=8, growth=1.25, power_iter=1, seed=0)
    for step in range(4):
        a = signal * (1 + 0.05 * step) + noise
        x, r = svt(a, 1.0)
        u, s, vh = np.linalg.svd(a, full_matrices=False)
        want = (u * np.maximum(s - 1.0, 0)) @ vh
        assert r == 20
        np.testing.assert_allclose(x, want, atol=1e-8 * s[0])
    # the first call predicted 8 directions for rank 20: it regrew, later calls did not
    assert svt.counts["regrow"] >= 1 and svt.counts["subspace"] == 4 + svt.counts["regrow"]
    assert svt.counts["full"] == 0
    # a threshold above the Frobenius norm: zero, without a decomposition
    x, r = svt(noise, 10.0)
    assert r == 0 and np.all(x == 0) and svt.counts["zero"] == 1


def test_slice_svt_wide_and_complex_matrices():
    rng = np.random.default_rng(6)
    for a in (rng.normal(size=(20, 35)), rng.normal(size=(30, 25)) + 1j * rng.normal(size=(30, 25))):
        x, r = SliceSVT(full_fraction=0.0)(a, 2.0)
        u, s, vh = np.linalg.svd(a, full_matrices=False)
        np.testing.assert_allclose(x, (u * np.maximum(s - 2.0, 0)) @ vh, atol=1e-10)
        assert r == int(np.sum(s > 2.0))


def test_fast_tsvt_state_and_threads_give_the_same_result():
    rng = np.random.default_rng(7)
    y = np.moveaxis(rng.normal(size=(24, 18, 4)), 2, 0)
    one = FastTSVT(4, dtype=np.float64)
    two = FastTSVT(4, dtype=np.float64, workers=2)
    for t in (3.0, 1.0, 0.5):
        x1, r1 = one(y, t)
        x2, r2 = two(y, t)
        np.testing.assert_array_equal(x1, x2)
        assert r1 == r2
    with pytest.raises(ValueError, match="expected"):
        one(np.zeros((3, 4, 4)), 1.0)
