"""shen08 (Shen, Zhang, Shao & Xin 2008) against closed forms and synthetic dichromatic images.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation.shen08 import modified_specular_free, separate_shen08
from polcam.synth.dichromatic import patch_scene


def test_modified_specular_free_image():
    image = np.array([[[0.5, 0.2, 0.1], [0.3, 0.3, 0.6]]])
    tau = (0.1 + 0.3) / 2
    expected = image - np.array([0.1, 0.3])[None, :, None] + tau
    np.testing.assert_allclose(modified_specular_free(image), expected, atol=1e-15)
    np.testing.assert_allclose(modified_specular_free(image, 0.0).min(axis=-1), 0.0, atol=1e-15)


def test_exact_on_one_colour():
    # Pixels of one diffuse colour: diffuse ones (small minimum channel) and specular
    # ones (minimum channel above twice the image mean).  The brightest diffuse pixel is
    # the body colour and every pixel is I = alpha B + beta (1, 1, 1) exactly.
    lam = np.array([0.7, 0.25, 0.05])
    m_d = np.linspace(0.3, 0.9, 12)
    m_s = np.zeros(12)
    m_s[[2, 5, 6]] = [0.6, 0.9, 0.75]
    image = (m_d[:, None] * lam + m_s[:, None] / 3)[None]
    out, info = separate_shen08(image)
    np.testing.assert_allclose(out[0], m_d[:, None] * lam, atol=1e-12)
    assert info["converged"] and info["unprocessed"] == 0


def test_recovers_synthetic_diffuse_layer():
    image, diffuse = patch_scene()
    before = psnr(image, diffuse)
    out, info = separate_shen08(image)
    # Body colours come from the brightest diffuse-class pixels; a few of them lie in a
    # lobe's faint tail, whose specular part then stays in their cluster.
    assert before < 31.0
    assert psnr(np.clip(out, 0, 1), diffuse) > 40.0
    assert info["converged"]


def test_without_diffuse_pixels_combined_pixels_are_left_unchanged():
    # 60 % black (dark, not diffuse candidates), 40 % bright pixels whose minimum
    # channel is above twice the mean: every bright pixel is "combined", no body colour.
    image = np.zeros((10, 10, 3))
    image[:4] = [0.9, 0.6, 0.5]
    out, info = separate_shen08(image)
    np.testing.assert_array_equal(out, image)
    assert info["unprocessed"] == 40 and not info["converged"]


@pytest.mark.parametrize(
    "image",
    [np.zeros((6, 7, 3)), np.full((6, 7, 3), 0.5), np.ones((6, 7, 3)), np.full((4, 4, 3), 0.05)],
    ids=["black", "grey", "white", "dark"],
)
def test_degenerate_images(image):
    out, _ = separate_shen08(image)
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)
    if image.max() <= 20 / 255:
        np.testing.assert_array_equal(out, image)  # too dark to be a diffuse candidate


def test_uniform_grey_is_unchanged():
    # One achromatic colour: the body colour is the pixel itself, alpha = 1.
    image = np.full((5, 6, 3), 0.4)
    out, _ = separate_shen08(image)
    np.testing.assert_allclose(out, image, atol=1e-12)


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_shen08(np.zeros((4, 4, 2)))
    with pytest.raises(MethodError, match="dtype"):
        separate_shen08(np.zeros((4, 4, 3), dtype=np.int64))
    with pytest.raises(MethodError, match=r"\[0, 1\]"):
        separate_shen08(np.full((4, 4, 3), -0.5))
    good = np.full((4, 4, 3), 0.5)
    with pytest.raises(MethodError, match="chroma_threshold"):
        separate_shen08(good, chroma_threshold=0)
    with pytest.raises(MethodError, match="dark_threshold"):
        separate_shen08(good, dark_threshold=1.5)
    with pytest.raises(MethodError, match="chroma_threshold=nan"):
        separate_shen08(good, chroma_threshold=np.nan)
    with pytest.raises(MethodError, match="dark_threshold=True"):
        separate_shen08(good, dark_threshold=True)
