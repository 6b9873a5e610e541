"""Tests of the lmmse filter bank: layout mapping, the bank against a per-pixel reference,
the second stage's closed forms, the shipped weights' constraints, and its quality claim."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import polcam.demosaicing.lmmse as lm
from polcam.bench.lmmse_training import training_stack
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.errors import MethodError
from polcam.mosaic import Layout, parse_layout
from polcam.polarimetry import aolp, dolp
from polcam.synth.patterns import stack_from_stokes, uniform_scene

MZR = parse_layout("imx250mzr")
MYR = parse_layout("imx250myr")
B = 8

ALL_MONO = [Layout(p) for p in itertools.permutations((0, 45, 90, 135))]
ALL_COLOR = [Layout(p, bayer) for p in itertools.permutations((0, 45, 90, 135))
             for bayer in ("RGGB", "BGGR", "GRBG", "GBRG")]


def _interior(a: np.ndarray, b: int = B) -> np.ndarray:
    return a[b:a.shape[0] - b, b:a.shape[1] - b]


def _angle_diff(a: np.ndarray, b: float) -> np.ndarray:
    d = np.mod(np.asarray(a, np.float64) - b, np.pi)
    return np.minimum(d, np.pi - d)


@pytest.mark.parametrize("lay", ALL_MONO + ALL_COLOR, ids=lambda x: x.name)
def test_every_layout_maps_to_a_canonical_one(lay: Layout) -> None:
    """After the plan's transform and shift, the relabelled pattern is the canonical one."""
    for h, w in ((24, 32), (26, 30)):
        p = lm.plan(lay, h, w)
        a = lm._transform(lay.angle_index(h, w), p.transform)
        c = lm._transform(lay.channel_index(h, w), p.transform)
        hh, ww = a.shape
        sy, sx = p.shift
        ca = p.canonical.angle_index(hh + sy, ww + sx)[sy:, sx:]
        cc = p.canonical.channel_index(hh + sy, ww + sx)[sy:, sx:]
        np.testing.assert_array_equal(np.asarray(p.relabel)[a], ca)
        np.testing.assert_array_equal(c, cc)


def test_imx250_and_its_mirrors_map_physically() -> None:
    """IMX250 needs no transform; a mirrored read-out is mapped back by the mirror itself, with
    the physical relabelling (45 and 135 trade places), not by an arbitrary one."""
    for sensor in (MZR, MYR):
        p = lm.plan(sensor, 32, 32)
        assert p.transform == (False, False, False) and p.relabel == (0, 1, 2, 3)
        for rx, ry in ((True, False), (False, True)):
            lay = sensor.for_readout(reverse_x=rx, reverse_y=ry, width=30, height=22)
            p = lm.plan(lay, 22, 30)
            assert p.relabel in ((0, 3, 2, 1), (2, 1, 0, 3))  # a flip or a transpose


def _reference_bank(img: np.ndarray, weights: np.ndarray, channels: int) -> np.ndarray:
    """Per-pixel reference: the 12x12 neighbourhood of each block (lattice-mirrored), dot the weights."""
    h, w = img.shape
    rows = lm._mirror(np.arange(-4, h + 4), h, 4)
    cols = lm._mirror(np.arange(-4, w + 4), w, 4)
    pad = img[np.ix_(rows, cols)]
    out = np.zeros((4, h, w, channels))
    for by in range(h // 4):
        for bx in range(w // 4):
            nb = pad[4 * by:4 * by + 12, 4 * bx:4 * bx + 12]
            feats = nb.reshape(3, 4, 3, 4).transpose(0, 2, 1, 3).reshape(-1)
            y = (feats @ weights).reshape(4, 4, 4, channels)
            out[:, 4 * by:4 * by + 4, 4 * bx:4 * bx + 4] = y
    return out


@pytest.mark.parametrize("color", [False, True])
def test_bank_matches_a_per_pixel_reference(color: bool) -> None:
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 1, size=(24, 40)).astype(np.float32)
    channels = 3 if color else 1
    weights = rng.normal(size=(144, 64 * channels)).astype(np.float32)
    got = lm.apply_bank(img, weights, (0, 0), channels)
    np.testing.assert_allclose(got, _reference_bank(img, weights, channels), rtol=1e-4, atol=1e-4)
    # a crop starting one row and two columns into the pattern (phase shift (1, 2)): away from
    # its borders, the same values as the whole mosaic's at the same pixels
    got = lm.apply_bank(img[1:-3, 2:-2], weights, (1, 2), channels)
    np.testing.assert_allclose(got[:, 8:-8, 8:-8], _reference_bank(img, weights, channels)[:, 9:-11, 10:-10],
                               rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("key", ["mono_diag", "mono_beside", "color_diag", "color_beside"])
def test_shipped_weights_keep_the_constraints(key: str) -> None:
    """Own samples kept; each output's weights sum to 1 on its own lattice and 0 on the others;
    first and second moments about the output pixel vanish (so quadratic images come back)."""
    weights = lm.shipped_weights()[key].astype(np.float64)
    color = key.startswith("color")
    canon = parse_layout(lm.CANONICAL[(color, key.split("_")[1])])
    channels = 3 if color else 1
    assert weights.shape == (144, 64 * channels)
    lat = lm.lattice_of_taps(canon)
    off = lm.tap_offsets()
    ai, ci = canon.angle_index(4, 4), canon.channel_index(4, 4)
    for k, u, v, c in itertools.product(range(4), range(4), range(4), range(channels)):
        w = weights[:, ((k * 4 + u) * 4 + v) * channels + c]
        target = k * channels + c
        if ai[u, v] * channels + ci[u, v] == target:
            expected = np.zeros(144)
            expected[(3 + 1) * 16 + u * 4 + v] = 1.0
            np.testing.assert_allclose(w, expected, atol=1e-6)
            continue
        for lt in range(4 * channels):
            sel = lat == lt
            assert w[sel].sum() == pytest.approx(1.0 if lt == target else 0.0, abs=1e-4)
            assert float(w[sel] @ (off[sel, 0] - u)) == pytest.approx(0.0, abs=1e-3)
            assert float(w[sel] @ (off[sel, 1] - v)) == pytest.approx(0.0, abs=1e-3)
            dy, dx = off[sel, 0] - u, off[sel, 1] - v  # second moments (quadratic images exact)
            for poly in (dy * dy, dy * dx, dx * dx):
                assert float(w[sel] @ poly) == pytest.approx(0.0, abs=1e-4)


@pytest.mark.parametrize("lay", [MZR, MYR, ALL_MONO[5], ALL_COLOR[37]], ids=lambda x: x.name)
def test_affine_images_come_back(lay: Layout) -> None:
    """Each angle (and colour) image a different affine function: the bank is exact (first
    moments vanish); the ratio stage too where the ratio is constant."""
    h, w = 32, 40
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    rng = np.random.default_rng(2)
    shape = (4, h, w, 3) if lay.is_color else (4, h, w)
    truth = np.empty(shape, np.float32)
    for k in range(4):
        for c in range(3 if lay.is_color else 1):
            img = rng.uniform(0.2, 0.4) + rng.uniform(-4e-3, 4e-3) * x + rng.uniform(-4e-3, 4e-3) * y
            if lay.is_color:
                truth[k, ..., c] = img
            else:
                truth[k] = img
    raw = mosaic_stack(truth, layout=lay)
    h_, w_ = raw.shape
    p = lm.plan(lay, h_, w_)
    bank = lm.apply_bank(np.ascontiguousarray(lm._transform(raw, p.transform)), lm.shipped_weights()[p.key],
                         p.shift, 3 if lay.is_color else 1)
    bank = lm._untransform(bank[list(p.relabel)], p.transform)
    bank = bank if lay.is_color else bank[..., 0]
    np.testing.assert_allclose(bank[:, B:-B, B:-B], truth[:, B:-B, B:-B], atol=1e-4)


def test_ratio_stage_is_exact_when_only_the_intensity_is_textured() -> None:
    """S0 textured, DoLP and AoLP constant: the polarization ratio is constant, so with the true
    S0 as guide the second stage recovers every angle exactly, in every colour."""
    rng = np.random.default_rng(4)
    h, w = 32, 48
    s0 = rng.uniform(0.2, 0.9, size=(h, w, 3))
    truth = stack_from_stokes(s0, np.float64(0.7), np.float64(1.1)).astype(np.float32)
    raw = mosaic_stack(truth, layout=MYR)
    out = lm.second_stage(raw, truth, MYR, mode="ratio", sigma=2.0, eps=0.0)
    np.testing.assert_allclose(out, truth, rtol=1e-4, atol=1e-5)
    # the difference stage needs the polarization difference constant: not the case here
    diff = lm.second_stage(raw, truth, MYR, mode="difference", sigma=2.0, eps=0.0)
    assert float(np.abs(diff - truth).max()) > 1e-3


@pytest.mark.parametrize("period", [2, 4])
@pytest.mark.parametrize("sigma", [0.0, 1.5])
def test_tent_kernel_sums_and_centres_on_every_lattice_phase(period: int, sigma: float) -> None:
    """On a lattice of its period, the tent kernel's taps of every phase sum to 1 / period and
    have zero first moment (why normalised convolution with it keeps affine ratios)."""
    k = lm._tent_kernel(period, sigma).astype(np.float64)
    assert k.sum() == pytest.approx(1.0, abs=1e-6) and len(k) % 2 == 1
    d = np.arange(len(k)) - len(k) // 2
    for phase in range(period):
        sel = (d - phase) % period == 0
        assert k[sel].sum() == pytest.approx(1 / period, abs=1e-6)
        assert float(k[sel] @ d[sel]) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("lay", [MYR, MZR, ALL_COLOR[37]], ids=lambda x: x.name)
def test_tent_ratio_stage_is_exact_for_affine_polarization(lay: Layout) -> None:
    """Textured S0, S1 / S0 and S2 / S0 affine in x and y (different in every colour): with the
    true S0 as guide the tent kernel recovers every angle exactly inside the image; on the
    colour lattices (period 4) the Gaussian kernel bends the affine ratio (on the mono lattice,
    period 2, a Gaussian of 2 pixels is close enough to exact)."""
    rng = np.random.default_rng(6)
    h, w = 48, 56
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    c = 3 if lay.is_color else 1
    s0 = rng.uniform(0.3, 0.9, size=(h, w, c))
    f = 0.1 + (2e-3 * x - 3e-3 * y)[..., None] * np.arange(1, c + 1)  # S1 / S0
    g = -0.2 + (4e-3 * y + 1e-3 * x)[..., None] * np.ones(c)  # S2 / S0
    truth = 0.5 * s0 * np.stack([1 + f, 1 + g, 1 - f, 1 - g])
    truth = truth.astype(np.float32) if lay.is_color else truth[..., 0].astype(np.float32)
    raw = mosaic_stack(truth, layout=lay)
    guide = truth if lay.is_color else truth[..., None]
    tent = lm.second_stage(raw, guide, lay, mode="ratio", sigma=1.5, eps=0.0, kernel="tent")
    gauss = lm.second_stage(raw, guide, lay, mode="ratio", sigma=2.0, eps=0.0, kernel="gauss")
    t = guide[:, B:-B, B:-B]
    assert float(np.abs(tent[:, B:-B, B:-B] - t).max()) < 1e-5
    if lay.is_color:
        assert float(np.abs(gauss[:, B:-B, B:-B] - t).max()) > 1e-4
    with pytest.raises(MethodError, match="kernel"):
        lm.second_stage(raw, guide, lay, mode="ratio", sigma=1.0, eps=0.0, kernel="box")


@pytest.mark.parametrize("lay", ALL_MONO[::3] + ALL_COLOR[::7], ids=lambda x: x.name)
def test_known_aolp_for_every_arrangement_and_phase(lay: Layout) -> None:
    """A uniform scene comes back with its DoLP and AoLP for every arrangement, Bayer order and
    ROI phase (offsets of one and two pixels, mirrored read-outs)."""
    s0 = (0.3, 0.6, 0.9) if lay.is_color else 0.7
    scene = uniform_scene(40, 40, s0=s0, dolp=0.5, aolp=2.2)
    sensor_raw = mosaic_stack(scene.stack, layout=lay)
    step = 2 if lay.is_color else 1
    for ox, oy, rx, ry in ((0, 0, False, False), (step, 0, False, False), (0, step, True, False),
                           (step, step, False, True), (2 * step, 0, True, True)):
        img = sensor_raw[oy:oy + 32, ox:ox + 36]
        img = img[:, ::-1] if rx else img
        img = img[::-1] if ry else img
        ro = lay.for_readout(offset_x=ox, offset_y=oy, width=36, height=32, reverse_x=rx, reverse_y=ry)
        est = demosaic(np.ascontiguousarray(img), layout=ro, method="lmmse")
        expected = (np.pi - 2.2) % np.pi if rx != ry else 2.2
        assert float(_angle_diff(aolp(est), expected).max()) < 1e-3  # borders included
        np.testing.assert_allclose(dolp(est), 0.5, atol=1e-4)


def test_beats_bilinear_where_colours_differ_in_polarization() -> None:
    """On rendered scenes whose colours carry different polarization (drawn with seeds the
    shipped weights were not trained with), lmmse's colour DoLP is at least 1 dB above bilinear."""
    gains = []
    for seed in (101, 102, 103):
        truth = training_stack(np.random.default_rng(seed), 128)
        raw = mosaic_stack(truth, layout=MYR)
        t = truth[:, B:-B, B:-B]
        psnr = {}
        for method in ("bilinear", "lmmse"):
            e = demosaic(raw, layout=MYR, method=method)[:, B:-B, B:-B]
            mse = float(np.mean((dolp(e).astype(np.float64) - dolp(t)) ** 2))
            psnr[method] = 10 * np.log10(1 / mse)
        gains.append(psnr["lmmse"] - psnr["bilinear"])
    assert float(np.mean(gains)) >= 1.0, gains


def test_bank_guide_is_the_angle_mean_of_the_bank_bit_for_bit() -> None:
    """``apply_bank(guide=True)`` is ``stack.sum(axis=0) / 4`` of the full bank's result."""
    rng = np.random.default_rng(8)
    raw = rng.uniform(0.0, 1.0, size=(36, 44)).astype(np.float32)
    for lay in (MYR, MZR):
        channels = 3 if lay.is_color else 1
        p = lm.plan(lay, *raw.shape)
        img = np.ascontiguousarray(lm._transform(raw, p.transform))
        full = lm.apply_bank(img, lm.shipped_weights()[p.key], p.shift, channels)
        guide = lm.apply_bank(img, lm.shipped_weights()[p.key], p.shift, channels, guide=True)
        assert guide.shape == (1, *full.shape[1:])
        np.testing.assert_array_equal(guide[0], full.sum(axis=0) * np.float32(0.25))
