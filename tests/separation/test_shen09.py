"""shen09 (Shen & Cai, Applied Optics 2009) on synthetic dichromatic scenes with known diffuse."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation import separate
from polcam.separation.shen09 import separate_shen09


def dichromatic_scene(h=64, w=96, spec_peak=0.6, colours=((0.9, 0.05, 0.05), (0.1, 0.45, 0.45))):
    """Vertical bands of diffuse colours with smooth shading, one white specular lobe per band.

    The lobes are Gaussian (sigma 5 px) cut to zero beyond 3 sigma.

    Returns the image ``m_d Lambda + m_s / 3`` (white illuminant) and its diffuse layer.
    """
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    n = len(colours)
    band = np.minimum((xx * n // w).astype(int), n - 1)
    lam = np.asarray(colours, dtype=float)[band]
    bw = w / n
    shade = 0.55 + 0.35 * np.cos(np.pi * (yy - h / 2) / h) * np.cos(np.pi * (xx % bw - bw / 2) / (2 * bw))
    diffuse = shade[..., None] * lam
    ms = np.zeros((h, w))
    for i in range(n):
        cy, cx = h * (0.4 + 0.2 * (i % 2)), bw * (i + 0.5)
        r2 = (yy - cy) ** 2 + (xx - cx) ** 2
        ms += np.where(r2 < 15.0**2, spec_peak * np.exp(-r2 / (2 * 5.0**2)), 0.0)  # lobe cut at 3 sigma
    return diffuse + ms[..., None] / 3, diffuse


def psnr(x, ref):
    return 10 * np.log10(1.0 / np.mean((np.asarray(x, float) - ref) ** 2))


def polarization_stack(image, diffuse):
    """Four angle images whose mean is ``image``: the specular part varies with the angle."""
    t = np.deg2rad([0, 45, 90, 135])[:, None, None, None]
    return diffuse[None] + (image - diffuse)[None] * (1 + 0.8 * np.cos(2 * t - 0.6))


EDGE_CASES = [
    ("zeros", np.zeros((9, 11, 3))),
    ("white", np.ones((9, 11, 3))),
    ("grey", np.repeat(np.linspace(0.1, 0.9, 99).reshape(9, 11, 1), 3, axis=2)),
    ("one pixel", np.array([[[0.6, 0.3, 0.1]]])),
    ("one row", np.linspace(0, 1, 21).reshape(1, 7, 3)),
    ("one column", np.linspace(0, 1, 21).reshape(7, 1, 3)),
    ("single channel", np.stack([np.linspace(0, 1, 99).reshape(9, 11), np.zeros((9, 11)),
                                 np.zeros((9, 11))], axis=-1)),
    ("tiny values", np.full((9, 11, 3), 1e-12) * np.array([1.0, 2.0, 3.0])),
    ("saturated", np.clip(dichromatic_scene(spec_peak=3.0)[0], 0, 1)),
    ("dark noise", np.random.default_rng(5).uniform(0, 0.03, (20, 24, 3))),
]


def test_single_material():
    image, diffuse = dichromatic_scene(colours=((0.6, 0.3, 0.1),))
    out, info = separate_shen09(image)
    assert not info["fallback"]
    assert psnr(image, diffuse) < 34
    assert psnr(out, diffuse) > 48  # measured 53.0 dB


def test_two_materials():
    image, diffuse = dichromatic_scene()
    out, info = separate_shen09(image)
    assert psnr(out, diffuse) > psnr(image, diffuse) + 8  # measured 40.2 dB against 29.9


def test_threshold_and_pseudo_specular_closed_form():
    # with k = 1 the result is the MSF image: I - max(I_min - T, 0), T = mean + nu std of I_min
    image, _ = dichromatic_scene()
    i_min = image.min(axis=-1)
    t = i_min.mean() + 0.5 * i_min.std()
    out, info = separate_shen09(image)
    assert info["threshold"] == pytest.approx(t, rel=1e-12)
    beta = np.maximum(i_min - t, 0)
    np.testing.assert_allclose(out, np.clip(image - info["k"] * beta[..., None], 0, image), atol=1e-12)
    # untouched below the threshold
    np.testing.assert_array_equal(out[i_min <= t], image[i_min <= t])


def test_scale_from_the_boundary():
    # a highlight whose pseudo specular term is a known fraction of the true one:
    # flat diffuse (I_min = T everywhere but the lobe), so beta = m_s / 3 exactly, k = 1
    h, w = 40, 50
    yy, xx = np.mgrid[0:h, 0:w]
    diffuse = np.broadcast_to(np.array([0.5, 0.3, 0.2]), (h, w, 3)).copy()
    ms = 0.6 * np.exp(-((yy - 20) ** 2 + (xx - 25) ** 2) / (2 * 4.0**2))
    image = diffuse + ms[..., None] / 3
    out, info = separate_shen09(image, nu=0.0)
    # T is the mean of I_min, slightly above the diffuse minimum 0.2: k compensates on the boundary
    assert not info["fallback"] and 0.5 < info["k"] < 1.5
    assert psnr(out, diffuse) > psnr(image, diffuse) + 10


def test_no_highlight_falls_back_and_keeps_the_image():
    flat = np.full((10, 12, 3), 0.4) * np.array([1.0, 0.5, 0.25])
    out, info = separate_shen09(flat)
    assert info["fallback"] and info["k"] == 1.0
    np.testing.assert_array_equal(out, flat)


def test_scale_contract_through_the_dispatcher():
    image, diffuse = dichromatic_scene(spec_peak=0.3)
    stack = polarization_stack(image, diffuse)
    res = separate(stack, method="shen09")
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (64, 96, 3) and res.diffuse.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    assert res.info["method"] == "shen09" and "k" in res.info


def test_deterministic():
    image, _ = dichromatic_scene()
    np.testing.assert_array_equal(separate_shen09(image)[0], separate_shen09(image.copy())[0])


@pytest.mark.parametrize("name, image", EDGE_CASES)
def test_edge_cases_are_finite_and_in_range(name, image):
    out, _ = separate_shen09(image)
    assert out.shape == image.shape and out.dtype == np.float64
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_shen09(np.zeros((3, 3)))
    with pytest.raises(MethodError, match="dtype"):
        separate_shen09(np.zeros((3, 3, 3), dtype=np.int32))
    with pytest.raises(MethodError, match="nu"):
        separate_shen09(np.full((3, 3, 3), 0.5), nu=-1)
    with pytest.raises(MethodError, match="region_threshold"):
        separate_shen09(np.full((3, 3, 3), 0.5), region_threshold=1.0)
    with pytest.raises(MethodError, match="ring"):
        separate_shen09(np.full((3, 3, 3), 0.5), ring=4)


@pytest.mark.slow
def test_fidelity_on_shen2013(shared_data):
    from polcam.bench.sihr import run

    (row,) = run(shared_data / "shen2013", ["shen09"])
    assert row["deviation"] < 1.0
