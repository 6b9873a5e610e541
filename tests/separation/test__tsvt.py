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
