"""shen13 (Shen & Zheng, Applied Optics 2013) on synthetic dichromatic scenes with known diffuse."""

from __future__ import annotations


import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation import separate
from polcam.separation.shen13 import cluster_pseudo_chromaticity, separate_shen13


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


def test_single_material_is_exact_where_processed():
    # one material: one cluster, one diffuse intensity ratio, I_max - Q I_range is the specular term
    image, diffuse = dichromatic_scene(colours=((0.6, 0.3, 0.1),))
    out, info = separate_shen13(image)
    assert info["clusters"] == 1
    processed = image.min(axis=-1) > image.min(axis=-1).mean()
    np.testing.assert_allclose(out[processed], diffuse[processed], atol=1e-9)
    assert psnr(out, diffuse) > 60  # the unprocessed pixels keep the faint lobe tails


def test_two_materials():
    image, diffuse = dichromatic_scene()
    out, info = separate_shen13(image)
    assert info["clusters"] == 2
    assert psnr(image, diffuse) < 31
    assert psnr(out, diffuse) > psnr(image, diffuse) + 5  # measured 37.3 dB against 29.9


def test_clustering():
    rng = np.random.default_rng(0)
    centres = np.array([[0.05, 0.9], [0.3, 0.4], [0.1, 0.5]])
    pts = np.concatenate([c + rng.uniform(-0.04, 0.04, (50, 2)) for c in centres])
    order = rng.permutation(pts.shape[0])
    labels = cluster_pseudo_chromaticity(pts[order], 0.3)
    truth = np.repeat(np.arange(3), 50)[order]
    # same partition, whatever the label numbers
    assert labels.max() == 2
    for k in range(3):
        assert np.unique(labels[truth == k]).size == 1
    assert np.unique([labels[truth == k][0] for k in range(3)]).size == 3


def test_cluster_without_reliable_ratio_is_unchanged():
    # a pale surface: every processed pixel has I_range <= mean(I_min), no ratio to trust
    image, _ = dichromatic_scene(colours=((0.36, 0.33, 0.31),))
    out, info = separate_shen13(image)
    assert info["clusters"] == 1
    np.testing.assert_array_equal(out, image)


def test_scale_contract_through_the_dispatcher():
    image, diffuse = dichromatic_scene(spec_peak=0.3)
    stack = polarization_stack(image, diffuse)
    res = separate(stack, method="shen13")
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (64, 96, 3) and res.diffuse.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    assert res.info["method"] == "shen13" and res.info["clusters"] == 2


def test_deterministic():
    image, _ = dichromatic_scene()
    np.testing.assert_array_equal(separate_shen13(image)[0], separate_shen13(image.copy())[0])


@pytest.mark.parametrize("name, image", EDGE_CASES)
def test_edge_cases_are_finite_and_in_range(name, image):
    out, _ = separate_shen13(image)
    assert out.shape == image.shape and out.dtype == np.float64
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_shen13(np.zeros((3, 3, 4)))
    with pytest.raises(MethodError, match="NaN"):
        separate_shen13(np.full((3, 3, 3), np.nan))
    with pytest.raises(MethodError, match="chroma_threshold"):
        separate_shen13(np.full((3, 3, 3), 0.5), chroma_threshold=0)
    with pytest.raises(MethodError, match="percentile"):
        separate_shen13(np.full((3, 3, 3), 0.5), percentile=1.5)


@pytest.mark.slow
def test_speed_640x480(benchmark):
    """Timed by pytest-benchmark (`make test-all PYTEST_ARGS=--benchmark-enable`), never asserted."""
    rng = np.random.default_rng(0)
    image, _ = dichromatic_scene(h=480, w=640, colours=tuple(rng.dirichlet([2, 2, 2], size=6)))
    out = benchmark(separate_shen13, image)
    d = out[0] if isinstance(out, tuple) else out
    assert d.shape == image.shape and np.all(np.isfinite(d))


@pytest.mark.slow
def test_fidelity_on_shen2013(shared_data):
    from polcam.bench.sihr import run

    (row,) = run(shared_data / "shen2013", ["shen13"])
    assert row["deviation"] < 1.0
