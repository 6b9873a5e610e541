"""Demosaicing's edge polarization: the linear fit on the gradient removes it, real polarization stays."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_a_polarization_linear_in_the_wider_gradient_is_removed():
    # the demosaicing's interpolation reaches two pixels: a profile of the 5 x 5 derivative is
    # removed as exactly as one of the 3 x 3
    import cv2

    ic = _ramp_scene()
    gx = np.stack([cv2.Sobel(ic[..., c], cv2.CV_32F, 1, 0, ksize=5) for c in range(3)], -1) / 16
    gy = np.stack([cv2.Sobel(ic[..., c], cv2.CV_32F, 0, 1, ksize=5) for c in range(3)], -1) / 16
    q = 0.03 * gx - 0.02 * gy
    u = -0.01 * gx - 0.04 * gy
    st = np.stack([ic + q, ic + u, ic - q, ic - u]).astype(np.float32)
    out = without_edge_polarization(st)
    np.testing.assert_allclose(out.mean(axis=0), ic, atol=1e-6)
    assert np.abs(0.5 * (out[0] - out[2])).max() < 1e-5 and np.abs(0.5 * (out[1] - out[3])).max() < 1e-5


def _energy(st):
    return float(((0.5 * (st[0] - st[2])) ** 2 + (0.5 * (st[1] - st[3])) ** 2).sum())


@pytest.mark.parametrize("layout, least", [("imx250myr", 0.85), ("imx250mzr", 0.93)])
def test_a_grey_checker_s_false_polarization_is_mostly_removed(layout, least):
    # an unpolarized grey checker of 16-pixel squares through the mosaic and its default
    # demosaicing: all its polarization is the demosaicing's. The two-scale fit removes more of it
    # than the least-squares fit on the 3 x 3 gradient alone (numpy's lstsq, computed here)
    import cv2

    import polcam
    from polcam.demosaicing import mosaic_stack

    yy, xx = np.mgrid[:128, :160]
    level = np.where(((yy // 16) + (xx // 16)) % 2 == 0, 0.55, 0.18)
    st = synthesize(level, np.zeros_like(level), np.zeros_like(level))
    if layout == "imx250myr":
        st = np.repeat(st[..., None], 3, axis=-1)
    cam = np.clip(polcam.demosaic(mosaic_stack(st, layout=layout), layout=layout), 0, 1).astype(np.float32)
    if cam.ndim == 3:
        cam = cam[..., None]
    before = _energy(cam)
    explained = 1 - _energy(without_edge_polarization(cam)) / before
    left = 0.0
    for c in range(cam.shape[-1]):
        img = cam.mean(axis=0)[..., c]
        a = np.stack([cv2.Sobel(img, cv2.CV_32F, 1, 0).ravel(), cv2.Sobel(img, cv2.CV_32F, 0, 1).ravel()], 1)
        for t in (0.5 * (cam[0] - cam[2])[..., c], 0.5 * (cam[1] - cam[3])[..., c]):
            coef = np.linalg.lstsq(a.astype(np.float64), t.ravel().astype(np.float64), rcond=None)[0]
            left += float(((t.ravel() - a @ coef) ** 2).sum())
    assert explained >= least and explained > (1 - left / before) + 0.05, (explained, 1 - left / before)
