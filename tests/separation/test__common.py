"""Shared helpers of the single-image methods: closed forms of the dichromatic model."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation._common import (
    as_rgb_image,
    channel_max,
    channel_min,
    channel_sum,
    chromaticity,
    dark_mask,
    diffuse_from_max_chromaticity,
    finish_diffuse,
    safe_divide,
    specular_free,
    specular_free_chromaticity,
)


def _dichromatic(rng, shape=(12, 10)):
    """Random diffuse chromaticities and weights plus a white specular term."""
    lam = rng.dirichlet([2.0, 2.0, 2.0], size=shape)
    md = rng.uniform(0.05, 0.6, shape)
    ms = rng.uniform(0.0, 0.4, shape)
    diffuse = md[..., None] * lam
    return diffuse + ms[..., None] / 3, diffuse, lam


def test_as_rgb_image_accepts_and_clips():
    x = np.full((2, 3, 3), 0.5, dtype=np.float32)
    x[0, 0, 0] = 1 + 5e-7
    out = as_rgb_image(x, method="m")
    assert out.dtype == np.float64 and out.shape == (2, 3, 3) and out.max() == 1.0


@pytest.mark.parametrize(
    "arr, match",
    [
        (np.zeros((4, 4)), r"expected an \(H, W, 3\)"),
        (np.zeros((4, 4, 4)), r"expected an \(H, W, 3\)"),
        (np.zeros((0, 4, 3)), "H >= 1"),
        (np.zeros((4, 4, 3), dtype=np.uint8), "dtype uint8"),
        (np.full((4, 4, 3), np.nan), "NaN"),
        (np.full((4, 4, 3), 1.5), r"expected \[0, 1\]"),
        (np.full((4, 4, 3), -0.1), r"expected \[0, 1\]"),
    ],
)
def test_as_rgb_image_refuses(arr, match):
    with pytest.raises(MethodError, match=match) as err:
        as_rgb_image(arr, method="yang10")
    assert "yang10" in str(err.value)


def test_channel_reductions_match_numpy():
    rng = np.random.default_rng(0)
    x = rng.random((5, 6, 3))
    np.testing.assert_array_equal(channel_max(x), x.max(axis=-1))
    np.testing.assert_array_equal(channel_min(x), x.min(axis=-1))
    np.testing.assert_allclose(channel_sum(x), x.sum(axis=-1), atol=1e-15)


def test_safe_divide():
    num = np.array([1.0, 2.0, 3.0, 0.0])
    den = np.array([2.0, 0.0, 1e-12, 0.0])
    np.testing.assert_array_equal(safe_divide(num, den, fill=-1.0), [0.5, -1.0, -1.0, -1.0])
    np.testing.assert_array_equal(safe_divide(num, den, fill=0.0, eps=1e-13), [0.5, 0.0, 3e12, 0.0])


def test_chromaticity():
    rng = np.random.default_rng(1)
    x = rng.random((4, 5, 3))
    x[0, 0] = 0.0
    c = chromaticity(x)
    np.testing.assert_allclose(c.sum(axis=-1), 1.0)
    np.testing.assert_allclose(c[0, 0], 1 / 3)
    np.testing.assert_allclose(c[1, 1], x[1, 1] / x[1, 1].sum())


def test_specular_free_removes_white_specular_exactly():
    rng = np.random.default_rng(2)
    image, diffuse, _ = _dichromatic(rng)
    np.testing.assert_allclose(specular_free(image), specular_free(diffuse), atol=1e-14)
    msf = specular_free(image, offset=0.1)
    np.testing.assert_allclose(msf.min(axis=-1), 0.1, atol=1e-14)


def test_specular_free_chromaticity_is_the_closed_form_and_specular_invariant():
    rng = np.random.default_rng(3)
    image, diffuse, lam = _dichromatic(rng)
    lam_min = lam.min(axis=-1, keepdims=True)
    expected = (lam - lam_min) / (1 - 3 * lam_min)  # Yang et al. 2010, eq. 6
    np.testing.assert_allclose(specular_free_chromaticity(image), expected, atol=1e-9)
    np.testing.assert_allclose(specular_free_chromaticity(diffuse), expected, atol=1e-9)


def test_specular_free_chromaticity_of_grey_and_black_is_achromatic():
    x = np.array([[[0.4, 0.4, 0.4], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])
    np.testing.assert_allclose(specular_free_chromaticity(x), 1 / 3)


def test_diffuse_from_the_true_max_chromaticity_is_exact():
    rng = np.random.default_rng(4)
    image, diffuse, lam = _dichromatic(rng)
    out = diffuse_from_max_chromaticity(image, lam.max(axis=-1))
    np.testing.assert_allclose(out, diffuse, atol=1e-12)


def test_diffuse_from_max_chromaticity_failure_points():
    image = np.array([[[0.3, 0.3, 0.3], [0.6, 0.2, 0.1], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])
    # grey estimate: the split is undetermined, nothing is removed
    np.testing.assert_array_equal(diffuse_from_max_chromaticity(image, np.full((1, 4), 1 / 3)), image)
    # an estimate below the pixel's own max chromaticity is raised to it: nothing removed
    out = diffuse_from_max_chromaticity(image[:, 1:2], np.array([[0.4]]))
    np.testing.assert_allclose(out, image[:, 1:2])
    # a saturated white pixel on a red surface is all specular
    out = diffuse_from_max_chromaticity(image[:, 3:4], np.array([[1.0]]))
    np.testing.assert_allclose(out, 0.0, atol=1e-12)
    # estimates just above 1/3 (denominator near zero) stay finite and in [0, I]
    with np.errstate(all="raise"):
        out = diffuse_from_max_chromaticity(image, np.full((1, 4), 1 / 3 + 1e-9))
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


def test_dark_mask():
    x = np.array([[[0.01, 0.02, 0.0], [0.5, 0.0, 0.0]]])
    np.testing.assert_array_equal(dark_mask(x, 0.05), [[True, False]])


def test_finish_diffuse():
    image = np.full((1, 3, 3), 0.5)
    est = np.array([[[np.nan, 0.2, 0.9], [-0.1, np.inf, 0.3], [0.4, 0.4, 0.4]]])
    out = finish_diffuse(est, image)
    np.testing.assert_array_equal(out, [[[0.0, 0.2, 0.5], [0.0, 0.0, 0.3], [0.4, 0.4, 0.4]]])


# ---------------------------------------------------------------------------
# the helpers Yang'10 uses, on PyTorch tensors: the numpy values, on the tensor's device
# ---------------------------------------------------------------------------

def test_torch_helpers_equal_numpy(dev):
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(4)
    x, _, lam = _dichromatic(rng)
    x[0, 0] = 0.0                      # black
    x[0, 1] = 0.4                      # grey
    x[0, 2] = (1.0, 1.0, 0.2)          # saturated
    lam_max = lam.max(axis=-1)
    t = torch.as_tensor(x, device=dev)
    cases = [
        (as_rgb_image(x.astype(np.float32)), as_rgb_image(t.to(torch.float32))),
        (channel_max(x), channel_max(t)),
        (channel_min(x), channel_min(t)),
        (channel_sum(x), channel_sum(t)),
        (safe_divide(x[..., 0], x[..., 1] - 0.3, fill=-1.0), safe_divide(t[..., 0], t[..., 1] - 0.3, fill=-1.0)),
        (chromaticity(x), chromaticity(t)),
        (specular_free(x, offset=0.1), specular_free(t, offset=0.1)),
        (specular_free_chromaticity(x), specular_free_chromaticity(t)),
        (diffuse_from_max_chromaticity(x, lam_max),
         diffuse_from_max_chromaticity(t, torch.as_tensor(lam_max, device=dev))),
        (finish_diffuse(x - 0.1, x), finish_diffuse(t - 0.1, t)),
    ]
    for want, got in cases:
        assert isinstance(got, torch.Tensor) and got.device.type == dev.split(":")[0]
        assert got.dtype == torch.float64
        np.testing.assert_allclose(got.cpu().numpy(), want, rtol=0, atol=1e-15)
    bad = torch.as_tensor([[[np.nan, 0.5, np.inf]]], device=dev)
    np.testing.assert_array_equal(finish_diffuse(bad, torch.full_like(bad, 0.7)).cpu().numpy(), [[[0, 0.5, 0]]])


def test_torch_as_rgb_image_refuses(dev):
    torch = pytest.importorskip("torch")
    with pytest.raises(MethodError, match="dtype"):
        as_rgb_image(torch.zeros((4, 4, 3), dtype=torch.uint8, device=dev), method="yang10")
    with pytest.raises(MethodError, match="NaN"):
        as_rgb_image(torch.full((4, 4, 3), float("nan"), device=dev))
    with pytest.raises(MethodError, match=r"expected an \(H, W, 3\)"):
        as_rgb_image(torch.zeros((4, 4), device=dev))
