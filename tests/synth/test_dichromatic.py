"""polcam.synth.dichromatic: the scenes' ground truth follows the dichromatic model they claim."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import PolcamError
from polcam.synth.dichromatic import (
    BAND_COLOURS,
    PATCH_COLOURS,
    banded_scene,
    edge_cases,
    patch_scene,
    polarization_stack,
)


def white_specular(image: np.ndarray, diffuse: np.ndarray) -> np.ndarray:
    """``image - diffuse`` as one (H, W) map, after checking it is equal in R, G, B and >= 0."""
    spec = image - diffuse
    np.testing.assert_allclose(spec[..., 1], spec[..., 0], atol=1e-15)
    np.testing.assert_allclose(spec[..., 2], spec[..., 0], atol=1e-15)
    assert np.all(spec >= 0)
    return spec[..., 0]


@pytest.mark.parametrize("h, w", [(64, 96), (17, 23), (1, 1)])
def test_banded_shapes_and_white_specular(h, w):
    image, diffuse = banded_scene(h, w)
    assert image.shape == diffuse.shape == (h, w, 3)
    assert image.dtype == diffuse.dtype == np.float64
    spec = white_specular(image, diffuse)
    assert spec.max() <= len(BAND_COLOURS) * 0.6 / 3 + 1e-15  # lobes overlap in narrow bands


def test_banded_diffuse_is_shading_times_the_band_colour():
    h, w = 64, 96
    _, diffuse = banded_scene(h, w)
    colours = np.asarray(BAND_COLOURS)
    for i, cols in enumerate((slice(0, 48), slice(48, 96))):
        band = diffuse[:, cols]
        shade = band / colours[i]  # the same in every channel
        np.testing.assert_allclose(shade, shade[..., :1].repeat(3, axis=-1), rtol=1e-12)
        assert shade.min() >= 0.55 - 1e-12 and shade.max() <= 0.9 + 1e-12


def test_banded_lobes():
    h, w, peak = 64, 96, 0.6
    image, diffuse = banded_scene(h, w, peak=peak)
    spec = white_specular(image, diffuse)
    yy, xx = np.mgrid[0:h, 0:w]
    # band 0's lobe is centred at (0.4 h, 24), band 1's at (0.6 h, 72); sigma 5 px, cut at 15 px
    for cy, cx in ((0.4 * h, 24.0), (0.6 * h, 72.0)):
        r2 = (yy - cy) ** 2 + (xx - cx) ** 2
        near = r2 < 15.0**2
        np.testing.assert_allclose(spec[near], peak / 3 * np.exp(-r2[near] / 50.0), rtol=1e-12)
    far = ((yy - 0.4 * h) ** 2 + (xx - 24) ** 2 >= 225) & ((yy - 0.6 * h) ** 2 + (xx - 72) ** 2 >= 225)
    np.testing.assert_array_equal(spec[far], 0.0)
    assert spec.max() <= peak / 3  # no overlap at this size


def test_banded_without_highlight_is_its_diffuse_layer():
    image, diffuse = banded_scene(peak=0.0, colours=((0.6, 0.3, 0.1),))
    np.testing.assert_array_equal(image, diffuse)


def test_patch_scene_ground_truth():
    h, w, margin, peak = 48, 64, 8, 0.6
    image, diffuse = patch_scene(h, w, margin=margin, peak=peak)
    assert image.shape == diffuse.shape == (h, w, 3) and image.dtype == np.float64
    spec = white_specular(image, diffuse)
    assert 0.9 * peak / 3 < spec.max() <= peak / 3
    # black outside the 2 x 2 block of 16 x 24 patches
    block = np.zeros((h, w), bool)
    block[margin:margin + 32, margin:margin + 48] = True
    np.testing.assert_array_equal(image[~block], 0.0)
    # each patch: shading in [0.9 (1 - 0.8 / 2), 0.9] times its colour
    for k, (y0, x0) in enumerate([(8, 8), (8, 32), (24, 8), (24, 32)]):
        patch = diffuse[y0:y0 + 16, x0:x0 + 24] / PATCH_COLOURS[k]
        np.testing.assert_allclose(patch, patch[..., :1].repeat(3, axis=-1), rtol=1e-12)
        assert patch.min() >= 0.9 * 0.6 - 1e-12 and patch.max() <= 0.9 + 1e-12


def test_patch_without_highlight_is_its_diffuse_layer():
    image, diffuse = patch_scene(24, 32, margin=4, peak=0.0)
    np.testing.assert_array_equal(image, diffuse)


def test_generators_are_deterministic():
    for make in (banded_scene, patch_scene):
        a, b = make(), make()
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])


def test_polarization_stack_mean_and_polarization():
    image, diffuse = banded_scene(peak=0.3)
    stack = polarization_stack(image, diffuse)
    assert stack.shape == (4, 64, 96, 3)
    np.testing.assert_allclose(stack.mean(axis=0), image, atol=1e-15)
    # Stokes parameters of the four angles (0, 45, 90, 135): the specular part alone is
    # polarized, with degree 0.8 and angle 0.6 / 2 rad
    s0 = stack.sum(axis=0) / 2
    s1 = stack[0] - stack[2]
    s2 = stack[1] - stack[3]
    spec = image - diffuse
    np.testing.assert_allclose(np.hypot(s1, s2), 0.8 * 2 * spec, atol=1e-14)
    np.testing.assert_allclose(s0, 2 * image, atol=1e-14)
    lit = spec[..., 0] > 1e-3
    np.testing.assert_allclose(0.5 * np.arctan2(s2, s1)[lit], 0.3, atol=1e-12)
    # where there is no highlight every angle sees the diffuse layer
    dark = spec[..., 0] == 0
    for k in range(4):
        np.testing.assert_array_equal(stack[k][dark], diffuse[dark])


def test_edge_cases():
    cases = edge_cases()
    names = [n for n, _ in cases]
    assert names == ["zeros", "white", "grey", "one pixel", "one row", "one column", "single channel",
                     "tiny values", "saturated", "dark noise"]
    for name, img in cases:
        assert img.ndim == 3 and img.shape[-1] == 3 and img.dtype == np.float64, name
        assert np.all(img >= 0) and np.all(img <= 1), name
    # new arrays on every call, the same values
    cases[0][1][:] = 0.5
    again = edge_cases()
    np.testing.assert_array_equal(again[0][1], 0.0)
    for (_, a), (_, b) in zip(cases[1:], again[1:]):
        np.testing.assert_array_equal(a, b)
    assert dict(again)["saturated"].max() == 1.0  # the clipped highlight


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: banded_scene(0, 5), "h=0"),
        (lambda: banded_scene(5, 2.5), "w=2.5"),
        (lambda: banded_scene(peak=-1.0), "peak"),
        (lambda: banded_scene(peak=np.nan), "peak"),
        (lambda: banded_scene(colours=((0.5, 0.5),)), "colours"),
        (lambda: banded_scene(colours=((0.5, -0.1, 0.2),)), "colours"),
        (lambda: patch_scene(10, 64, margin=8), "h=10"),
        (lambda: patch_scene(margin=-1), "margin"),
        (lambda: patch_scene(colours=PATCH_COLOURS[:3]), r"\(4, 3\)"),
        (lambda: polarization_stack(np.zeros((4, 4, 3)), np.zeros((4, 5, 3))), "shape"),
        (lambda: polarization_stack(np.zeros((4, 4, 3)), np.zeros((4, 4, 3)), amplitude=1.5), "amplitude"),
    ],
)
def test_bad_input(call, match):
    with pytest.raises(PolcamError, match=match):
        call()
