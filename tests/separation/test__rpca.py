"""The blocked IALM iterations of wen21's solver (polcam.separation._rpca)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from polcam.separation import _rpca
from polcam.separation._rpca import _rpca_direction_t, rpca_ialm


def _problem(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A (3, n) dichromatic matrix: diffuse of rank 1 plus sparse specular along g."""
    rng = np.random.default_rng(seed)
    g = np.array([0.9, 1.0, 1.1])
    diffuse = np.outer([0.7, 0.4, 0.2], rng.uniform(0.1, 0.8, n))
    spec = np.where(rng.random(n) < 0.1, rng.uniform(0.1, 0.5, n), 0.0)
    m = diffuse + np.outer(g, spec) + rng.normal(0, 1e-3, (3, n))
    m = np.ascontiguousarray(np.clip(m, 0, None))
    lower = np.ascontiguousarray(0.2 * np.outer(g, spec))
    prior = np.ascontiguousarray(np.minimum(2 * lower, m))
    return m, lower, prior, g


@pytest.mark.parametrize("parts", [2, 3, 5])
def test_blocks_on_threads_give_the_serial_result_bit_for_bit(monkeypatch, parts):
    monkeypatch.setattr(_rpca, "_IALM_BLOCK", 256)  # 1000 pixels: 4 blocks, unevenly split
    m, lower, prior, g = _problem(1000)
    kw = {"lam": 1 / np.sqrt(1000), "beta": 0.5, "tol": 1e-9, "max_iter": 60}
    serial, its, conv = _rpca_direction_t(m, lower, prior, g, **kw)
    with ThreadPoolExecutor(max_workers=2) as pool:
        threaded, its_t, conv_t = _rpca_direction_t(m, lower, prior, g, pool=pool, parts=parts, **kw)
    assert its == its_t and conv == conv_t and its > 5
    np.testing.assert_array_equal(threaded, serial)


def test_blocked_solver_matches_the_general_one(monkeypatch):
    """The transposed, blocked path solves the same problem as rpca_ialm's general loop."""
    monkeypatch.setattr(_rpca, "_IALM_BLOCK", 256)
    m, lower, prior, g = _problem(1000, seed=1)
    kw = {"lam": 1 / np.sqrt(1000), "beta": 0.5, "tol": 1e-9, "max_iter": 200}
    with ThreadPoolExecutor(max_workers=2) as pool:
        sp, _, conv = _rpca_direction_t(m, lower, prior, g, pool=pool, parts=2, **kw)
    ref = rpca_ialm(m.T, lower=lower.T, upper=m.T, direction=g, prior=prior.T, **kw)
    assert conv and ref.converged
    np.testing.assert_allclose(sp, ref.sparse.T, atol=1e-7)
