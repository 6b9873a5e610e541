"""Tests of lmmse's shared-ratio second stage (colour): the lattice smoothing's exactness,
exactness for polarization that differs between colours (uniform, and affine ratios under a
textured S0), and its gain where the colours share detailed polarization."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import polcam.demosaicing.lmmse as lm
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.demosaicing._shared_ratio import _filter_at_samples, lattice_filter, lattice_smooth, shared_ratio_stage
from polcam.errors import MethodError
from polcam.mosaic import Layout, parse_layout
from polcam.polarimetry import aolp, dolp

MYR = parse_layout("imx250myr")
MZR = parse_layout("imx250mzr")
B = 8
COLOR_LAYOUTS = [MYR, Layout((0, 45, 90, 135), "BGGR"), Layout((45, 0, 135, 90), "GBRG"),
                 MYR.for_readout(offset_x=2, offset_y=0), MYR.for_readout(reverse_x=True, width=44, height=40)]
PARAMS = {"common_sigma": 1.2, "offset_sigma": 24.0, "residual_sigma": 4.0, "eps": 0.0}


def _stack(s0: np.ndarray, s1n: np.ndarray, s2n: np.ndarray) -> np.ndarray:
    """(4, H, W, C) float32 from S0 and the normalised Stokes s1 = S1 / S0, s2 = S2 / S0."""
    s1n, s2n = np.broadcast_to(s1n, s0.shape), np.broadcast_to(s2n, s0.shape)
    return (0.5 * s0 * np.stack([1 + s1n, 1 + s2n, 1 - s1n, 1 - s2n])).astype(np.float32)


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.mod(np.asarray(a, np.float64) - b, np.pi)
    return np.minimum(d, np.pi - d)


@pytest.mark.parametrize(("period", "offsets"), [(4, [(1, 2)]), (4, [(0, 1), (2, 3)]), (2, [(1, 0)])])
@pytest.mark.parametrize("sigma", [0.0, 3.0, 24.0])
def test_lattice_smoothing_keeps_affine_and_constant_images(period: int, offsets: list, sigma: float) -> None:
    h, w = 44, 52
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    affine = np.float32(0.4) + np.float32(3e-3) * x - np.float32(5e-3) * y
    out = lattice_smooth(affine, offsets, period, sigma)
    np.testing.assert_allclose(out[B:-B, B:-B], affine[B:-B, B:-B], atol=1e-5)
    const = np.full((h, w), 0.3, np.float32)
    np.testing.assert_allclose(lattice_smooth(const, offsets, period, sigma), 0.3, atol=1e-6)
    # and it smooths: noise on the samples shrinks with sigma
    noise = np.random.default_rng(1).normal(0, 1, (h, w)).astype(np.float32)
    sm = lattice_smooth(noise, offsets, period, sigma)
    for oy, ox in offsets:  # sigma 0 interpolates: the samples come back
        if sigma == 0 and len(offsets) == 1:
            np.testing.assert_allclose(sm[oy::period, ox::period], noise[oy::period, ox::period], atol=1e-5)
        elif sigma > 0:
            assert float(np.std(sm[B:-B, B:-B])) < 0.5


@pytest.mark.parametrize("offset", [(0, 0), (1, 0), (0, 1), (1, 1)])
@pytest.mark.parametrize("sigma", [0.0, 1.2, 3.0])
def test_lattice_filter_is_exact_on_affine_images_and_matches_its_value_at_the_samples(
        offset: tuple[int, int], sigma: float) -> None:
    """The shared ratio's filter T: affine images exact at every pixel (borders included); with
    sigma 0 it interpolates the samples; the stage's shortcut for T at the samples
    (``_filter_at_samples``) equals T there."""
    h, w = 30, 38
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    affine = np.float32(0.5) - np.float32(4e-3) * x + np.float32(7e-3) * y
    np.testing.assert_allclose(lattice_filter(affine, offset, 2, sigma), affine, atol=2e-6)
    noise = np.random.default_rng(4).normal(0, 1, (h, w)).astype(np.float32)
    full = lattice_filter(noise, offset, 2, sigma)
    oy, ox = offset
    at = _filter_at_samples(np.ascontiguousarray(noise[oy::2, ox::2]), 2, sigma)
    np.testing.assert_allclose(at, full[oy::2, ox::2], atol=1e-5)
    if sigma == 0:
        np.testing.assert_allclose(full[oy::2, ox::2], noise[oy::2, ox::2], atol=1e-6)
    else:  # a smoothing filter: the samples do not come back
        assert float(np.abs(full[oy::2, ox::2] - noise[oy::2, ox::2]).max()) > 0.1


@pytest.mark.parametrize("lay", COLOR_LAYOUTS, ids=lambda x: x.name)
def test_uniform_polarization_different_in_every_colour_comes_back(lay: Layout) -> None:
    """Every colour its own uniform DoLP and AoLP (Umov's effect, coloured filters): the shipped
    lmmse (bank + shared-ratio stage) returns each exactly.  Interpolating all colours' ratios
    together without removing each colour's offset first fails this by several degrees."""
    h, w = 40, 44
    dolp_ = np.array([0.4, 0.25, 0.1])
    aolp_ = np.array([0.4, 0.5, 0.6])
    s0 = np.broadcast_to(np.array([0.3, 0.6, 0.9]), (h, w, 3))
    truth = _stack(s0, dolp_ * np.cos(2 * aolp_), dolp_ * np.sin(2 * aolp_))
    raw = mosaic_stack(truth, layout=lay)
    est = demosaic(raw, layout=lay, method="lmmse")[:, B:-B, B:-B]
    np.testing.assert_allclose(dolp(est), np.broadcast_to(dolp_, est.shape[1:]), atol=1e-4)
    assert float(_angle_diff(aolp(est), aolp_).max()) < 1e-3
    np.testing.assert_allclose(est, truth[:, B:-B, B:-B], atol=1e-5)


@pytest.mark.parametrize(("h", "w"), [(42, 46), (8, 8), (10, 12)])
def test_uniform_polarization_per_colour_is_exact_up_to_the_borders(h: int, w: int) -> None:
    """The lattice filters extend point-symmetrically, so the exactness holds at every pixel,
    borders included, also for sizes that are not multiples of the 4-pixel period."""
    s0 = np.broadcast_to(np.array([0.3, 0.6, 0.9]), (h, w, 3))
    dolp_, aolp_ = np.array([0.4, 0.25, 0.1]), np.array([0.4, 0.5, 0.6])
    truth = _stack(s0, dolp_ * np.cos(2 * aolp_), dolp_ * np.sin(2 * aolp_))
    est = demosaic(mosaic_stack(truth, layout=MYR), layout=MYR, method="lmmse")
    np.testing.assert_allclose(est, truth, atol=1e-5)


@pytest.mark.parametrize("lay", COLOR_LAYOUTS, ids=lambda x: x.name)
def test_affine_ratios_of_every_colour_come_back_under_a_textured_s0(lay: Layout) -> None:
    """Textured S0, and s1, s2 affine in x and y with a different plane in every colour: with the
    true S0 as guide the stage is exact inside the image, and keeps every own sample."""
    rng = np.random.default_rng(6)
    h, w = 48, 56
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    s0 = rng.uniform(0.3, 0.9, size=(h, w, 3))
    s1n = 0.1 + (2e-3 * x - 3e-3 * y)[..., None] * np.arange(1, 4)
    s2n = np.array([-0.2, 0.05, 0.3]) + (4e-3 * y + 1e-3 * x)[..., None]
    truth = _stack(s0, s1n, s2n)
    raw = mosaic_stack(truth, layout=lay)
    out = shared_ratio_stage(raw, truth, lay, **PARAMS)
    assert float(np.abs(out[:, B:-B, B:-B] - truth[:, B:-B, B:-B]).max()) < 2e-5
    np.testing.assert_array_equal(mosaic_stack(out, layout=lay), raw)


def test_shared_detail_is_resolved_better_than_by_each_colour_alone() -> None:
    """AoLP varying across the image with a period of 12 pixels, shared by the colours (DoLP
    different in each): each colour's own lattice (one sample in 4 x 4 pixels) aliases it, the
    samples of all colours (one in 2 x 2) do not.  With the true S0 as guide, the shared-ratio
    stage's mean AoLP error is well below the per-colour ratio stage's (tent
    kernel): measured 0.105 against 0.202 rad (about 0.52 of it at periods of 8 to 12 pixels)."""
    rng = np.random.default_rng(3)
    h, w = 64, 72
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    s0 = rng.uniform(0.3, 0.9, size=(h, w, 3))
    theta = 0.8 * np.sin(2 * np.pi * (x + 0.5 * y) / 12)
    dl = np.array([0.5, 0.35, 0.2])
    truth = _stack(s0, dl * np.cos(2 * theta)[..., None], dl * np.sin(2 * theta)[..., None])
    raw = mosaic_stack(truth, layout=MYR)
    t = truth[:, B:-B, B:-B]
    shared = shared_ratio_stage(raw, truth, MYR, **PARAMS)[:, B:-B, B:-B]
    ratio = lm.second_stage(raw, truth, MYR, mode="ratio", sigma=1.5, eps=0.0, kernel="tent")[:, B:-B, B:-B]
    err = {name: float(np.mean(_angle_diff(aolp(e), aolp(t)))) for name, e in (("shared", shared), ("ratio", ratio))}
    assert err["shared"] < 0.6 * err["ratio"], err


def test_default_colour_stage_is_the_shared_ratio() -> None:
    """The shipped lmmse runs the bank and then this stage on colour layouts."""
    assert lm.LMMSE_PARAMS["color_stage"] == "shared-ratio"
    rng = np.random.default_rng(2)
    raw = rng.uniform(0.1, 0.9, size=(32, 40)).astype(np.float32)
    p = lm.plan(MYR, *raw.shape)
    bank = lm.apply_bank(np.ascontiguousarray(lm._transform(raw, p.transform)), lm.shipped_weights()[p.key], p.shift, 3)
    bank = np.ascontiguousarray(lm._untransform(bank[list(p.relabel)], p.transform))
    expected = shared_ratio_stage(raw, bank, MYR, common_sigma=float(lm.LMMSE_PARAMS["common_sigma"]),
                                  offset_sigma=float(lm.LMMSE_PARAMS["offset_sigma"]),
                                  residual_sigma=float(lm.LMMSE_PARAMS["residual_sigma"]),
                                  eps=float(lm.LMMSE_PARAMS["ratio_eps"]))
    np.testing.assert_allclose(demosaic(raw, layout=MYR, method="lmmse"), expected, atol=1e-6)


def test_mono_layout_is_refused() -> None:
    raw = np.full((16, 16), 0.5, np.float32)
    with pytest.raises(MethodError, match="mono"):
        shared_ratio_stage(raw, np.full((4, 16, 16, 1), 0.5, np.float32), MZR, **PARAMS)


def test_every_colour_layout_keeps_its_own_samples() -> None:
    """All 96 colour layouts: the stage keeps the raw at every pixel's own angle and colour."""
    rng = np.random.default_rng(5)
    raw = rng.uniform(0.1, 0.9, size=(24, 28)).astype(np.float32)
    guide = rng.uniform(0.2, 0.8, size=(4, 24, 28, 3)).astype(np.float32)
    for perm, bayer in itertools.product(itertools.permutations((0, 45, 90, 135)), ("RGGB", "BGGR", "GRBG", "GBRG")):
        lay = Layout(perm, bayer)
        out = shared_ratio_stage(raw, guide, lay, **PARAMS)
        np.testing.assert_array_equal(mosaic_stack(out, layout=lay), raw)


def test_odd_dimensions_are_refused() -> None:
    raw = np.full((18, 17), 0.5, np.float32)
    with pytest.raises(MethodError, match="17x18 pixels, expected even"):
        shared_ratio_stage(raw, np.full((4, 18, 17, 3), 0.5, np.float32), MYR, **PARAMS)
