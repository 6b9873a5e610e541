"""Tests of the bilinear method against an independent normalised convolution."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from polcam.demosaicing import demosaic, mosaic_stack
from polcam.mosaic import Layout, parse_layout

MZR = parse_layout("imx250mzr")
MYR = parse_layout("imx250myr")
H, W = 32, 48


def _interior(a: np.ndarray, b: int = 8) -> np.ndarray:
    return a[b:a.shape[0] - b, b:a.shape[1] - b]


def test_bilinear_colour_is_exact_on_affine_images(affine_stack) -> None:
    truth = affine_stack(MYR, H, W)
    est = demosaic(mosaic_stack(truth, layout=MYR), layout=MYR, method="bilinear")
    np.testing.assert_allclose(est[:, 6:-6, 6:-6], truth[:, 6:-6, 6:-6], atol=2e-5)


@pytest.mark.parametrize("lay", [MZR, MYR, parse_layout("color:90,135,0,45:GBRG")], ids=lambda x: x.name)
def test_bilinear_is_the_normalised_convolution_of_each_lattice(lay: Layout) -> None:
    """Independent reference: scipy convolution of each (angle, colour) lattice, divided by
    the convolved sampling mask (mirrored borders), with the bilinear kernel of the lattice:
    the separable tent of radius = period for the rectangular lattices, the tent product
    along the two diagonals for the green quincunx of a colour layout (inside the image:
    the corners of a mirrored quincunx are a special case)."""
    rng = np.random.default_rng(11)
    raw = rng.uniform(0.0, 1.0, size=(H, W))
    p = lay.period
    t = np.concatenate([np.arange(1, p + 1), np.arange(p - 1, 0, -1)]) / p
    tent = np.outer(t, t)
    d = np.arange(-(p - 1), p)
    dx, dy = np.meshgrid(d, d)
    diag = np.maximum(0, 1 - np.abs(dx + dy) / p) * np.maximum(0, 1 - np.abs(dx - dy) / p)
    ai = lay.angle_index(H, W)
    ci = lay.channel_index(H, W)
    est = demosaic(raw.astype(np.float32), layout=lay, method="bilinear")
    for k in range(4):
        for c in range(3 if lay.is_color else 1):
            mask = ((ai == k) & (ci == c)).astype(np.float64)
            kernel = diag if lay.is_color and c == 1 else tent
            num = ndimage.convolve(raw * mask, kernel, mode="reflect")
            den = ndimage.convolve(mask, kernel, mode="reflect")
            got = est[k, ..., c] if lay.is_color else est[k]
            b = 4 if lay.is_color and c == 1 else 0
            ref = _interior(num, b) / _interior(den, b)
            np.testing.assert_allclose(_interior(got, b), ref, atol=1e-5)
