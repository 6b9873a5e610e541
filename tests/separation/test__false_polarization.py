"""Demosaicing's edge polarization: the linear fit on the gradient removes it, real polarization stays."""

from __future__ import annotations

import numpy as np

from polcam.polarimetry import synthesize
from polcam.separation._false_polarization import without_edge_polarization


def _ramp_scene(h=64, w=80):
    yy, xx = np.mgrid[:h, :w]
    ic = 0.2 + 0.5 * (np.sin(xx / 7.0) * np.cos(yy / 9.0) + 1) / 2
    return np.repeat(ic[..., None], 3, axis=-1).astype(np.float32)


def test_a_polarization_linear_in_the_gradient_is_removed_and_ic_kept():
    import cv2

    ic = _ramp_scene()
    gx = np.stack([cv2.Sobel(ic[..., c], cv2.CV_32F, 1, 0) for c in range(3)], -1)
    gy = np.stack([cv2.Sobel(ic[..., c], cv2.CV_32F, 0, 1) for c in range(3)], -1)
    q = -0.04 * (gx + gy)
    u = -0.04 * (gx - gy)
    st = np.stack([ic + q, ic + u, ic - q, ic - u]).astype(np.float32)
    out = without_edge_polarization(st)
    np.testing.assert_allclose(out.mean(axis=0), ic, atol=1e-6)
    assert np.abs(0.5 * (out[0] - out[2])).max() < 1e-5 and np.abs(0.5 * (out[1] - out[3])).max() < 1e-5


def test_a_highlight_polarization_is_kept():
    # a polarized highlight (constant AoLP) on the same shading: its polarization is not a linear
    # function of the gradient (both flanks, one AoLP), so the fit leaves it almost whole
    ic = _ramp_scene()
    h, w = ic.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    spec = 0.3 * np.exp(-((yy - 32) ** 2 + (xx - 40) ** 2) / 18.0)
    st = synthesize(ic + spec[..., None], 0.6 * np.repeat(spec[..., None], 3, -1), np.full(ic.shape, 0.4))
    out = without_edge_polarization(st.astype(np.float32))
    before = np.hypot(0.5 * (st[0] - st[2]), 0.5 * (st[1] - st[3])).sum()
    after = np.hypot(0.5 * (out[0] - out[2]), 0.5 * (out[1] - out[3])).sum()
    assert after > 0.9 * before
