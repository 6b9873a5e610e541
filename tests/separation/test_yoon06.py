"""yoon06 (Yoon, Choi & Kweon 2006) against a literal run of the paper's iteration and synthetic images."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation._registry import method_spec, separate
from polcam.separation.yoon06 import separate_yoon06

COLOURS = np.array([[0.65, 0.25, 0.10], [0.10, 0.60, 0.30], [0.30, 0.10, 0.60], [0.50, 0.40, 0.10]])


def synthetic(h: int = 48, w: int = 64, margin: int = 8, peak: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Dichromatic image under a white illuminant with known diffuse layer.

    A 2 x 2 block of patches on black; each patch has diffuse chromaticity
    ``COLOURS[k]``, a smooth shading ``m_d = 0.9 (1 - 0.8 r^2)`` and a white
    Gaussian specular lobe (peak ``m_s = peak``, sigma 2.5 px):
    ``I = m_d Lambda + m_s / 3``.
    """
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    diffuse = np.zeros((h, w, 3))
    spec = np.zeros((h, w))
    hh, hw = (h - 2 * margin) // 2, (w - 2 * margin) // 2
    origins = [(margin, margin), (margin, margin + hw), (margin + hh, margin), (margin + hh, margin + hw)]
    for k, (y0, x0) in enumerate(origins):
        sl = (slice(y0, y0 + hh), slice(x0, x0 + hw))
        cy, cx = y0 + hh / 2, x0 + hw / 2
        r2 = ((yy[sl] - cy) / hh) ** 2 + ((xx[sl] - cx) / hw) ** 2
        diffuse[sl] = (0.9 * (1.0 - 0.8 * r2))[..., None] * COLOURS[k]
        sy, sx = cy - hh / 5, cx + hw / 5
        spec[sl] = peak * np.exp(-((yy[sl] - sy) ** 2 + (xx[sl] - sx) ** 2) / (2 * 2.5**2))
    return diffuse + spec[..., None] / 3.0, diffuse


def psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    mse = float(np.mean((np.clip(estimate, 0, 1) - truth) ** 2))
    return 10 * np.log10(1 / mse)


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


def test_registered_as_single_image_method():
    spec = method_spec("yoon06")
    assert spec.kind == "single" and not spec.mono
    assert "Yoon" in spec.reference and "2006" in spec.reference


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
    image, diffuse = synthetic()
    before = psnr(image, diffuse)
    out, _ = separate_yoon06(image)
    # Every column through a lobe also crosses diffuse pixels of the same colour, whose
    # ratio T / S is the true diffuse one: the fixed point is exact there.
    assert before < 31.0
    assert psnr(out, diffuse) > 60.0


def test_horizontal_is_vertical_on_the_transposed_image():
    image, _ = synthetic(h=32, w=40, margin=4)
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


def test_scale_contract_through_dispatcher_with_a_stack():
    image, _ = synthetic(h=24, w=32, margin=4)
    rng = np.random.default_rng(3)
    stack = np.clip(image[None] * rng.uniform(0.9, 1.1, (4, 1, 1, 1)), 0, 1)
    res = separate(stack, method="yoon06")
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (24, 32, 3) and res.diffuse.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    assert res.specular.sum() > 0.01
    assert res.info["method"] == "yoon06" and res.info["converged"]


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


def test_saturated_pixels_stay_bounded():
    image, _ = synthetic(h=24, w=32, margin=4, peak=1.5)
    image = np.clip(image, 0, 1)
    out, _ = separate_yoon06(image)
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 9, 3), (9, 1, 3)])
def test_thin_images(shape):
    image = np.random.default_rng(4).uniform(0.1, 0.9, shape)
    for direction in ("vertical", "horizontal", "both"):
        out, _ = separate_yoon06(image, direction=direction)
        assert out.shape == shape and np.all(out >= 0) and np.all(out <= image)


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


@pytest.mark.slow
def test_fidelity_on_shen2013(shared_data):
    from polcam.bench.sihr import run

    (row,) = run(shared_data / "shen2013", ["yoon06"])
    assert row["deviation"] < 1.0
