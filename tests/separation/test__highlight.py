"""Highlight evidence: the rise above the surroundings' floor in the illuminant's colour."""

from __future__ import annotations

import numpy as np

from polcam.separation._highlight import peak_excess


def test_uniform_patches_and_steps_have_no_excess_a_narrow_bump_has_its_height():
    h, w = 60, 90
    ic = np.full((h, w, 3), 0.2, np.float32)
    ic[:, 45:] = (0.5, 0.3, 0.2)                            # a step between two materials, both wide
    yy, xx = np.mgrid[:h, :w]
    bump = 0.25 * np.exp(-((yy - 30) ** 2 + (xx - 20) ** 2) / 8.0)
    g = np.array([1.0, 1.0, 1.0], np.float32)
    out = peak_excess(ic + bump[..., None].astype(np.float32), g, window=15, smooth=5)
    assert out.dtype == np.float32 and out.min() >= 0
    far = np.hypot(yy - 30, xx - 20) > 12                 # the bump is below 1e-8 there
    assert float(out[far].max()) < 1e-6
    assert abs(float(out[30, 20]) - 0.25) < 0.03


def test_a_peak_in_one_channel_only_has_no_excess():
    h, w = 40, 40
    ic = np.full((h, w, 3), 0.3, np.float32)
    ic[18:22, :, 0] = 0.6                                   # a thin red line on grey: not G's colour
    out = peak_excess(ic, np.ones(3, np.float32), window=15, smooth=3)
    assert float(out.max()) < 1e-6
