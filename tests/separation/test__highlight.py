"""Highlight evidence: the rise above the surroundings' floor in the illuminant's colour."""

from __future__ import annotations

import numpy as np

from polcam.separation._highlight import peak_excess


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
