"""The one IALM loop: planted TRPCA problems, the phase term, batches, and the torch backend."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.separation.tensor.ialm import ialm
from polcam.separation.tensor.operators import phase_project, unfold


def tprod(a, b):
    """t-product via the definition: circular convolution along the third mode."""
    n3 = a.shape[2]
    out = np.zeros((a.shape[0], b.shape[1], n3))
    for k in range(n3):
        for j in range(n3):
            out[:, :, k] += a[:, :, j] @ b[:, :, (k - j) % n3]
    return out


def _planted_trpca():
    """Tubal rank r = 2 (40 x 40 x 5) plus 5 % gross corruptions of +-2, slice-first (5, 40, 40);
    (L0, S0, TRPCA's lambda, r)."""
    rng = np.random.default_rng(0)
    n, n3, r = 40, 5, 2
    L0 = tprod(rng.normal(size=(n, r, n3)) / np.sqrt(n), rng.normal(size=(r, n, n3)))
    S0 = np.zeros_like(L0)
    mask = rng.random(L0.shape) < 0.05
    S0[mask] = rng.choice([-1.0, 1.0], mask.sum()) * 2
    return np.moveaxis(L0, 2, 0), np.moveaxis(S0, 2, 0), 1 / np.sqrt(n * n3), r


def test_ialm_recovers_a_planted_low_tubal_rank_plus_sparse_tensor():
    """TRPCA exact recovery (Lu et al. 2020): tubal rank 2, 5% gross corruptions."""
    L0, S0, lam, r = _planted_trpca()
    L, S, info = ialm(L0 + S0, tau=None, lam=lam, gamma=0.0, rho=1.1, tol=1e-8, max_iter=500)
    assert info["converged"] and L.dtype == np.float64
    assert np.linalg.norm(L - L0) / np.linalg.norm(L0) < 1e-3
    assert np.linalg.norm(S - S0) / np.linalg.norm(S0) < 1e-3
    assert max(info["ranks"][-1]) == r
    # residuals are recorded per iteration and end below the tolerance
    assert len(info["residuals"]) == info["iterations"] and info["residual"] < 1e-8


def test_fast_ialm_recovers_the_planted_tensor_like_the_exact_one():
    """The TRPCA problem of the exact test: both t-SVTs reach the same minimiser (tol 1e-8)."""
    L0, S0, lam, r = _planted_trpca()
    Le, Se, ie = ialm(L0 + S0, tau=None, lam=lam, gamma=0.0, rho=1.1, tol=1e-8, max_iter=500)
    Lf, Sf, i_f = ialm(L0 + S0, tau=None, lam=lam, gamma=0.0, rho=1.1, tol=1e-8, max_iter=500,
                       solver="fast", dtype=np.float64)
    assert i_f["converged"] and max(i_f["ranks"][-1]) == r
    assert np.linalg.norm(Lf - L0) / np.linalg.norm(L0) < 1e-3
    assert np.linalg.norm(Lf - Le) / np.linalg.norm(Le) < 1e-6
    assert i_f["iterations"] == ie["iterations"]
    assert sum(i_f["svt_counts"].values()) > 0


def test_ialm_phase_term_pulls_towards_the_projection():
    """With a projection onto a set containing the truth, the phase term cannot hurt."""
    rng = np.random.default_rng(1)
    D = np.abs(rng.normal(size=(3, 8, 6)))
    L, S, info = ialm(D, tau=None, lam=0.3, gamma=1.0, project=lambda t: np.zeros_like(t), max_iter=300)
    L0, S0, _ = ialm(D, tau=None, lam=0.3, gamma=0.0, max_iter=300)
    assert np.linalg.norm(L) < np.linalg.norm(L0)
    assert info["converged"]
    with pytest.raises(ValueError, match="projection"):
        ialm(D, tau=None, lam=0.3, gamma=1.0)


def test_fast_ialm_stops_on_the_residual_and_keeps_zero_input():
    rng = np.random.default_rng(12)
    D = np.abs(rng.normal(size=(3, 12, 9)))
    L, S, info = ialm(D, tau=None, lam=0.3, gamma=0.0, tol=1e-4, solver="fast")
    assert L.dtype == np.float32 and info["converged"] and info["residual"] < 1e-4
    assert np.linalg.norm(D - L - S) / np.linalg.norm(D) < 1e-4 * 1.01
    z, _, info0 = ialm(np.zeros((3, 4, 4)), tau=None, lam=0.3, gamma=0.0, solver="fast")
    assert np.all(z == 0) and info0["converged"] and info0["iterations"] == 0
    with pytest.raises(ValueError, match="projection"):
        ialm(D, tau=None, lam=0.3, gamma=1.0, solver="fast")


def test_a_batch_is_independent_problems():
    """Each problem of a batch has its own mu0, stopping iteration and answer; a zero one stays zero."""
    rng = np.random.default_rng(13)
    Z = unfold(rng.uniform(0, 1, (4, 4, 6, 5, 3)))
    tau = rng.uniform(0.5, 2, (1,) + Z.shape[1:])

    def project(t, out=None):
        return phase_project(t, 6, 5, out=out)

    kw = dict(lam=0.1, gamma=0.1, project=project, chunked_project=True, tol=1e-6, solver="exact")
    one, _, r1 = ialm(Z, tau=tau, **kw)
    L, _, recs = ialm(np.stack([Z, 0.5 * Z, 0 * Z]), tau=np.stack([tau] * 3), **kw)
    np.testing.assert_allclose(L[0], one, atol=1e-12)
    assert recs[0]["iterations"] == r1["iterations"]
    # scale-equivariant: half the data, half the answer, in as many iterations, mu0 twice as large
    np.testing.assert_allclose(L[1], 0.5 * L[0], atol=1e-9)
    assert recs[1]["iterations"] == recs[0]["iterations"] and np.isclose(recs[1]["mu0"], 2 * recs[0]["mu0"])
    assert np.all(L[2] == 0) and recs[2]["iterations"] == 0 and recs[2]["converged"]


def test_torch_backend_matches_numpy():
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(13)
    d = rng.uniform(0, 1, (4, 4, 12, 12, 3))
    Z = unfold(d)
    tau = rng.uniform(0.5, 2, (1,) + Z.shape[1:])

    def project(t, out=None):
        return phase_project(t, 12, 12, out=out)

    # one tensor problem: the batched torch IALM in float64 = the numpy one with its full path
    Ln, _, rn = ialm(Z, tau=tau, lam=0.1, gamma=0.1, project=project, chunked_project=True, tol=1e-6,
                     solver="fast", dtype=np.float64, svt_options={"full_fraction": 0.0})
    Lt, _, rt = ialm(torch.as_tensor(np.stack([Z, 0.5 * Z])), tau=torch.as_tensor(np.stack([tau, tau])),
                     lam=0.1, gamma=0.1, project=project, chunked_project=True, tol=1e-6, solver="fast",
                     dtype=np.float64)
    Lt = Lt.numpy()
    assert rt[0]["iterations"] == rn["iterations"] and rt[0]["converged"]
    np.testing.assert_allclose(Lt[0], Ln, atol=1e-8)
    # each tile is its own problem with its own mu0 = 1.25 / ||D||_2: the iteration is then
    # scale-equivariant, so the tile at half the scale gives half the answer in as many iterations
    assert rt[1]["iterations"] == rt[0]["iterations"] and rt[1]["converged"]
    np.testing.assert_allclose(Lt[1], 0.5 * Lt[0], atol=1e-8)
    assert np.isclose(rt[1]["mu0"], 2 * rt[0]["mu0"])
