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
    separate_tensor,
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


def _planted_trpca():
    """Tubal rank r = 2 (40 x 40 x 5) plus 5 % gross corruptions of +-2; (L0, S0, TRPCA's lambda, r)."""
    rng = np.random.default_rng(0)
    n, n3, r = 40, 5, 2
    L0 = tprod(rng.normal(size=(n, r, n3)) / np.sqrt(n), rng.normal(size=(r, n, n3)))
    S0 = np.zeros_like(L0)
    mask = rng.random(L0.shape) < 0.05
    S0[mask] = rng.choice([-1.0, 1.0], mask.sum()) * 2
    return L0, S0, 1 / np.sqrt(n * n3), r


def test_ialm_recovers_a_planted_low_tubal_rank_plus_sparse_tensor():
    """TRPCA exact recovery (Lu et al. 2020): tubal rank 2, 5% gross corruptions."""
    L0, S0, lam, r = _planted_trpca()
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
    # the dispatcher refuses it first, naming the options (the registered option list)
    with pytest.raises(MethodError, match="takes no option 'n5'; its options: n4, block"):
        separate(stack, method="tensor", n5=3)
    with pytest.raises(MethodError, match="unknown option"):          # called directly
        separate_tensor(stack, n5=3)


def test_dark_input_gives_zero():
    res = separate(np.zeros((4, 8, 8, 3)), method="tensor")
    assert np.all(res.diffuse == 0) and res.info["converged"]


# ---------------------------------------------------------------------------
# the fast solver, tiling and the PyTorch backend
# ---------------------------------------------------------------------------

from polcam.separation.tensor import (  # noqa: E402
    FAST_TOL,
    blend,
    fold_slices,
    ialm_fast,
    phase_project_slices,
    tile_spans,
    tile_windows,
    tiled,
    unfold_slices,
)


def test_slice_first_layout_and_phase_projection_match_the_unfolded_ones():
    rng = np.random.default_rng(10)
    d = rng.uniform(0, 1, (3, 4, 5, 6, 3))
    d[:, :, 0, 0, :] = 0.4                      # a pixel without polarization: no phase
    z = unfold_slices(d)
    np.testing.assert_array_equal(z, np.moveaxis(unfold(d), 2, 0))
    np.testing.assert_array_equal(fold_slices(z, 5, 6), d)
    np.testing.assert_allclose(phase_project_slices(z, 5, 6), unfold_slices(phase_project(d)), atol=1e-12)
    out = np.empty_like(z)
    assert phase_project_slices(z, 5, 6, out=out) is out


def test_fast_ialm_recovers_the_planted_tensor_like_the_exact_one():
    """The TRPCA problem of the exact test: both solvers reach the same minimiser (tol 1e-8)."""
    L0, S0, lam, r = _planted_trpca()
    Le, Se, ie = ialm(L0 + S0, tau=None, lam=lam, gamma=0.0, rho=1.1, tol=1e-8, max_iter=500)
    Lf, Sf, i_f = ialm(L0 + S0, tau=None, lam=lam, gamma=0.0, rho=1.1, tol=1e-8, max_iter=500,
                       solver="fast")
    assert i_f["converged"] and max(i_f["ranks"][-1]) == r
    assert np.linalg.norm(Lf - L0) / np.linalg.norm(L0) < 1e-3
    assert np.linalg.norm(Lf - Le) / np.linalg.norm(Le) < 1e-6
    assert i_f["iterations"] == ie["iterations"]


def test_fast_and_exact_agree_on_a_small_scene():
    """float64, the paper's initialisation: the fast solver's only departure is its randomized
    subspace (measured <= 5e-6 here); float32 and the shared initialisation (the defaults): Gram
    eigenvalues resolve singular values to sqrt(eps32) ~ 2.4e-4 of the largest and the run stops at
    FAST_TOL: within 1e-2 of a [0, 1] image, and an RMS difference 20 dB below the input's error."""
    stack, D = _scene(20)
    for method in ("tensor", "tensor-plain"):
        exact = separate(stack, method=method, solver="exact")
        f64 = separate(stack, method=method, solver="fast", precision="float64", tol=1e-5,
                       shared_init=False)
        np.testing.assert_allclose(f64.diffuse, exact.diffuse, atol=5e-5)
        assert f64.info["iterations"] == exact.info["iterations"]
        f32 = separate(stack, method=method)
        assert f32.info["solver"] == "fast" and f32.info["tol"] == FAST_TOL
        np.testing.assert_allclose(f32.diffuse, exact.diffuse, atol=1e-2)
        rms = np.sqrt(np.mean((f32.diffuse - exact.diffuse) ** 2))
        assert rms < 0.1 * np.sqrt(np.mean((stack.mean(axis=0) - D) ** 2))


@pytest.mark.parametrize("n,tile,overlap", [(10, 16, 4), (16, 16, 4), (40, 16, 4), (37, 12, 5), (100, 30, 0)])
def test_tile_spans_cover_with_the_overlap(n, tile, overlap):
    spans = tile_spans(n, tile, overlap)
    assert spans[0][0] == 0 and spans[-1][1] == n
    assert all(b - a == min(tile, n) for a, b in spans)
    for (a0, b0), (a1, b1) in zip(spans, spans[1:]):
        assert a0 < a1 and b0 - a1 >= overlap          # consecutive tiles share >= overlap pixels


def test_blending_reproduces_a_pixelwise_result_on_any_tiling():
    """A per-pixel 'solver' gives the same image whatever the tiles: the weights sum to one."""
    rng = np.random.default_rng(11)
    img = rng.uniform(0, 1, (37, 50, 3))

    def solve(rows, cols):
        return np.sqrt(img[rows, cols])

    for tile, overlap, workers in [(64, 0, 1), (16, 4, 1), (12, 5, 2), (9, 0, 1)]:
        np.testing.assert_allclose(tiled(img.shape[:2], tile, overlap, solve, workers=workers),
                                   np.sqrt(img), atol=1e-12)
    # blend takes results in tile_windows order
    windows = tile_windows(img.shape[:2], 16, 4)
    res = [np.full((r.stop - r.start, c.stop - c.start, 1), 2.0) for r, c in windows]
    np.testing.assert_allclose(blend(img.shape[:2], 16, 4, res), 2.0)
    with pytest.raises(ValueError, match="tile results"):
        blend(img.shape[:2], 16, 4, res[:-1])


def test_tiling_reproduces_the_untiled_result_when_the_input_fits_one_tile():
    stack, _ = _scene(16)
    whole = separate(stack, method="tensor", tile=None)
    for tile in (16, 40):
        one = separate(stack, method="tensor", tile=tile, overlap=4)
        np.testing.assert_array_equal(one.diffuse, whole.diffuse)
        assert one.info["tiles"] == 1 and one.info["tile"] is None


def test_tiled_separation_keeps_the_contract_and_does_not_depend_on_workers():
    stack, D = _scene(24)
    one = separate(stack, method="tensor", tile=12, overlap=4, workers=1)
    two = separate(stack, method="tensor", tile=12, overlap=4, workers=2)
    np.testing.assert_array_equal(one.diffuse, two.diffuse)
    info = one.info
    assert info["tiles"] == 9 and info["tile"] == [12, 12, 4] and len(info["iterations_per_tile"]) == 9
    assert info["iterations"] == max(info["iterations_per_tile"]) == len(info["residuals"])
    mean = stack.mean(axis=0)
    np.testing.assert_allclose(one.diffuse + one.specular, mean, atol=1e-6)
    assert np.all(one.diffuse >= 0) and np.all(one.diffuse <= mean + 1e-6)
    assert np.mean((one.diffuse - D) ** 2) < 0.25 * np.mean((mean - D) ** 2)


def test_fast_ialm_stops_on_the_residual_and_keeps_zero_input():
    rng = np.random.default_rng(12)
    D = np.abs(rng.normal(size=(3, 12, 9)))
    L, S, info = ialm_fast(D, tau=None, lam=0.3, gamma=0.0, tol=1e-4)
    assert L.dtype == np.float32 and info["converged"] and info["residual"] < 1e-4
    assert np.linalg.norm(D - L - S) / np.linalg.norm(D) < 1e-4 * 1.01
    z, _, info0 = ialm_fast(np.zeros((3, 4, 4)), tau=None, lam=0.3, gamma=0.0)
    assert np.all(z == 0) and info0["converged"] and info0["iterations"] == 0
    with pytest.raises(ValueError, match="projection"):
        ialm_fast(D, tau=None, lam=0.3, gamma=1.0)


@pytest.mark.parametrize("bad,match", [({"solver": "magic"}, "solver"), ({"tile": 4}, "tile"),
                                       ({"tile": 16, "overlap": 8}, "overlap"),
                                       ({"workers": 0}, "workers"), ({"precision": "half"}, "precision"),
                                       ({"device": 3}, "device"),
                                       ({"device": "cpu", "solver": "exact"}, "fast solver")])
def test_fast_options_are_checked(bad, match):
    stack, _ = _scene(8)
    if "device" in bad and isinstance(bad["device"], str):
        pytest.importorskip("torch")
    with pytest.raises(MethodError, match=match):
        separate(stack, method="tensor", **bad)


def test_torch_backend_matches_numpy():
    torch = pytest.importorskip("torch")
    from polcam.separation import _torch

    rng = np.random.default_rng(13)
    z = rng.uniform(0, 1, (2, 4, 4 * 5, 3 * 6))
    np.testing.assert_allclose(_torch.phase_project_batch(torch.from_numpy(z), 5, 6).numpy(),
                               np.stack([phase_project_slices(x, 5, 6) for x in z]), atol=1e-12)
    # one tensor problem: the batched torch IALM in float64 = the numpy one with its full path
    stack, _ = _scene(12)
    d = rng.uniform(0, 1, (4, 4, 12, 12, 3))
    Z = unfold_slices(d)
    tau = rng.uniform(0.5, 2, (1,) + Z.shape[1:])
    Ln, _, rn = ialm_fast(Z, tau=tau, lam=0.1, gamma=0.1, project=lambda T: phase_project_slices(T, 12, 12),
                          tol=1e-6, dtype=np.float64, svt_options={"full_fraction": 0.0})
    Lt, rt = _torch.ialm_batch(np.stack([Z, 0.5 * Z]), tau=np.stack([tau, tau]), lam=0.1, gamma=0.1,
                               shape=(12, 12), device="cpu", tol=1e-6, dtype="float64")
    assert rt[0]["iterations"] == rn["iterations"] and rt[0]["converged"]
    np.testing.assert_allclose(Lt[0], Ln, atol=1e-8)
    # each tile is its own problem with its own mu0 = 1.25 / ||D||_2: the iteration is then
    # scale-equivariant, so the tile at half the scale gives half the answer in as many iterations
    assert rt[1]["iterations"] == rt[0]["iterations"] and rt[1]["converged"]
    np.testing.assert_allclose(Lt[1], 0.5 * Lt[0], atol=1e-8)
    assert np.isclose(rt[1]["mu0"], 2 * rt[0]["mu0"])
    # end to end, float32 both
    a = separate(stack, method="tensor")
    b = separate(stack, method="tensor", device="cpu")
    np.testing.assert_allclose(b.diffuse, a.diffuse, atol=1e-2)
    assert b.info["device"] == "cpu"


def test_torch_device_errors():
    from polcam.separation import _torch

    if not _torch.available():
        with pytest.raises(MethodError, match="PyTorch"):
            _torch.check_device("cpu")
        return
    with pytest.raises(MethodError, match="not a torch device"):
        _torch.check_device("nonsense")


def test_tile_plan_keeps_the_exact_solver_whole_and_tiles_large_fast_runs():
    from polcam.separation.tensor import AUTO_TILE, AUTO_UNTILED_PIXELS, _tile_plan

    big = int(np.sqrt(AUTO_UNTILED_PIXELS)) + 1
    assert _tile_plan(big, big, None, 4, "exact") == ((big, big), 0)
    (th, tw), ov = _tile_plan(big, big, None, 4, "fast")
    assert ov == 4 and th <= AUTO_TILE[0] and tw <= AUTO_TILE[1]
    # the automatic tile is the smallest that needs no more tiles than AUTO_TILE does
    for got, most in ((th, AUTO_TILE[0]), (tw, AUTO_TILE[1])):
        assert len(tile_spans(big, got, 4)) == len(tile_spans(big, most, 4))
        assert len(tile_spans(big, got - 1, 4)) > len(tile_spans(big, most, 4))
    assert _tile_plan(big - 1, big - 1, None, 4, "fast") == ((big - 1, big - 1), 0)
    assert _tile_plan(big, big, 32, 4, "exact") == ((32, 32), 4)     # asked for: tiles
    assert _tile_plan(big, big, (48, 16), 4, "fast") == ((48, 16), 4)
    assert _tile_plan(20, big, (48, 16), 4, "fast") == ((20, 16), 4)  # one tile along the short side
    assert _tile_plan(20, 30, (48, 32), 4, "fast") == ((20, 30), 0)   # the whole image
    for bad in [(48,), (48, 4), (48, 16, 2), "48", True, (48.0, 16)]:
        with pytest.raises(MethodError, match="tile"):
            _tile_plan(big, big, bad, 4, "fast")
    with pytest.raises(MethodError, match="overlap"):
        _tile_plan(big, big, (48, 16), 8, "fast")                     # half the narrow side


def test_rectangular_tiles_cover_the_image_and_blend_constants_exactly():
    windows = tile_windows((50, 70), (24, 12), 4)
    cover = np.zeros((50, 70), int)
    for r, c in windows:
        assert (r.stop - r.start, c.stop - c.start) == (24, 12)
        cover[r, c] += 1
    assert cover.min() >= 1
    res = [np.full((24, 12, 3), 0.25) for _ in windows]
    np.testing.assert_allclose(blend((50, 70), (24, 12), 4, res), 0.25)
    stack, D = _scene(24)
    got = separate(stack, method="tensor", tile=(24, 12), overlap=4, workers=1)
    assert got.info["tile"] == [24, 12, 4] and got.info["tiles"] == len(tile_windows((24, 24), (24, 12), 4))
    mean = stack.mean(axis=0)
    assert np.mean((got.diffuse - D) ** 2) < 0.25 * np.mean((mean - D) ** 2)


def test_spectral_norm_of_slices_matches_arpack():
    from polcam.separation.tensor import _spectral_norm, _spectral_norm_slices

    rng = np.random.default_rng(14)
    for shape in [(40, 30, 4), (30, 50, 5), (8, 8, 3), (60, 45, 4)]:
        D = rng.normal(size=shape)
        if shape[0] == 60:
            D = np.abs(D)                                  # a dominant DC slice, as images have
        want = _spectral_norm(D)
        assert _spectral_norm_slices(np.moveaxis(D, 2, 0)) == pytest.approx(want, rel=1e-10)


def test_worker_pools_fork_only_without_threads_and_agree_either_way():
    import sys
    import threading

    from polcam.separation.tensor import _process_context

    stack, _ = _scene(24)
    alone = separate(stack, method="tensor", tile=12, overlap=4, workers=2)
    if sys.version_info < (3, 12):
        assert _process_context().get_start_method() == "fork"
    release = threading.Event()
    other = threading.Thread(target=release.wait, daemon=True)
    other.start()
    try:
        # a running thread (a live view, an application): no fork, the fork server instead,
        # which start_workers starts ahead of the first call
        assert _process_context().get_start_method() == "forkserver"
        from multiprocessing import forkserver

        from polcam.separation.tensor import start_workers

        assert start_workers() == "forkserver" and forkserver._forkserver._forkserver_pid
        with_thread = separate(stack, method="tensor", tile=12, overlap=4, workers=2)
    finally:
        release.set()
        other.join()
    np.testing.assert_array_equal(with_thread.diffuse, alone.diffuse)


def test_initial_diffuse_in_the_background_gives_the_same_answer():
    # from 256 x 256 the four Yang'10 runs of the shared initial diffuse start in worker
    # processes before the representations are found; one worker runs them in turn afterwards
    stack, _ = _scene(256)
    kw = dict(tile=(128, 128), max_iter=3)
    one = separate(stack, method="tensor", workers=1, **kw)
    two = separate(stack, method="tensor", workers=2, **kw)
    np.testing.assert_array_equal(two.diffuse, one.diffuse)
    assert two.info["tiles"] == 9 and two.info["iterations"] == 3
