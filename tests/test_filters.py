"""The constant-time joint bilateral filter against a brute-force joint bilateral filter.

The same filter on PyTorch tensors (the one implementation over the array
namespace) is checked against the numpy results, on the CPU build of PyTorch
where it is installed (skipped otherwise) and on a CUDA GPU where one is present
(``POLCAM_TEST_DEVICES`` overrides the list, e.g. ``cpu,cuda``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from polcam.errors import MethodError
from polcam.filters import JointBilateral, gaussian_matrix, joint_bilateral

TRUNCATE = 4.0  # the filter truncates its spatial Gaussian at 4 sigma (scipy.ndimage's convention)


def brute_force(image, guide, sigma_spatial, sigma_range, weights=None, truncate=None):
    """Direct double sum of the joint bilateral filter over the image.

    With ``truncate``, the spatial kernel is limited to the square of radius
    ``int(truncate * sigma + 0.5)`` (the separable truncation of a blurred
    image); without it, every pixel of the image contributes.
    """
    h, w = guide.shape
    yy, xx = np.mgrid[0:h, 0:w]
    p = np.stack([yy.ravel(), xx.ravel()], axis=1).astype(float)
    dy = p[:, None, 0] - p[None, :, 0]
    dx = p[:, None, 1] - p[None, :, 1]
    k = np.exp(-(dy**2 + dx**2) / (2 * sigma_spatial**2))
    if truncate is not None:
        r = int(truncate * sigma_spatial + 0.5)
        k *= (np.abs(dy) <= r) & (np.abs(dx) <= r)
    g = guide.ravel()
    k *= np.exp(-((g[:, None] - g[None, :]) ** 2) / (2 * sigma_range**2))
    if weights is not None:
        k *= weights.ravel()[None, :]
    return ((k @ image.ravel()) / k.sum(axis=1)).reshape(h, w)


def _guide(rng, h=36, w=44):
    g = np.zeros((h, w))
    g[:, w // 2:] = 0.5
    g[h // 3: 2 * h // 3, w // 4: 3 * w // 4] += 0.2
    g += 0.15 * np.linspace(0, 1, w)[None, :] * np.linspace(0, 1, h)[:, None]
    return g + 0.01 * rng.standard_normal((h, w))


def test_exact_when_the_guide_takes_only_level_values():
    # A guide with two values and two levels placed on them: every pixel reads a
    # component at its own guide value, which the method computes exactly.
    rng = np.random.default_rng(0)
    g = np.where(rng.random((30, 40)) > 0.5, 0.2, 0.7)
    f = rng.random((30, 40))
    out = joint_bilateral(f, g, sigma_spatial=3.0, sigma_range=0.3, levels=2, downsample=1)
    ref = brute_force(f, g, 3.0, 0.3, truncate=TRUNCATE)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


def test_close_to_brute_force_with_default_levels():
    rng = np.random.default_rng(1)
    g = _guide(rng)
    f = rng.random(g.shape)
    out = joint_bilateral(f, g, sigma_spatial=3.0, sigma_range=0.05, downsample=1)
    ref = brute_force(f, g, 3.0, 0.05)
    # levels at most sigma_range apart: the range interpolation error stays below 1% of the
    # signal's range [0, 1]
    assert np.abs(out - ref).max() < 0.01
    assert np.abs(out - ref).mean() < 0.002


def test_more_levels_converge_to_brute_force():
    rng = np.random.default_rng(2)
    g = _guide(rng)
    f = rng.random(g.shape)
    ref = brute_force(f, g, 3.0, 0.05, truncate=TRUNCATE)
    errs = [np.abs(joint_bilateral(f, g, sigma_spatial=3.0, sigma_range=0.05, levels=n, downsample=1) - ref).max()
            for n in (4, 12, 48, 200)]
    assert errs == sorted(errs, reverse=True)
    assert errs[-1] < 2e-4


def test_coarse_grid_for_a_large_spatial_sigma():
    rng = np.random.default_rng(3)
    g = _guide(rng, 48, 60)
    f = rng.random(g.shape)
    jb = JointBilateral(g, sigma_spatial=15.0, sigma_range=0.08)
    assert jb.downsample == 2  # sigma / downsample >= 6 grid cells
    ref = brute_force(f, g, 15.0, 0.08)
    assert np.abs(jb(f) - ref).max() < 0.005


def test_constant_guide_is_a_normalised_gaussian():
    rng = np.random.default_rng(4)
    f = rng.random((25, 31))
    g = np.full(f.shape, 0.4)
    out = joint_bilateral(f, g, sigma_spatial=2.5, sigma_range=0.1, downsample=1)
    np.testing.assert_allclose(out, brute_force(f, g, 2.5, 0.1, truncate=TRUNCATE), atol=1e-12)


def test_constant_image_is_kept():
    rng = np.random.default_rng(5)
    g = _guide(rng)
    out = joint_bilateral(np.full(g.shape, 0.37), g, sigma_spatial=20.0, sigma_range=0.04)
    np.testing.assert_allclose(out, 0.37, atol=1e-12)


def test_zero_weights_exclude_pixels():
    rng = np.random.default_rng(6)
    g = np.where(rng.random((24, 30)) > 0.5, 0.1, 0.6)
    f = rng.random(g.shape)
    wts = (rng.random(g.shape) > 0.3) * rng.uniform(0.5, 2.0, g.shape)
    f_poisoned = np.where(wts > 0, f, 1e3)
    out = joint_bilateral(f_poisoned, g, sigma_spatial=3.0, sigma_range=0.3, levels=2, downsample=1,
                          weights=wts)
    ref = brute_force(f, g, 3.0, 0.3, weights=wts, truncate=TRUNCATE)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-10)


def test_no_weight_within_reach_returns_the_input():
    g = np.zeros((20, 60))
    f = np.linspace(0, 1, 60)[None, :].repeat(20, axis=0)
    wts = np.zeros(g.shape)
    wts[:, :5] = 1.0  # only the left edge counts; the right side is > 4 sigma away
    out = joint_bilateral(f, g, sigma_spatial=2.0, sigma_range=0.1, weights=wts, downsample=1)
    np.testing.assert_array_equal(out[:, 30:], f[:, 30:])
    assert np.all(np.isfinite(out))


def test_channels_are_filtered_independently():
    rng = np.random.default_rng(7)
    g = _guide(rng, 20, 24)
    f = rng.random((20, 24, 3))
    jb = JointBilateral(g, sigma_spatial=4.0, sigma_range=0.1)
    out = jb(f)
    for c in range(3):
        np.testing.assert_allclose(out[..., c], jb(f[..., c]), atol=1e-12)


def test_tiny_images():
    out = joint_bilateral(np.array([[0.3]]), np.array([[0.5]]), sigma_spatial=100.0, sigma_range=0.04)
    np.testing.assert_allclose(out, [[0.3]])
    row = np.linspace(0, 1, 7)[None, :]
    out = joint_bilateral(row, row, sigma_spatial=50.0, sigma_range=0.01)
    assert out.shape == (1, 7) and np.all(np.isfinite(out))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"sigma_spatial": 0.0, "sigma_range": 0.1}, "sigma_spatial"),
        ({"sigma_spatial": 2.0, "sigma_range": -1.0}, "sigma_range"),
        ({"sigma_spatial": 2.0, "sigma_range": 0.1, "levels": 1}, "levels"),
        ({"sigma_spatial": 2.0, "sigma_range": 0.1, "downsample": 0}, "downsample"),
        ({"sigma_spatial": 2.0, "sigma_range": 0.1, "weights": -np.ones((4, 5))}, "non-negative"),
        ({"sigma_spatial": 2.0, "sigma_range": 0.1, "weights": np.ones((5, 4))}, "weights of shape"),
    ],
)
def test_bad_parameters(kwargs, match):
    with pytest.raises(MethodError, match=match):
        joint_bilateral(np.zeros((4, 5)), np.zeros((4, 5)), **kwargs)


def test_bad_arrays():
    with pytest.raises(MethodError, match="guide's shape"):
        joint_bilateral(np.zeros((4, 6)), np.zeros((4, 5)), sigma_spatial=1.0, sigma_range=0.1)
    with pytest.raises(MethodError, match="NaN"):
        joint_bilateral(np.zeros((4, 5)), np.full((4, 5), np.nan), sigma_spatial=1.0, sigma_range=0.1)
    with pytest.raises(MethodError, match="NaN"):
        joint_bilateral(np.full((4, 5), np.inf), np.zeros((4, 5)), sigma_spatial=1.0, sigma_range=0.1)
    with pytest.raises(MethodError, match=r"\(H, W\)"):
        joint_bilateral(np.zeros(5), np.zeros(5), sigma_spatial=1.0, sigma_range=0.1)


def test_automatic_levels():
    g = np.linspace(0.2, 0.7, 40).reshape(5, 8)
    assert JointBilateral(g, sigma_spatial=2.0, sigma_range=0.1).levels.size == 6  # span 0.5 / 0.1 + 1
    assert JointBilateral(g, sigma_spatial=2.0, sigma_range=0.09).levels.size == 7
    jb = JointBilateral(g, sigma_spatial=2.0, sigma_range=1e-5)
    assert jb.levels.size == 64  # capped: memory is levels x H x W
    np.testing.assert_allclose(jb.levels[[0, -1]], [0.2, 0.7])


def test_gaussian_matrix_is_scipys_gaussian_filter():
    # the device blur of the coarse grid: a matrix product equal to scipy's 1-D filter
    # with zeros outside, also when the kernel is wider than the signal
    rng = np.random.default_rng(8)
    for n, sigma in ((40, 2.3), (25, 6.0), (5, 6.0), (1, 3.0)):
        x = rng.random(n)
        want = ndimage.gaussian_filter1d(x, sigma, mode="constant", cval=0.0, truncate=TRUNCATE)
        np.testing.assert_allclose(gaussian_matrix(n, sigma) @ x, want, rtol=0, atol=1e-14)


# ---------------------------------------------------------------------------
# the same filter on PyTorch tensors
# ---------------------------------------------------------------------------

def _t(a: np.ndarray, dev: str):
    torch = pytest.importorskip("torch")
    return torch.as_tensor(np.ascontiguousarray(a), device=dev)


def test_torch_with_empty_components_matches_numpy(dev):
    rng = np.random.default_rng(2)
    g = rng.uniform(0, 1, (50, 61))
    f = rng.uniform(0, 1, (50, 61))
    wts = (rng.uniform(0, 1, g.shape) > 0.7).astype(float)
    wts[:, :40] = 0                        # beyond the kernel's reach of the left columns: empty
    a = JointBilateral(g, sigma_spatial=4.0, sigma_range=0.05, weights=wts)
    b = JointBilateral(_t(g, dev), sigma_spatial=4.0, sigma_range=0.05, weights=_t(wts, dev))
    assert not a._den_ok.all() and not a._slice_ok.all()
    got = b(_t(f, dev))
    assert got.device.type == dev.split(":")[0] and str(got.dtype) == "torch.float64"
    np.testing.assert_allclose(got.cpu().numpy(), a(f), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got.cpu().numpy()[:, :20], f[:, :20])     # the input where nothing counts


@pytest.mark.parametrize("shape,sigma,downsample", [((48, 60), 15.0, None), ((33, 70), 20.0, 3),
                                                    ((20, 24), 4.0, 1)])
def test_torch_coarse_grid_and_channels_match_numpy(dev, shape, sigma, downsample):
    # cells of 2 x 2 and 3 x 3 pixels with partial cells at the border, and the full grid;
    # a numpy image given to a tensor-bound filter is moved to the guide's device
    rng = np.random.default_rng(3)
    g = _guide(rng, *shape)
    f = rng.random(shape + (3,))
    a = JointBilateral(g, sigma_spatial=sigma, sigma_range=0.08, downsample=downsample)
    b = JointBilateral(_t(g, dev), sigma_spatial=sigma, sigma_range=0.08, downsample=downsample)
    assert b.downsample == a.downsample and b._slice_ok is None
    want = a(f)
    np.testing.assert_allclose(b(_t(f, dev)).cpu().numpy(), want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b(f).cpu().numpy(), want, rtol=0, atol=1e-12)
    if downsample is None:
        assert np.abs(want[..., 0] - brute_force(f[..., 0], g, sigma, 0.08)).max() < 0.005


def test_torch_exact_when_the_guide_takes_only_level_values(dev):
    rng = np.random.default_rng(0)
    g = np.where(rng.random((30, 40)) > 0.5, 0.2, 0.7)
    f = rng.random((30, 40))
    out = joint_bilateral(_t(f, dev), _t(g, dev), sigma_spatial=3.0, sigma_range=0.3, levels=2, downsample=1)
    ref = brute_force(f, g, 3.0, 0.3, truncate=TRUNCATE)
    np.testing.assert_allclose(out.cpu().numpy(), ref, rtol=0, atol=1e-12)


def test_torch_bad_arrays(dev):
    with pytest.raises(MethodError, match="NaN"):
        joint_bilateral(_t(np.zeros((4, 5)), dev), _t(np.full((4, 5), np.nan), dev),
                        sigma_spatial=1.0, sigma_range=0.1)
    with pytest.raises(MethodError, match="non-negative"):
        JointBilateral(_t(np.zeros((4, 5)), dev), sigma_spatial=1.0, sigma_range=0.1,
                       weights=_t(-np.ones((4, 5)), dev))
    with pytest.raises(MethodError, match="guide's shape"):
        JointBilateral(_t(np.zeros((4, 5)), dev), sigma_spatial=1.0, sigma_range=0.1)(_t(np.zeros((4, 6)), dev))
