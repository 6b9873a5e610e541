"""yang10 (Yang, Wang & Ahuja, ECCV 2010) on synthetic dichromatic scenes with known diffuse."""

from __future__ import annotations


import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation import separate
from polcam.separation.yang10 import max_diffuse_chromaticity, separate_yang10


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


def test_recovers_the_diffuse_layer_of_two_materials():
    image, diffuse = dichromatic_scene()
    out, info = separate_yang10(image)
    assert psnr(image, diffuse) < 31
    assert psnr(out, diffuse) > 48  # measured 53.0 dB
    assert info["converged"] and 1 <= info["iterations"] <= 10


def test_max_diffuse_chromaticity_estimate():
    image, _ = dichromatic_scene()
    lam, bright, info = max_diffuse_chromaticity(image)
    truth = np.where(np.arange(96)[None, :] < 48, 0.9, 0.45) * np.ones((64, 1))
    assert bright.all()
    assert np.abs(lam - truth).max() < 0.02
    assert info["converged"]


def test_single_material_is_nearly_exact():
    image, diffuse = dichromatic_scene(colours=((0.6, 0.3, 0.1),))
    out, _ = separate_yang10(image)
    assert psnr(out, diffuse) > 55  # measured 58.7 dB


def test_without_highlight_nothing_changes_much():
    _, diffuse = dichromatic_scene()
    out, _ = separate_yang10(diffuse)
    assert psnr(out, diffuse) > 55


def test_dark_pixels_are_left_unchanged():
    image, diffuse = dichromatic_scene()
    padded = np.pad(image, ((8, 8), (8, 8), (0, 0)))
    rng = np.random.default_rng(0)
    padded[:8] = rng.uniform(0.0, 0.06, (8, padded.shape[1], 3))  # dark, chromatically noisy border
    out, _ = separate_yang10(padded)
    np.testing.assert_array_equal(out[:8], padded[:8])
    assert psnr(out[8:-8, 8:-8], diffuse) > 48
    # dark=0 processes them: noise pixels of similar lambda_max share their sigma_max
    out0, _ = separate_yang10(padded, dark=0.0)
    assert np.any(out0[:8] < padded[:8])


def test_iteration_bound():
    image, diffuse = dichromatic_scene()
    out, info = separate_yang10(image, max_iter=1)
    assert info == {"iterations": 1, "converged": False}
    assert psnr(out, diffuse) < psnr(separate_yang10(image)[0], diffuse)


def test_scale_contract_through_the_dispatcher():
    image, diffuse = dichromatic_scene(spec_peak=0.3)
    # a polarization stack whose mean is the image: the specular lobe varies with the angle
    t = np.deg2rad([0, 45, 90, 135])[:, None, None, None]
    spec = image - diffuse
    stack = diffuse[None] + spec[None] * (1 + 0.8 * np.cos(2 * t - 0.6))
    res = separate(stack, method="yang10")
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (64, 96, 3) and res.diffuse.dtype == np.float32
    assert res.specular.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    assert res.info["method"] == "yang10" and "iterations" in res.info and "converged" in res.info
    assert psnr(res.diffuse, diffuse) > 45


def test_deterministic():
    image, _ = dichromatic_scene(h=32, w=40)
    a, _ = separate_yang10(image)
    b, _ = separate_yang10(image.copy())
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "name, image",
    [
        ("zeros", np.zeros((9, 11, 3))),
        ("white", np.ones((9, 11, 3))),
        ("grey", np.repeat(np.linspace(0.1, 0.9, 99).reshape(9, 11, 1), 3, axis=2)),
        ("one pixel", np.array([[[0.6, 0.3, 0.1]]])),
        ("one row", np.linspace(0, 1, 21).reshape(1, 7, 3)),
        ("single channel", np.stack([np.linspace(0, 1, 99).reshape(9, 11), np.zeros((9, 11)),
                                     np.zeros((9, 11))], axis=-1)),
        ("tiny values", np.full((9, 11, 3), 1e-12) * np.array([1.0, 2.0, 3.0])),
    ],
)
def test_edge_cases_are_finite_and_in_range(name, image):
    out, _ = separate_yang10(image)
    assert out.shape == image.shape and out.dtype == np.float64
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


def test_achromatic_surface_is_kept():
    grey = np.repeat(np.linspace(0.1, 0.9, 99).reshape(9, 11, 1), 3, axis=2)
    np.testing.assert_array_equal(separate_yang10(grey)[0], grey)


def test_saturated_highlight_on_a_coloured_surface():
    image, diffuse = dichromatic_scene(spec_peak=2.0)
    clipped = np.clip(image, 0.0, 1.0)
    out, _ = separate_yang10(clipped)
    assert np.all(np.isfinite(out)) and np.all(out <= clipped) and np.all(out >= 0)
    # outside the clipped core the recovery still works
    ok = np.all(image < 1.0, axis=-1)
    assert psnr(out[ok], diffuse[ok]) > 40


@pytest.mark.parametrize(
    "image, match",
    [
        (np.zeros((4, 4)), r"\(H, W, 3\)"),
        (np.zeros((4, 4, 3), dtype=np.uint16), "dtype"),
        (np.full((4, 4, 3), 2.0), r"\[0, 1\]"),
    ],
)
def test_bad_images(image, match):
    with pytest.raises(MethodError, match=match):
        separate_yang10(image)


@pytest.mark.parametrize(
    "opts, match",
    [
        ({"sigma_range": 0}, "sigma_range"),
        ({"threshold": -1}, "threshold"),
        ({"sigma_spatial": -3}, "sigma_spatial"),
        ({"dark": 1.5}, "dark"),
        ({"max_iter": 0}, "max_iter"),
    ],
)
def test_bad_options(opts, match):
    with pytest.raises(MethodError, match=match):
        separate_yang10(np.full((4, 4, 3), 0.5), **opts)


@pytest.mark.slow
def test_speed_640x480(benchmark):
    """Timed by pytest-benchmark (`make test-all PYTEST_ARGS=--benchmark-enable`), never asserted."""
    rng = np.random.default_rng(0)
    image, _ = dichromatic_scene(h=480, w=640, colours=tuple(rng.dirichlet([2, 2, 2], size=6)))
    out = benchmark(separate_yang10, image)
    d = out[0] if isinstance(out, tuple) else out
    assert d.shape == image.shape and np.all(np.isfinite(d))


@pytest.mark.slow
def test_fidelity_on_shen2013(shared_data):
    from polcam.bench.sihr import run

    (row,) = run(shared_data / "shen2013", ["yang10"])
    assert row["deviation"] < 1.0
