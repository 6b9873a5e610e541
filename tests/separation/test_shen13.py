"""shen13 (Shen & Zheng, Applied Optics 2013) on synthetic dichromatic scenes with known diffuse.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation.shen13 import cluster_pseudo_chromaticity, separate_shen13
from polcam.synth.dichromatic import banded_scene


def test_single_material_is_exact_where_processed():
    # one material: one cluster, one diffuse intensity ratio, I_max - Q I_range is the specular term
    image, diffuse = banded_scene(colours=((0.6, 0.3, 0.1),))
    out, info = separate_shen13(image)
    assert info["clusters"] == 1
    processed = image.min(axis=-1) > image.min(axis=-1).mean()
    np.testing.assert_allclose(out[processed], diffuse[processed], atol=1e-9)
    assert psnr(out, diffuse) > 60  # the unprocessed pixels keep the faint lobe tails


def test_two_materials():
    image, diffuse = banded_scene()
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
    image, _ = banded_scene(colours=((0.36, 0.33, 0.31),))
    out, info = separate_shen13(image)
    assert info["clusters"] == 1
    np.testing.assert_array_equal(out, image)


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_shen13(np.zeros((3, 3, 4)))
    with pytest.raises(MethodError, match="NaN"):
        separate_shen13(np.full((3, 3, 3), np.nan))
    with pytest.raises(MethodError, match="chroma_threshold"):
        separate_shen13(np.full((3, 3, 3), 0.5), chroma_threshold=0)
    with pytest.raises(MethodError, match="percentile"):
        separate_shen13(np.full((3, 3, 3), 0.5), percentile=1.5)


def test_cluster_ratios_on_torch_are_the_same(dev):
    torch = pytest.importorskip("torch")
    from polcam.separation.shen13 import cluster_ratios, ratio_specular

    image, _ = banded_scene()
    q, n = cluster_ratios(image)
    qt, nt = cluster_ratios(torch.as_tensor(image, device=dev))
    assert nt == n >= 2 and qt.device.type == dev.split(":")[0]
    np.testing.assert_array_equal(np.isnan(qt.cpu().numpy()), np.isnan(q))
    np.testing.assert_allclose(qt.cpu().numpy(), q, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(ratio_specular(torch.as_tensor(image, device=dev), qt).cpu().numpy(),
                               ratio_specular(image, q), rtol=0, atol=1e-12)
    pts = np.random.default_rng(1).uniform(0, 1, (300, 2))
    np.testing.assert_array_equal(cluster_pseudo_chromaticity(torch.as_tensor(pts, device=dev), 0.3).cpu().numpy(),
                                  cluster_pseudo_chromaticity(pts, 0.3))
