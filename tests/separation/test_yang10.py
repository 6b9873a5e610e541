"""yang10 (Yang, Wang & Ahuja, ECCV 2010) on synthetic dichromatic scenes with known diffuse.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.
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
