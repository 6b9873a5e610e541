"""yang10 (Yang, Wang & Ahuja, ECCV 2010) on synthetic dichromatic scenes with known diffuse.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.  The same method on PyTorch tensors (the tensor method's initial diffuse
with ``device=``) is checked against numpy on the CPU build of PyTorch where it is installed
(skipped otherwise) and on a CUDA GPU where one is present (``POLCAM_TEST_DEVICES`` overrides
the list, e.g. ``cpu,cuda``).
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation.yang10 import max_diffuse_chromaticity, separate_yang10
from polcam.synth.dichromatic import banded_scene


def test_recovers_the_diffuse_layer_of_two_materials():
    image, diffuse = banded_scene()
    out, info = separate_yang10(image)
    assert psnr(image, diffuse) < 31
    assert psnr(out, diffuse) > 48  # measured 53.0 dB
    assert info["converged"] and 1 <= info["iterations"] <= 10


def test_max_diffuse_chromaticity_estimate():
    image, _ = banded_scene()
    lam, bright, info = max_diffuse_chromaticity(image)
    truth = np.where(np.arange(96)[None, :] < 48, 0.9, 0.45) * np.ones((64, 1))
    assert bright.all()
    assert np.abs(lam - truth).max() < 0.02
    assert info["converged"]


def test_single_material_is_nearly_exact():
    image, diffuse = banded_scene(colours=((0.6, 0.3, 0.1),))
    out, _ = separate_yang10(image)
    assert psnr(out, diffuse) > 55  # measured 58.7 dB


def test_without_highlight_nothing_changes_much():
    _, diffuse = banded_scene()
    out, _ = separate_yang10(diffuse)
    assert psnr(out, diffuse) > 55


def test_dark_pixels_are_left_unchanged():
    image, diffuse = banded_scene()
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
    image, diffuse = banded_scene()
    out, info = separate_yang10(image, max_iter=1)
    assert info == {"iterations": 1, "converged": False}
    assert psnr(out, diffuse) < psnr(separate_yang10(image)[0], diffuse)


def test_achromatic_surface_is_kept():
    grey = np.repeat(np.linspace(0.1, 0.9, 99).reshape(9, 11, 1), 3, axis=2)
    np.testing.assert_array_equal(separate_yang10(grey)[0], grey)


def test_saturated_highlight_on_a_coloured_surface():
    image, diffuse = banded_scene(peak=2.0)
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


# ---------------------------------------------------------------------------
# the same method on PyTorch tensors
# ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bunny() -> np.ndarray:
    from polcam.synth.render import render
    from polcam.synth.scenes import scene

    return np.clip(render(scene("Bunny6"), size=72, seed=3).stack[1], 0, 1)


@pytest.mark.parametrize("size,dark", [(40, 20 / 255), (72, 20 / 255), (72, 0.45)])
def test_torch_matches_numpy(bunny, dev, size, dark):
    # 40: the grid is the image (sigma 10 < 12 pixels); 72: cells of 3 x 3 pixels;
    # dark=0.45 leaves many pixels out (zero weight), so some grid components are empty
    torch = pytest.importorskip("torch")
    img = bunny[:size, :size]
    want, info = separate_yang10(img, dark=dark)
    got, got_info = separate_yang10(torch.as_tensor(img, device=dev), dark=dark)
    assert np.abs(want - img).max() > 0.01         # Yang'10 removed something
    assert got.device.type == dev.split(":")[0] and got.dtype == torch.float64
    assert got_info == info
    np.testing.assert_allclose(got.cpu().numpy(), want, rtol=0, atol=1e-10)
    # a float32 tensor (the tensor method's default) is computed in float64 all the same
    got32, _ = separate_yang10(torch.as_tensor(img.astype(np.float32), device=dev), dark=dark)
    want32, _ = separate_yang10(img.astype(np.float32), dark=dark)
    np.testing.assert_allclose(got32.cpu().numpy(), want32, rtol=0, atol=1e-10)


def test_torch_recovers_the_banded_scene_and_refuses_bad_images(dev):
    torch = pytest.importorskip("torch")
    image, diffuse = banded_scene()
    out, info = separate_yang10(torch.as_tensor(image, device=dev))
    assert psnr(out.cpu().numpy(), diffuse) > 48 and info["converged"]
    dark = torch.full((6, 7, 3), 0.05, dtype=torch.float64, device=dev)
    np.testing.assert_array_equal(separate_yang10(dark)[0].cpu().numpy(), dark.cpu().numpy())
    with pytest.raises(MethodError, match="dtype"):
        separate_yang10(torch.zeros((4, 4, 3), dtype=torch.uint8, device=dev))
    with pytest.raises(MethodError, match=r"\[0, 1\]"):
        separate_yang10(torch.full((4, 4, 3), 2.0, device=dev))
