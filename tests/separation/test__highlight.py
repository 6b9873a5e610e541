"""Highlight evidence: the rise above the surroundings' floor in the illuminant's colour."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage

from polcam.separation._highlight import _LEVELS, _quantile_filter, peak_excess, surroundings_floor


def test_uniform_patches_and_steps_have_no_excess_a_narrow_bump_has_its_height():
    h, w = 60, 90
    ic = np.full((h, w, 3), 0.2, np.float32)
    ic[:, 45:] = (0.5, 0.3, 0.2)                            # a step between two materials, both wide
    yy, xx = np.mgrid[:h, :w]
    bump = 0.25 * np.exp(-((yy - 30) ** 2 + (xx - 20) ** 2) / 18.0)     # sigma 3 px
    g = np.array([1.0, 1.0, 1.0], np.float32)
    out = peak_excess(ic + bump[..., None].astype(np.float32), g, window=21, smooth=5)
    assert out.dtype == np.float32 and out.min() >= 0
    far = np.hypot(yy - 30, xx - 20) > 16                 # the bump is below 1e-6 there
    assert float(out[far].max()) < 1e-6
    # at the peak: the height less what the 5 x 5 median takes off a lobe this narrow (0.05)
    assert 0.75 * 0.25 < float(out[30, 20]) <= 0.25


def test_a_peak_in_one_channel_only_has_no_excess():
    h, w = 40, 40
    ic = np.full((h, w, 3), 0.3, np.float32)
    ic[18:22, :, 0] = 0.6                                   # a thin red line on grey: not G's colour
    out = peak_excess(ic, np.ones(3, np.float32), window=15, smooth=3)
    assert float(out.max()) < 1e-6


def _holed_surface(h, w, pitch, hole, level=(0.6, 0.5, 0.15), dark=0.05):
    """A uniform surface with square dark holes of side ``hole`` every ``pitch`` pixels (under a quarter of its area)."""
    ic = np.broadcast_to(np.asarray(level, np.float32), (h, w, 3)).copy()
    yy, xx = np.mgrid[:h, :w]
    holes = ((yy % pitch) < hole) & ((xx % pitch) < hole)
    ic[holes] = dark
    return ic, holes


def test_sparse_dark_holes_do_not_lower_the_floor_a_bump_on_the_surface_keeps_its_height():
    # a moulded part with dark holes in every window: the plain opening would take the holes for
    # the floor and the whole face for a highlight
    ic, holes = _holed_surface(96, 96, 16, 4)
    g = np.ones(3, np.float32)
    assert float(peak_excess(ic, g, window=31, smooth=5)[~holes].max()) < 1e-6
    opened = cv2.dilate(cv2.erode(cv2.medianBlur(ic, 5), np.ones((31, 31))), np.ones((31, 31)))
    assert float(opened[..., 2].max()) < 0.1                    # what the opening alone sees: the holes
    yy, xx = np.mgrid[:96, :96]
    bump = 0.2 * np.exp(-((yy - 42) ** 2 + (xx - 42) ** 2) / 18.0)        # sigma 3 px, between holes
    out = peak_excess(ic + bump[..., None].astype(np.float32), g, window=31, smooth=5)
    assert 0.75 * 0.2 < float(out[42, 42]) <= 0.2              # as on a plain surface: the median takes the rest
    assert float(out[(np.hypot(yy - 42, xx - 42) > 16) & ~holes].max()) < 1e-6


def test_a_large_frame_takes_the_quantile_at_the_training_side():
    # 640 px: the rank opening runs on the frame shrunk by 5, the plain opening at full resolution
    ic, holes = _holed_surface(480, 640, 80, 20)
    g = np.ones(3, np.float32)
    out = peak_excess(ic, g, window=77, smooth=5)
    away = cv2.dilate(holes.astype(np.uint8), np.ones((11, 11))) == 0     # the bilinear return blurs 5 px
    assert float(out[away].max()) < 1e-6
    # the edges of a patch wider than the window are exact: the plain opening bounds the floor
    ic2 = np.full((480, 640, 3), 0.1, np.float32)
    ic2[:, 320:] = 0.7
    assert float(peak_excess(ic2, g, window=77, smooth=5).max()) < 1e-6


def test_quantile_filter_matches_a_percentile_filter_to_one_level():
    rng = np.random.default_rng(3)
    a = (rng.random((50, 70, 3)) ** 2).astype(np.float32)
    for k in (5, 15):
        got = _quantile_filter(a, k, 0.25)
        ref = np.stack([ndimage.percentile_filter(a[..., c], 25, size=k, mode="mirror") for c in range(3)], -1)
        span = a.max(axis=(0, 1)) - a.min(axis=(0, 1))
        assert np.all(np.abs(got - ref) <= span / (_LEVELS - 1) + 1e-6)
    flat = np.full((20, 20, 3), 0.3, np.float32)
    np.testing.assert_array_equal(_quantile_filter(flat, 5, 0.25), flat)


@pytest.mark.parametrize("shape", [(96, 96), (300, 260)])
def test_surroundings_floor_on_torch_matches_numpy(shape):
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(1)
    base = cv2.GaussianBlur(rng.random(shape + (3,)).astype(np.float32), (9, 9), 0)
    want = surroundings_floor(base, 31)
    got = surroundings_floor(torch.as_tensor(base), 31)
    np.testing.assert_allclose(got.numpy(), want, atol=2e-5)
