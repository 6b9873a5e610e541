"""yoon06 (Yoon, Choi & Kweon 2006) against a literal run of the paper's iteration and synthetic images.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation.yoon06 import separate_yoon06
from polcam.synth.dichromatic import patch_scene


def literal_iteration(image: np.ndarray, chroma_threshold: float, dark_threshold: float) -> np.ndarray:
    """The paper's pair rule applied pixel by pixel, in raster order, until nothing changes.

    Each pixel is compared with the pixel below (the default ``direction``).
    """
    out = image.copy()
    h, w, _ = out.shape
    sf = out - out.min(axis=-1, keepdims=True)  # unchanged by the updates
    s = sf.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        chroma = sf / s[..., None]
    usable = (s > 0) & (out.min(axis=-1) >= dark_threshold)
    for _ in range(10 * h * w):
        changed = False
        for i in range(h - 1):
            for j in range(w):
                a, b = (i, j), (i + 1, j)
                if not (usable[a] and usable[b]):
                    continue
                if np.any(np.abs(chroma[a][:2] - chroma[b][:2]) > chroma_threshold):
                    continue
                r_d = s[a] / s[b]
                ta, tb = out[a].sum(), out[b].sum()
                if ta / tb > r_d:
                    m = ta - r_d * tb
                    if m > 1e-13:
                        out[a] -= m / 3
                        changed = True
                elif ta / tb < r_d:
                    m = tb - ta / r_d
                    if m > 1e-13:
                        out[b] -= m / 3
                        changed = True
        if not changed:
            return out
    raise AssertionError("the literal iteration did not converge")


def test_equals_the_literal_iteration():
    # Random dichromatic pixels of three colours, in vertical stripes with interruptions,
    # varying shading and random specular weights: the closed-form fixed point must equal
    # the pixel-by-pixel iteration run to convergence.
    rng = np.random.default_rng(0)
    h, w = 14, 9
    lam = np.array([[0.6, 0.3, 0.1], [0.2, 0.5, 0.3], [0.15, 0.25, 0.6]])
    labels = rng.integers(0, 3, size=(h, w))
    m_d = rng.uniform(0.3, 0.9, (h, w))
    m_s = rng.uniform(0.0, 0.3, (h, w)) * (rng.random((h, w)) < 0.5)
    image = m_d[..., None] * lam[labels] + m_s[..., None] / 3
    image[3, :] *= 0.1  # a dark row cutting the chains
    expected = literal_iteration(image, 0.05, 12 / 255)
    out, info = separate_yoon06(image)
    np.testing.assert_allclose(out, expected, atol=1e-12)
    assert info["converged"]


def test_recovers_synthetic_diffuse_layer():
    image, diffuse = patch_scene()
    before = psnr(image, diffuse)
    out, _ = separate_yoon06(image)
    # Every column through a lobe also crosses diffuse pixels of the same colour, whose
    # ratio T / S is the true diffuse one: the fixed point is exact there.
    assert before < 31.0
    assert psnr(np.clip(out, 0, 1), diffuse) > 60.0


def test_horizontal_is_vertical_on_the_transposed_image():
    image, _ = patch_scene(h=32, w=40, margin=4)
    vertical, _ = separate_yoon06(image, direction="vertical")
    horizontal_t, _ = separate_yoon06(image.transpose(1, 0, 2).copy(), direction="horizontal")
    np.testing.assert_allclose(horizontal_t.transpose(1, 0, 2), vertical, atol=1e-15)


def test_both_directions_propagate_across_columns():
    # One colour; the specular pixel sits in a column without diffuse pixels of its
    # own, so only the horizontal link reaches the diffuse ratio.
    lam = np.array([0.6, 0.3, 0.1])
    m_d = np.array([[0.5, 0.6], [0.7, 0.8]])
    image = m_d[..., None] * lam
    image[:, 1] += 0.1 / 3  # whole right column specular
    diffuse = m_d[..., None] * lam
    both, _ = separate_yoon06(image, direction="both")
    vertical, _ = separate_yoon06(image, direction="vertical")
    np.testing.assert_allclose(both, diffuse, atol=1e-12)
    assert np.abs(vertical - diffuse).max() > 0.01


def test_colour_discontinuity_blocks_the_ratio():
    a = np.array([0.6, 0.3, 0.1]) * 0.8
    b = np.array([0.1, 0.3, 0.6]) * 0.5 + 0.1 / 3  # other colour, specular
    image = np.stack([a, b])[:, None, :]  # one column, two rows
    out, _ = separate_yoon06(image)
    np.testing.assert_array_equal(out, image)


@pytest.mark.parametrize(
    "image",
    [
        np.zeros((6, 7, 3)),
        np.full((6, 7, 3), 0.5),
        np.ones((6, 7, 3)),
        np.array([[[0.04, 0.03, 0.01]], [[0.05, 0.04, 0.02]]]),  # min channel < 12/255
    ],
    ids=["black", "grey", "white", "dark"],
)
def test_degenerate_images_are_returned_unchanged(image):
    out, _ = separate_yoon06(image)
    np.testing.assert_array_equal(out, image)


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_yoon06(np.zeros((4, 4)))
    with pytest.raises(MethodError, match="dtype"):
        separate_yoon06(np.zeros((4, 4, 3), dtype=np.int16))
    with pytest.raises(MethodError, match="NaN"):
        separate_yoon06(np.full((4, 4, 3), np.inf))
    good = np.full((4, 4, 3), 0.5)
    with pytest.raises(MethodError, match="direction"):
        separate_yoon06(good, direction="diagonal")
    with pytest.raises(MethodError, match="chroma_threshold"):
        separate_yoon06(good, chroma_threshold=2.0)
    with pytest.raises(MethodError, match="dark_threshold"):
        separate_yoon06(good, dark_threshold=-1)
    with pytest.raises(MethodError, match="chroma_threshold=nan"):
        separate_yoon06(good, chroma_threshold=np.nan)
    with pytest.raises(MethodError, match="dark_threshold=True"):
        separate_yoon06(good, dark_threshold=True)
