"""akashi16 (Akashi & Okatani 2016) on synthetic dichromatic images and against its own objective.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation.akashi16 import separate_akashi16, sparse_nmf
from polcam.synth.dichromatic import patch_scene


def objective(data, weights, w, h, lam):
    err = data - w @ h
    return 0.5 * float(((err**2).sum(axis=0) * weights).sum()) + lam * float((h.sum(axis=0) * weights).sum())


def test_sparse_nmf_keeps_the_illuminant_column_and_reports_its_objective():
    rng = np.random.default_rng(0)
    lam_d = rng.dirichlet([1, 1, 1], size=3).T  # 3 diffuse colours
    coef = rng.uniform(0, 1, (3, 200)) * (rng.random((3, 200)) < 0.4)
    data = lam_d @ coef + rng.uniform(0, 0.2, 200) / 3
    weights = rng.integers(1, 4, 200).astype(float)
    h0 = rng.uniform(1, 255, (4, 200)) / 255
    w0 = rng.uniform(1, 255, (3, 3)) / 255
    w, h, info = sparse_nmf(data, weights, h0, w0, lam=0.01, tol=1e-9, max_iter=3000)
    np.testing.assert_allclose(w[:, 0], np.full(3, 1 / np.sqrt(3)))
    np.testing.assert_allclose(np.linalg.norm(w, axis=0), 1.0, rtol=1e-12)
    assert np.all(h >= 0) and np.all(w >= 0)
    assert info["objective"] == pytest.approx(objective(data, weights, w, h, 0.01), rel=1e-10)
    # The factorisation explains the data far better than the zero model.
    assert info["objective"] < 0.2 * objective(data, weights, w, np.zeros_like(h), 0.01)


def test_merging_identical_pixels_equals_the_full_pixel_matrix():
    # Weighted columns for repeated colours are the full algorithm with those pixels
    # started alike: run both and compare.
    rng = np.random.default_rng(1)
    base = rng.uniform(0.05, 0.9, (30, 3))
    idx = rng.integers(0, 30, 120)
    full = base[idx].T
    colours, inverse, counts = np.unique(base[idx], axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    h_col = rng.uniform(1, 255, (4, colours.shape[0])) / 255
    w0 = rng.uniform(1, 255, (3, 3)) / 255
    opts = {"lam": 0.01, "tol": 1e-12, "max_iter": 500}
    w_m, h_m, i_m = sparse_nmf(colours.T.copy(), counts.astype(float), h_col.copy(), w0, **opts)
    w_f, h_f, i_f = sparse_nmf(full.copy(), np.ones(120), h_col[:, inverse].copy(), w0, **opts)
    assert i_m["iterations"] == i_f["iterations"]
    np.testing.assert_allclose(w_m, w_f, atol=1e-12)
    np.testing.assert_allclose(h_m[:, inverse], h_f, atol=1e-10)


def test_start_is_the_per_pixel_draw_averaged_over_identical_pixels():
    # Rebuild the method from its documented start on the full pixel matrix.
    rng = np.random.default_rng(2)
    image = rng.uniform(0.05, 0.95, (6, 5, 3))
    image[3:, :] = image[0, 0]  # 16 identical pixels with (0, 0)
    pixels = image.reshape(-1, 3)
    draw = np.random.default_rng(11)
    per_pixel = draw.uniform(1, 255, (7, 30)) / 255
    w0 = draw.uniform(1, 255, (3, 6)) / 255
    same = np.all(pixels == pixels[0], axis=1)
    per_pixel[:, same] = per_pixel[:, same].mean(axis=1, keepdims=True)
    w, h, _ = sparse_nmf(pixels.T.copy(), np.ones(30), per_pixel, w0, lam=3 / 255, tol=1e-300, max_iter=100)
    expected = np.clip((w[:, 1:] @ h[1:]).T.reshape(6, 5, 3), 0, image)
    out, info = separate_akashi16(image, seed=11, tol=1e-300, max_iter=100)
    np.testing.assert_allclose(out, expected, atol=1e-9)
    assert info["colours"] == 15


def test_recovers_synthetic_diffuse_layer():
    image, diffuse = patch_scene()
    before = psnr(image, diffuse)
    assert before < 31.0
    for seed in (0, 1):
        out, info = separate_akashi16(image, seed=seed)
        # Random start and the l1 shrinkage of H: not exact, but well above the input
        # (36.8 to 46.8 dB over seeds 0-4 when written).
        assert psnr(np.clip(out, 0, 1), diffuse) > 35.0
        assert info["converged"] and 0 < info["iterations"] < 10000


def test_seeded_runs_repeat_and_seeds_differ():
    image, _ = patch_scene(h=16, w=20, margin=2)
    a, ia = separate_akashi16(image, seed=7, max_iter=300)
    b, ib = separate_akashi16(image, seed=7, max_iter=300)
    c, _ = separate_akashi16(image, seed=8, max_iter=300)
    np.testing.assert_array_equal(a, b)
    assert ia == ib
    assert np.abs(a - c).max() > 1e-6


def test_restarts_keep_the_lowest_objective():
    image, _ = patch_scene(h=16, w=20, margin=2)
    _, one = separate_akashi16(image, seed=3, max_iter=200)
    _, three = separate_akashi16(image, seed=3, max_iter=200, restarts=3)
    assert three["objective"] <= one["objective"]
    assert three["restarts"] == 3


def test_iteration_bound_reports_no_convergence():
    image, _ = patch_scene(h=16, w=20, margin=2)
    _, info = separate_akashi16(image, max_iter=5)
    assert info["iterations"] == 5 and not info["converged"]


@pytest.mark.parametrize(
    "image",
    [np.zeros((6, 7, 3)), np.full((6, 7, 3), 0.5), np.ones((6, 7, 3)), np.full((4, 4, 3), 0.02)],
    ids=["black", "grey", "white", "dark"],
)
def test_degenerate_images_stay_finite_and_bounded(image):
    out, info = separate_akashi16(image, max_iter=500)
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)
    assert np.isfinite(info["objective"])


@pytest.mark.parametrize("lam", [0.0, 3 / 255])
def test_black_image_gives_black_and_converges(lam):
    out, info = separate_akashi16(np.zeros((3, 3, 3)), lam=lam, max_iter=50)
    np.testing.assert_array_equal(out, 0.0)
    assert info["converged"] and info["objective"] == 0.0


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_akashi16(np.zeros((4, 4)))
    with pytest.raises(MethodError, match="dtype"):
        separate_akashi16(np.zeros((4, 4, 3), dtype=np.uint16))
    good = np.full((4, 4, 3), 0.5)
    with pytest.raises(MethodError, match="n_diffuse"):
        separate_akashi16(good, n_diffuse=0)
    with pytest.raises(MethodError, match="seed"):
        separate_akashi16(good, seed=-1)
    with pytest.raises(MethodError, match="lam"):
        separate_akashi16(good, lam=np.nan)
    with pytest.raises(MethodError, match="tol"):
        separate_akashi16(good, tol=0)
    with pytest.raises(MethodError, match="restarts"):
        separate_akashi16(good, restarts=1.5)
