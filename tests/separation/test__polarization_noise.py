"""polcam.separation._polarization_noise: the garrotes that shrink what noise explains."""

from __future__ import annotations

import numpy as np

from polcam.separation._polarization_noise import _KSIG, _prior_removal


def test_colour_prior_removal_is_shrunk_by_the_noise():
    # the colour prior's removal is a garrote at _KSIG deviations of Ic's noise: a removal at the
    # noise's level is (almost) undone, one far above it is kept
    h, w = 4, 5
    sig = np.full((h, w, 3), 0.01, np.float32)            # deviation of q and u
    sd_ic = float(np.sqrt(0.5 * 3) * 0.01)                # of Ic, over the three channels
    diffuse = np.full((h, w, 3), 0.5, np.float32)
    for size, lo, hi in ((0.5 * _KSIG * sd_ic, 0.0, 1e-6), (10 * _KSIG * sd_ic, 0.98, 0.995)):
        t = size / np.sqrt(3.0)                           # a removal of norm `size` along white
        sf = diffuse - t
        kept = _prior_removal(diffuse, sf, sig).sum(axis=-1) / (3 * t)
        assert np.all((kept >= lo) & (kept <= hi))
    # never more than the prior asked for, never negative (sf above the diffuse removes nothing)
    rng = np.random.default_rng(0)
    sf = diffuse + rng.normal(0, 0.05, diffuse.shape).astype(np.float32)
    out = _prior_removal(diffuse, sf, sig)
    assert np.all(out >= 0) and np.all(out <= diffuse - np.minimum(sf, diffuse) + 1e-7)
