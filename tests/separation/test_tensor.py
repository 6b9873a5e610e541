"""The tensor method, step by step, against independent references."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation import separate
from polcam.separation.tensor import (
    estimate_illuminant,
    fold,
    gather,
    ialm,
    phase_project,
    polarization_chromaticity,
    representations,
    tau_weights,
    unfold,
)
from polcam.stokes import fit_sinusoid, synthesize


def tprod(a, b):
    """t-product via the definition: circular convolution along the third mode."""
    n3 = a.shape[2]
    out = np.zeros((a.shape[0], b.shape[1], n3))
    for k in range(n3):
        for j in range(n3):
            out[:, :, k] += a[:, :, j] @ b[:, :, (k - j) % n3]
    return out


def test_ialm_recovers_a_planted_low_tubal_rank_plus_sparse_tensor():
    """TRPCA exact recovery (Lu et al. 2020): tubal rank 2, 5% gross corruptions."""
    rng = np.random.default_rng(0)
    n, n3, r = 40, 5, 2
    L0 = tprod(rng.normal(size=(n, r, n3)) / np.sqrt(n), rng.normal(size=(r, n, n3)))
    S0 = np.zeros_like(L0)
    mask = rng.random(L0.shape) < 0.05
    S0[mask] = rng.choice([-1.0, 1.0], mask.sum()) * 2
    lam = 1 / np.sqrt(n * n3)
    L, S, info = ialm(L0 + S0, tau=None, lam=lam, gamma=0.0, rho=1.1, tol=1e-8, max_iter=500)
    assert info["converged"]
    assert np.linalg.norm(L - L0) / np.linalg.norm(L0) < 1e-3
    assert np.linalg.norm(S - S0) / np.linalg.norm(S0) < 1e-3
    assert max(info["ranks"][-1]) == r
    # residuals are recorded per iteration and end below the tolerance
    assert len(info["residuals"]) == info["iterations"] and info["residual"] < 1e-8


def test_ialm_phase_term_pulls_towards_the_projection():
    """With a projection onto a set containing the truth, the phase term cannot hurt."""
    rng = np.random.default_rng(1)
    D = np.abs(rng.normal(size=(8, 6, 3)))
    L, S, info = ialm(D, tau=None, lam=0.3, gamma=1.0, project=lambda t: np.zeros_like(t),
                      max_iter=300)
    L0, S0, _ = ialm(D, tau=None, lam=0.3, gamma=0.0, max_iter=300)
    assert np.linalg.norm(L) < np.linalg.norm(L0)
    assert info["converged"]
    with pytest.raises(ValueError, match="projection"):
        ialm(D, tau=None, lam=0.3, gamma=1.0)


def _common_phase_stack(rng, n4=2, h=5, w=6):
    ic = rng.uniform(0.3, 0.6, (n4, h, w, 3))
    isv = rng.uniform(0.0, 0.2, (n4, h, w, 3))
    phi = np.repeat(rng.uniform(0, np.pi, (n4, h, w, 1)), 3, axis=-1)
    return np.moveaxis(synthesize(ic, isv, phi), 0, 1), ic, isv  # (n4, 4, h, w, 3)


def test_phase_projection_keeps_a_stack_with_a_common_phase():
    rng = np.random.default_rng(2)
    x, _, _ = _common_phase_stack(rng)
    np.testing.assert_allclose(phase_project(x), x, atol=1e-12)


def test_phase_projection_gives_one_phase_and_keeps_ic_and_isv():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (2, 4, 5, 6, 3))
    q = phase_project(x)
    fx = fit_sinusoid(np.moveaxis(x, 1, 0))
    fq = fit_sinusoid(np.moveaxis(q, 1, 0))
    np.testing.assert_allclose(fq.ic, fx.ic, atol=1e-12)
    np.testing.assert_allclose(fq.isv, fx.isv, atol=1e-12)
    # all channels share the phase; it is the circular mean of the channel phases (doubled angles)
    d = np.abs((fq.phi - fq.phi[..., :1] + np.pi / 2) % np.pi - np.pi / 2)
    assert d.max() < 1e-9
    want = 0.5 * np.angle(np.exp(2j * fx.phi).sum(axis=-1)) % np.pi
    d = np.abs((fq.phi[..., 0] - want + np.pi / 2) % np.pi - np.pi / 2)
    assert d.max() < 1e-9
    # the wrap at pi: phases 179 and 1 degrees average to 0, not 90
    two = np.deg2rad([179.0, 1.0, 0.0])
    y = np.moveaxis(synthesize(np.full(3, 0.5), np.full(3, 0.2), two), 0, 0)[None, :, None, None, :]
    fy = fit_sinusoid(np.moveaxis(phase_project(y), 1, 0))
    assert min(fy.phi.ravel()[0], np.pi - fy.phi.ravel()[0]) < 1e-6


def test_unfold_layout_and_round_trip():
    rng = np.random.default_rng(4)
    n4, n1, n2 = 3, 4, 5
    d = rng.normal(size=(n4, 4, n1, n2, 3))
    D = unfold(d)
    assert D.shape == (4 * n1, 3 * n2, n4)
    # row block a = angle, column block c = channel, third mode = representation
    for rep, ang, y, x, c in [(0, 0, 0, 0, 0), (2, 3, 1, 4, 2), (1, 2, 3, 2, 1)]:
        assert D[ang * n1 + y, c * n2 + x, rep] == d[rep, ang, y, x, c]
    np.testing.assert_array_equal(fold(D, n1, n2), d)


def test_polarization_chromaticity_closed_form():
    # one pixel polarized, one not; Ic = 0.4/0.3/0.2, Isv = 0.05 each channel on pixel 0
    ic = np.array([[[0.4, 0.3, 0.2], [0.2, 0.2, 0.2]]])
    isv = np.array([[[0.05, 0.05, 0.05], [0.0, 0.0, 0.0]]])
    stack = synthesize(ic, isv, np.zeros_like(ic))
    chro = polarization_chromaticity(stack)
    raw_d = np.maximum(ic - 2 * isv, 0)
    i_min_bar = np.mean([0.2, 0.2])
    want = raw_d / (raw_d.sum(axis=-1, keepdims=True) + i_min_bar)
    np.testing.assert_allclose(chro, want, atol=1e-12)
    # DoLP > 0.5: raw diffuse is clipped at 0, never negative
    s = synthesize(np.full((1, 1, 3), 0.2), np.full((1, 1, 3), 0.15), np.zeros((1, 1, 3)))
    assert np.all(polarization_chromaticity(s) == 0)


def test_representations_are_similar_neighbours_in_the_block():
    rng = np.random.default_rng(5)
    chro = np.zeros((12, 14, 3))
    chro[:, 7:] = [0.5, 0.3, 0.2]     # two regions of different chromaticity
    chro[:, :7] = [0.2, 0.3, 0.5]
    off, filled = representations(chro, n4=4, block=5, threshold=0.03, rng=rng)
    assert off.shape == (4, 12, 14, 2) and np.all(off[0] == 0)
    assert np.abs(off).max() <= 2 and filled > 0.9
    yy, xx = np.mgrid[0:12, 0:14]
    for i in range(1, 4):
        qy, qx = yy + off[i, ..., 0], xx + off[i, ..., 1]
        assert qy.min() >= 0 and qy.max() < 12 and qx.min() >= 0 and qx.max() < 14
        assert np.all(np.linalg.norm(chro[qy, qx] - chro, axis=-1) < 0.03)
        # without replacement: representations of a pixel differ unless they fell back to p
        for j in range(1, i):
            same = np.all(off[i] == off[j], axis=-1) & np.any(off[i] != 0, axis=-1)
            assert not np.any(same)
    # seeded: the same draw again
    off2, _ = representations(chro, n4=4, block=5, threshold=0.03, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(off, off2)
    # an isolated pixel with no similar neighbour falls back to itself
    chro[6, 3] = [0.9, 0.05, 0.05]
    off3, _ = representations(chro, n4=4, block=3, threshold=0.03, rng=np.random.default_rng(0))
    assert np.all(off3[:, 6, 3] == 0)


def test_gather_moves_pixels_by_their_offsets():
    img = np.arange(2 * 3 * 4 * 3, dtype=float).reshape(2, 3, 4, 3)
    off = np.zeros((2, 3, 4, 2), dtype=np.intp)
    off[1, 1, 2] = (1, -1)
    g = gather(img, off)
    np.testing.assert_array_equal(g[0], img)
    np.testing.assert_array_equal(g[1, :, 1, 2], img[:, 2, 1])


def test_tau_follows_the_formula_and_stays_positive():
    first = np.zeros((4, 6, 6, 3))
    first[:, :, 3:] = 0.5          # a vertical edge
    first[0, 0, 0, 0] = 1.2        # saturated / above 1
    tau = tau_weights(first, alpha=2.0, beta=0.25, floor=1e-3)
    assert np.all(tau > 0)
    assert np.isclose(tau[1, 4, 0, 1], 1.0)                       # flat, I = 0, no gradient
    g = 0.25                                                    # central difference at the edge
    assert np.isclose(tau[1, 4, 2, 1], 1.0 * np.exp(2.0 * g**0.25))
    assert np.isclose(tau[1, 4, 5, 1], 0.5)
    assert tau[0, 0, 0, 0] < 0.01


def test_illuminant_from_the_polarized_light():
    rng = np.random.default_rng(6)
    h = w = 40
    yy, xx = np.mgrid[0:h, 0:w] / h
    diffuse = np.where((xx < 0.5)[..., None], [0.5, 0.2, 0.1], [0.1, 0.3, 0.4])   # coloured albedo
    gam = np.array([0.45, 0.35, 0.20])
    lobe = 0.3 * np.exp(-((xx - 0.5) ** 2 + (yy - 0.5) ** 2) / 0.02)[..., None]
    spec = lobe * gam * 3
    phi = ((np.arctan2(yy - 0.5, xx - 0.5) + np.pi / 2) % np.pi)[..., None] * np.ones(3)
    clean = synthesize(diffuse + spec, 0.6 * spec, phi)
    np.testing.assert_allclose(estimate_illuminant(clean), gam, atol=1e-6)
    # noise in the colour of the (reddish) diffuse does not bias the estimate
    noisy = clean + rng.normal(0, 0.01, clean.shape) * np.sqrt(clean / 0.5)
    np.testing.assert_allclose(estimate_illuminant(np.clip(noisy, 0, 1)), gam, atol=0.02)
    # no polarized light, only noise: white
    flat = synthesize(diffuse, np.zeros_like(diffuse), np.zeros_like(diffuse))
    flat = flat + rng.normal(0, 0.01, flat.shape)
    np.testing.assert_allclose(estimate_illuminant(np.clip(flat, 0, 1)), 1 / 3)


def _scene(n=16):
    yy, xx = np.mgrid[0:n, 0:n] / n
    albedo = np.where((xx < 0.5)[..., None], [0.6, 0.25, 0.15], [0.15, 0.35, 0.6])
    D = albedo * (0.6 + 0.4 * np.cos(2 * (xx - 0.5)))[..., None]
    lobe = 0.5 * np.exp(-((xx - 0.45) ** 2 + (yy - 0.4) ** 2) / (2 * 0.1 ** 2))
    spec = lobe[..., None] * np.ones(3)
    phi = np.repeat(((np.arctan2(yy - 0.5, xx - 0.5) + np.pi / 2) % np.pi)[..., None], 3, -1)
    return np.clip(synthesize(D + spec, 0.7 * spec, phi), 0, 1), D


@pytest.mark.parametrize("method", ["tensor", "tensor-tau", "tensor-plain"])
def test_tensor_methods_end_to_end(method):
    stack, D = _scene()
    res = separate(stack, method=method, max_iter=60)
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (16, 16, 3) and res.diffuse.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    err_in = np.mean((mean - D) ** 2)
    err_out = np.mean((res.diffuse - D) ** 2)
    assert err_out < 0.25 * err_in                # > 6 dB better than doing nothing
    info = res.info
    assert info["iterations"] >= 1 and len(info["residuals"]) == info["iterations"]
    assert info["variant"] == method and "converged" in info and "residual" in info
    # deterministic with the seed
    again = separate(stack, method=method, max_iter=60)
    np.testing.assert_array_equal(again.diffuse, res.diffuse)


def test_tensor_refuses_what_it_cannot_use():
    stack, _ = _scene(8)
    with pytest.raises(MethodError, match="needs colour"):
        separate(stack[..., 0], method="tensor")
    with pytest.raises(MethodError, match="polarization stack"):
        separate(stack[0], method="tensor")
    with pytest.raises(MethodError, match="unknown option"):
        separate(stack, method="tensor", n5=3)


def test_dark_input_gives_zero():
    res = separate(np.zeros((4, 8, 8, 3)), method="tensor")
    assert np.all(res.diffuse == 0) and res.info["converged"]
