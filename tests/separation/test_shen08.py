"""shen08 (Shen, Zhang, Shao & Xin 2008) against closed forms and synthetic dichromatic images."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation._registry import method_spec, separate
from polcam.separation.shen08 import modified_specular_free, separate_shen08

COLOURS = np.array([[0.65, 0.25, 0.10], [0.10, 0.60, 0.30], [0.30, 0.10, 0.60], [0.50, 0.40, 0.10]])


def synthetic(h: int = 48, w: int = 64, margin: int = 8, peak: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Dichromatic image under a white illuminant with known diffuse layer.

    A 2 x 2 block of patches on black (the black margin keeps the mean minimum
    channel, the method's threshold, low as in its test scenes); each patch has
    diffuse chromaticity ``COLOURS[k]``, a smooth shading ``m_d = 0.9 (1 - 0.8
    r^2)`` and a white Gaussian specular lobe (peak ``m_s = peak``, sigma 2.5
    px) away from the shading maximum: ``I = m_d Lambda + m_s / 3``.
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


def test_registered_as_single_image_method():
    spec = method_spec("shen08")
    assert spec.kind == "single" and not spec.mono
    assert "Shen" in spec.reference and "2008" in spec.reference


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
    image, diffuse = synthetic()
    before = psnr(image, diffuse)
    out, info = separate_shen08(image)
    # Body colours come from the brightest diffuse-class pixels; a few of them lie in a
    # lobe's faint tail, whose specular part then stays in their cluster.
    assert before < 31.0
    assert psnr(out, diffuse) > 40.0
    assert info["converged"]


def test_scale_contract_through_dispatcher_with_a_stack():
    image, _ = synthetic(h=24, w=32, margin=4)
    rng = np.random.default_rng(3)
    stack = np.clip(image[None] * rng.uniform(0.9, 1.1, (4, 1, 1, 1)), 0, 1)
    res = separate(stack, method="shen08")
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (24, 32, 3) and res.diffuse.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    assert res.specular.sum() > 0.01
    assert res.info["method"] == "shen08" and {"iterations", "converged"} <= res.info.keys()


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


def test_saturated_pixels_stay_bounded():
    image, _ = synthetic(h=24, w=32, margin=4, peak=1.5)
    image = np.clip(image, 0, 1)
    out, _ = separate_shen08(image)
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 9, 3), (9, 1, 3)])
def test_thin_images(shape):
    image = np.random.default_rng(4).uniform(0.1, 0.9, shape)
    out, _ = separate_shen08(image)
    assert out.shape == shape and np.all(out >= 0) and np.all(out <= image)


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


@pytest.mark.slow
def test_fidelity_on_shen2013(shared_data):
    from polcam.bench.sihr import run

    (row,) = run(shared_data / "shen2013", ["shen08"])
    assert row["deviation"] < 1.0
