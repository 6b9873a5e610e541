"""tan05 (Tan & Ikeuchi 2005) against closed forms and synthetic dichromatic images.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation.tan05 import separate_tan05, shift_max_chromaticity, specular_free_image
from polcam.synth.dichromatic import patch_scene


def test_shift_to_true_max_chromaticity_gives_the_diffuse_pixel():
    # eq. 11: I = m_d Lambda + m_s / 3; shifting to Lambda_max recovers m_d Lambda exactly.
    rng = np.random.default_rng(0)
    lam = rng.dirichlet([2, 2, 2], size=50)
    m_d = rng.uniform(0.1, 0.8, 50)
    m_s = rng.uniform(0.0, 0.5, 50)
    pixels = m_d[:, None] * lam + m_s[:, None] / 3
    out = shift_max_chromaticity(pixels, lam.max(axis=1))
    np.testing.assert_allclose(out, m_d[:, None] * lam, atol=1e-12)


def test_specular_free_total_is_proportional_to_the_diffuse_weight():
    # Sec. 4: the specular-free image's total intensity is m_d (3 Lambda_max - 1) / (3 L_sf - 1),
    # whatever the specular weight.
    lam = np.array([0.6, 0.3, 0.1])
    m_d = np.array([0.2, 0.5, 0.7])
    m_s = np.array([0.0, 0.3, 0.1])
    image = (m_d[:, None] * lam + m_s[:, None] / 3)[None]
    sf = specular_free_image(image, sf_max_chromaticity=0.5)
    np.testing.assert_allclose(sf.sum(axis=-1)[0], m_d * (3 * 0.6 - 1) / (3 * 0.5 - 1), rtol=1e-12)


def test_two_pixels_of_one_colour():
    # A diffuse pixel beside a specular pixel of the same diffuse colour: the specular
    # one is shifted to the diffuse pixel's maximum chromaticity, i.e. made diffuse.
    lam = np.array([0.6, 0.3, 0.1])
    diffuse = np.stack([0.8 * lam, 0.7 * lam])[None]
    image = diffuse.copy()
    image[0, 1] += 0.15 / 3
    out, info = separate_tan05(image)
    np.testing.assert_allclose(out, diffuse, atol=1e-12)
    assert info["converged"]


def test_diffuse_image_is_left_unchanged():
    _, diffuse = patch_scene(peak=0.0)
    out, info = separate_tan05(diffuse)
    np.testing.assert_array_equal(out, diffuse)
    assert info["converged"] and info["remaining"] == 0


def test_colour_boundary_is_left_alone():
    image = np.array([[[0.5, 0.2, 0.1], [0.1, 0.5, 0.3]]])
    out, _ = separate_tan05(image)
    np.testing.assert_array_equal(out, image)


def test_recovers_synthetic_diffuse_layer():
    image, diffuse = patch_scene()
    before = psnr(image, diffuse)
    out, info = separate_tan05(image)
    after = psnr(np.clip(out, 0, 1), diffuse)
    # Exact in theory; the noise threshold (pairs whose maximum chromaticities differ
    # by < 0.01 are left alone) leaves the faint tails of the lobes.
    assert before < 31.0
    assert after > 40.0
    assert info["converged"]
    assert np.all(out <= image + 1e-12) and np.all(out >= 0)


@pytest.mark.parametrize(
    "image",
    [
        np.zeros((6, 7, 3)),  # all black
        np.full((6, 7, 3), 0.5),  # grey: achromatic, undetermined
        np.ones((6, 7, 3)),  # saturated white
        np.array([[[0.06, 0.03, 0.01], [0.07, 0.04, 0.02]]]),  # dark: every channel < 20/255
    ],
    ids=["black", "grey", "white", "dark"],
)
def test_degenerate_images_are_returned_unchanged(image):
    out, info = separate_tan05(image)
    np.testing.assert_array_equal(out, image)
    assert info["converged"]


def test_saturated_and_dark_pixels_stay_finite_and_bounded():
    image, _ = patch_scene(h=24, w=32, margin=4, peak=1.5)
    image = np.clip(image, 0, 1)  # clipped highlights
    image[:3] = np.array([0.07, 0.03, 0.01]) + np.linspace(0, 0.005, 32)[:, None]  # dark rows
    out, _ = separate_tan05(image)
    assert np.all(np.isfinite(out))
    assert np.all(out >= 0) and np.all(out <= image)
    np.testing.assert_array_equal(out[:3], image[:3])  # dark pixels are never processed


def test_sweep_bound_reports_no_convergence():
    image, _ = patch_scene(h=24, w=32, margin=4)
    _, info = separate_tan05(image, max_sweeps=1)
    assert info["iterations"] == 1 and not info["converged"]


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_tan05(np.zeros((4, 4)))
    with pytest.raises(MethodError, match="dtype"):
        separate_tan05(np.zeros((4, 4, 3), dtype=np.uint8))
    with pytest.raises(MethodError, match="NaN"):
        separate_tan05(np.full((4, 4, 3), np.nan))
    with pytest.raises(MethodError, match=r"\[0, 1\]"):
        separate_tan05(np.full((4, 4, 3), 2.0))
    good = np.full((4, 4, 3), 0.5)
    with pytest.raises(MethodError, match="epsilon_step"):
        separate_tan05(good, epsilon_step=0)
    with pytest.raises(MethodError, match="sf_max_chromaticity"):
        separate_tan05(good, sf_max_chromaticity=0.3)
    with pytest.raises(MethodError, match="max_sweeps"):
        separate_tan05(good, max_sweeps=0)
    with pytest.raises(MethodError, match="chroma_threshold"):
        separate_tan05(good, chroma_threshold=-0.1)
    with pytest.raises(MethodError, match="noise_threshold"):
        separate_tan05(good, noise_threshold=np.nan)
