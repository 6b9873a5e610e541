"""Tests of polcam.demosaic: every method on every kind of layout, against known answers."""

from __future__ import annotations

import importlib

import cv2
import numpy as np
import pytest
from scipy import ndimage

from polcam.demosaic import DEMOSAIC_METHODS, demosaic, mosaic_stack, to_float
from polcam.errors import FrameReadError, LayoutError, MethodError
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout
from polcam.stokes import aolp, dolp, stokes
from polcam.synth.patterns import make_scene, stack_from_stokes, uniform_scene

dm = importlib.import_module("polcam.demosaic")  # the module (the package re-exports the function)

MZR = parse_layout("imx250mzr")
MYR = parse_layout("imx250myr")

# every family of layout: both IMX250 sensors, other 2x2 angle arrangements (orthogonal
# angles on the diagonal, side by side, one above the other), every Bayer phase, and the
# layouts of ROI-shifted and mirrored read-outs
LAYOUTS: list[Layout] = [
    MZR,
    MYR,
    parse_layout("mono:0,45,90,135"),  # 0 and 90 one above the other
    parse_layout("mono:0,90,45,135"),  # 0 and 90 side by side
    parse_layout("mono:135,90,45,0"),
    parse_layout("color:0,45,90,135:BGGR"),
    parse_layout("color:45,0,135,90:GRBG"),
    parse_layout("color:90,135,0,45:GBRG"),
    MZR.for_readout(offset_x=1, offset_y=0),
    MZR.for_readout(offset_x=1, offset_y=1, reverse_x=True, width=30),
    MYR.for_readout(offset_x=2, offset_y=0),
    MYR.for_readout(offset_x=0, offset_y=2, reverse_y=True, height=22),
    MYR.for_readout(reverse_x=True, reverse_y=True, width=26, height=18),
]
LAYOUT_IDS = [lay.name for lay in LAYOUTS]
H, W = 32, 48
B = 8  # interior: pixels this far from every edge


def _interior(a: np.ndarray, b: int = B) -> np.ndarray:
    return a[b:a.shape[0] - b, b:a.shape[1] - b]


def _angle_diff(a: np.ndarray, b: float) -> np.ndarray:
    """|a - b| on the circle of period pi."""
    d = np.mod(np.asarray(a, np.float64) - b, np.pi)
    return np.minimum(d, np.pi - d)


def _scene(lay: Layout, *, dolp_: float = 0.6, aolp_: float = 0.4):
    s0 = (0.3, 0.6, 0.9) if lay.is_color else 0.7
    return uniform_scene(H, W, s0=s0, dolp=dolp_, aolp=aolp_)


# ---------------------------------------------------------------------------
# known polarization comes back, for every layout, method and resolution
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("resolution", ["full", "cell"])
@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize("lay", LAYOUTS, ids=LAYOUT_IDS)
def test_uniform_scene_gives_its_aolp_and_dolp(lay: Layout, method: str, resolution: str) -> None:
    scene = _scene(lay)
    raw = mosaic_stack(scene.stack, layout=lay)
    est = demosaic(raw, layout=lay, method=method, resolution=resolution)
    b = B if resolution == "full" else B // 2
    d = _interior(dolp(est), b)
    a = _interior(aolp(est), b)
    s0 = _interior(stokes(est).s0, b)
    np.testing.assert_allclose(d, 0.6, atol=1e-4)
    assert float(_angle_diff(a, 0.4).max()) < 1e-3
    expected_s0 = np.broadcast_to(np.asarray((0.3, 0.6, 0.9) if lay.is_color else 0.7), s0.shape)
    np.testing.assert_allclose(s0, expected_s0, atol=1e-4)


@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize(
    ("sensor", "ox", "oy", "rx", "ry"),
    [
        ("imx250mzr", 1, 0, False, False),
        ("imx250mzr", 0, 1, True, False),
        ("imx250mzr", 3, 1, False, True),
        ("imx250myr", 2, 0, False, False),
        ("imx250myr", 2, 2, True, False),
        ("imx250myr", 0, 2, True, True),
    ],
)
def test_roi_and_mirrored_readout_of_a_sensor(sensor: str, ox: int, oy: int, rx: bool, ry: bool,
                                               method: str) -> None:
    """A camera cuts an ROI out of the sensor mosaic and mirrors it; demosaicking the
    delivered image with Layout.for_readout gives the scene's polarization in the image
    frame (a single mirror turns AoLP a into pi - a)."""
    sensor_lay = parse_layout(sensor)
    big_h, big_w = H + 8, W + 8
    true_aolp = 0.4
    s0 = (0.3, 0.6, 0.9) if sensor_lay.is_color else 0.7
    scene = uniform_scene(big_h, big_w, s0=s0, dolp=0.6, aolp=true_aolp)
    sensor_raw = mosaic_stack(scene.stack, layout=sensor_lay)
    img = sensor_raw[oy:oy + H, ox:ox + W]
    if rx:
        img = img[:, ::-1]
    if ry:
        img = img[::-1, :]
    lay = sensor_lay.for_readout(offset_x=ox, offset_y=oy, width=W, height=H, reverse_x=rx, reverse_y=ry)
    est = demosaic(np.ascontiguousarray(img), layout=lay, method=method)
    expected = (np.pi - true_aolp) % np.pi if rx != ry else true_aolp
    assert float(_angle_diff(_interior(aolp(est)), expected).max()) < 1e-3
    np.testing.assert_allclose(_interior(dolp(est)), 0.6, atol=1e-4)


@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize(("dolp_", "aolp_"), [(0.0, 0.0), (1.0, 0.0), (0.3, np.pi / 2), (0.9, 3.0)])
def test_range_of_polarization_states(method: str, dolp_: float, aolp_: float) -> None:
    for lay in (MZR, MYR):
        scene = _scene(lay, dolp_=dolp_, aolp_=aolp_)
        est = demosaic(mosaic_stack(scene.stack, layout=lay), layout=lay, method=method)
        np.testing.assert_allclose(_interior(dolp(est)), dolp_, atol=1e-4)
        if dolp_ > 0:
            assert float(_angle_diff(_interior(aolp(est)), aolp_).max()) < 1e-3


# ---------------------------------------------------------------------------
# properties every method must have
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("resolution", ["full", "cell"])
@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize("lay", [MZR, MYR, LAYOUTS[6], LAYOUTS[9]], ids=lambda x: x.name)
def test_constant_input_stays_constant(lay: Layout, method: str, resolution: str) -> None:
    raw = np.full((H, W), 0.37, np.float32)
    est = demosaic(raw, layout=lay, method=method, resolution=resolution)
    np.testing.assert_allclose(est, 0.37, atol=1e-6)


@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize("lay", LAYOUTS, ids=LAYOUT_IDS)
def test_known_samples_are_reproduced(lay: Layout, method: str) -> None:
    """At every pixel, the output at the pixel's own angle (and colour) is the raw sample."""
    rng = np.random.default_rng(7)
    raw = rng.uniform(0.0, 1.0, size=(H, W)).astype(np.float32)
    est = demosaic(raw, layout=lay, method=method)
    np.testing.assert_allclose(mosaic_stack(est, layout=lay), raw, atol=1e-5)


def _affine_stack(lay: Layout) -> np.ndarray:
    """Every angle (and colour) image a different affine function of x and y."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    shape = (4, H, W, 3) if lay.is_color else (4, H, W)
    out = np.empty(shape, np.float32)
    rng = np.random.default_rng(3)
    for k in range(4):
        for c in range(3 if lay.is_color else 1):
            a, bx, by = rng.uniform(0.2, 0.4), rng.uniform(-4e-3, 4e-3), rng.uniform(-4e-3, 4e-3)
            img = a + bx * x + by * y
            if lay.is_color:
                out[k, ..., c] = img
            else:
                out[k] = img
    return out


@pytest.mark.parametrize("lay", [MZR, LAYOUTS[3], LAYOUTS[9]], ids=lambda x: x.name)
@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
def test_mono_methods_are_exact_on_affine_images(lay: Layout, method: str) -> None:
    """Bilinear interpolation reproduces affine functions; so does EARI, whose guide is
    then the centred intensity and whose residual slope is 0 (no Laplacian energy)."""
    truth = _affine_stack(lay)
    est = demosaic(mosaic_stack(truth, layout=lay), layout=lay, method=method)
    np.testing.assert_allclose(est[:, B:-B, B:-B], truth[:, B:-B, B:-B], atol=2e-5)


def test_bilinear_colour_is_exact_on_affine_images() -> None:
    truth = _affine_stack(MYR)
    est = demosaic(mosaic_stack(truth, layout=MYR), layout=MYR, method="bilinear")
    np.testing.assert_allclose(est[:, 6:-6, 6:-6], truth[:, 6:-6, 6:-6], atol=2e-5)


@pytest.mark.parametrize("lay", [MZR, MYR, LAYOUTS[7]], ids=lambda x: x.name)
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


# ---------------------------------------------------------------------------
# EARI internals against the paper's own formulation
# ---------------------------------------------------------------------------

def test_eari_guide_matches_the_papers_kernels_on_imx250() -> None:
    """Morimatsu et al.'s guide for the 90 45 / 135 0 cell, written with their 3x3
    directional kernels and one-sided 5x3 smoothing windows, equals the fast one inside."""
    rng = np.random.default_rng(5)
    img = rng.uniform(0.0, 1.0, size=(40, 56)).astype(np.float32)
    eps = 1e-3
    fn = np.array([[1, 2, 1], [1, 2, 1], [0, 0, 0]], np.float32) / 8
    hn = np.array([[-0.5, 1, -0.5], [0.5, -1, 0.5], [0, 0, 0]], np.float32)
    mn = np.zeros((5, 5), np.float32)
    mn[:3] = 1 / 15
    kernels = {
        "n": (fn, hn, mn),
        "s": (fn[::-1], hn[::-1], mn[::-1]),
        "w": (fn.T, hn.T, mn.T),
        "e": (fn[::-1].T, hn[::-1].T, mn[::-1].T),
    }
    num = np.zeros_like(img, np.float64)
    den = np.zeros_like(img, np.float64)
    for kx, kh, km in kernels.values():
        x = cv2.filter2D(img.astype(np.float64), cv2.CV_64F, kx)
        d = cv2.filter2D(np.abs(cv2.filter2D(img.astype(np.float64), cv2.CV_64F, kh)), cv2.CV_64F, km)
        wgt = 1.0 / (d + eps)
        num += wgt * x
        den += wgt
    ref = num / den
    got = dm._eari_guide(img, MZR, eps)
    np.testing.assert_allclose(_interior(got, 6), _interior(ref, 6), rtol=1e-4, atol=1e-5)


def test_eari_strips_do_not_change_the_result(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(9)
    raw = rng.uniform(0.0, 1.0, size=(96, 64)).astype(np.float32)
    whole = demosaic(raw, layout=MZR, method="eari")
    monkeypatch.setattr(dm, "_STRIP", 16)
    strips = demosaic(raw, layout=MZR, method="eari")
    np.testing.assert_allclose(strips, whole, atol=1e-5)


def test_eari_alternative_colour_stage(monkeypatch: pytest.MonkeyPatch) -> None:
    """The Malvar-He-Cutler colour stage kept as an option is exact on piecewise-constant
    colours (its kernels' weights per colour sum to 1 or 0) and keeps the samples."""
    monkeypatch.setitem(dm.EARI_PARAMS, "color_stage", "mhc")
    for lay in (MYR, LAYOUTS[7]):
        scene = _scene(lay)
        est = demosaic(mosaic_stack(scene.stack, layout=lay), layout=lay, method="eari")
        np.testing.assert_allclose(_interior(dolp(est)), 0.6, atol=1e-4)
        assert float(_angle_diff(_interior(aolp(est)), 0.4).max()) < 1e-3
        raw = np.random.default_rng(4).uniform(0, 1, size=(H, W)).astype(np.float32)
        out = demosaic(raw, layout=lay, method="eari")
        np.testing.assert_allclose(mosaic_stack(out, layout=lay), raw, atol=1e-5)


# ---------------------------------------------------------------------------
# the quality claim, on data made independently of the method
# ---------------------------------------------------------------------------

def _psnr(est: np.ndarray, ref: np.ndarray, data_range: float) -> float:
    mse = float(np.mean((est.astype(np.float64) - ref) ** 2))
    return 10.0 * np.log10(data_range**2 / mse)


@pytest.mark.parametrize("lay", [MZR, MYR], ids=["mono", "colour"])
def test_eari_beats_bilinear_on_textured_scenes(lay: Layout) -> None:
    """Mean over three seeds of a 128x128 textured scene: EARI at least 1 dB above
    bilinear in PSNR of S0 and of DoLP."""
    gains = []
    for seed in range(3):
        truth = make_scene("textured", height=128, width=128, seed=seed, color=lay.is_color).stack
        raw = mosaic_stack(truth, layout=lay)
        t = truth[:, B:-B, B:-B]
        scores = {}
        for method in ("bilinear", "eari"):
            e = demosaic(raw, layout=lay, method=method)[:, B:-B, B:-B]
            scores[method] = (_psnr(stokes(e).s0, stokes(t).s0, 2.0), _psnr(dolp(e), dolp(t), 1.0))
        gains.append(np.subtract(scores["eari"], scores["bilinear"]))
    mean_gain = np.mean(gains, axis=0)
    assert mean_gain[0] >= 1.0, f"S0 gain {mean_gain[0]:.2f} dB"
    assert mean_gain[1] >= 1.0, f"DoLP gain {mean_gain[1]:.2f} dB"


# ---------------------------------------------------------------------------
# shapes, dtypes, errors
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_shapes_and_dtypes(method: str, dtype: type) -> None:
    rng = np.random.default_rng(1)
    if np.issubdtype(dtype, np.integer):
        raw = rng.integers(0, np.iinfo(dtype).max, size=(H, W), dtype=dtype)
    else:
        raw = rng.uniform(0, 1, size=(H, W)).astype(dtype)
    for lay, full, cell in ((MZR, (4, H, W), (4, H // 2, W // 2)),
                            (MYR, (4, H, W, 3), (4, H // 2, W // 2, 3))):
        a = demosaic(raw, layout=lay, method=method)
        c = demosaic(raw, layout=lay, method=method, resolution="cell")
        assert a.shape == full and a.dtype == np.float32 and a.flags.c_contiguous
        assert c.shape == cell and c.dtype == np.float32


def test_integer_input_is_scaled_by_its_range() -> None:
    raw = np.full((H, W), 1000, np.uint16)
    for method in DEMOSAIC_METHODS:
        np.testing.assert_allclose(demosaic(raw, layout=MZR, method=method), 1000 / 65535, rtol=1e-6)


def test_frame_input_uses_its_layout_and_levels() -> None:
    frame = Frame(np.full((H, W), 2058, np.uint16), layout="imx250mzr", bit_depth=12,
                  black_level=10, white_level=4106)
    for method in DEMOSAIC_METHODS:
        np.testing.assert_allclose(demosaic(frame, method=method), 0.5, atol=1e-6)


def test_cell_resolution_mono_is_the_cell_samples() -> None:
    rng = np.random.default_rng(2)
    raw = rng.uniform(0, 1, size=(H, W)).astype(np.float32)
    for method in DEMOSAIC_METHODS:
        c = demosaic(raw, layout=MZR, method=method, resolution="cell")
        # IMX250MZR cell: 90 45 / 135 0
        np.testing.assert_array_equal(c[2], raw[0::2, 0::2])
        np.testing.assert_array_equal(c[1], raw[0::2, 1::2])
        np.testing.assert_array_equal(c[3], raw[1::2, 0::2])
        np.testing.assert_array_equal(c[0], raw[1::2, 1::2])


@pytest.mark.parametrize("shape", [(31, 48), (32, 47), (31, 47)])
def test_odd_dimensions_are_refused(shape: tuple[int, int]) -> None:
    raw = np.zeros(shape, np.float32)
    for method in DEMOSAIC_METHODS:
        with pytest.raises(LayoutError, match="even dimensions"):
            demosaic(raw, layout=MZR, method=method)


def test_too_small_mosaics_are_refused() -> None:
    with pytest.raises(LayoutError, match="at least 8"):
        demosaic(np.zeros((6, 16), np.float32), layout=MYR)
    with pytest.raises(LayoutError, match="at least 4"):
        demosaic(np.zeros((2, 16), np.float32), layout=MZR)


def test_unknown_method_and_resolution_are_refused() -> None:
    raw = np.zeros((H, W), np.float32)
    with pytest.raises(MethodError, match="'newton'.*bilinear"):
        demosaic(raw, layout=MZR, method="newton")
    with pytest.raises(MethodError, match="'quarter'"):
        demosaic(raw, layout=MZR, resolution="quarter")
    with pytest.raises(MethodError):  # the method is checked whatever the resolution
        demosaic(raw, layout=MZR, method="newton", resolution="cell")


def test_bad_raw_arrays_are_refused() -> None:
    with pytest.raises(LayoutError, match="no layout"):
        demosaic(np.zeros((H, W), np.float32))
    with pytest.raises(FrameReadError, match="2-D"):
        demosaic(np.zeros((H, W, 3), np.float32), layout=MZR)
    bad = np.zeros((H, W), np.float32)
    bad[3, 4] = np.nan
    with pytest.raises(FrameReadError, match="NaN"):
        demosaic(bad, layout=MZR)
    with pytest.raises(FrameReadError, match="dtype"):
        demosaic(np.zeros((H, W), complex), layout=MZR)
    with pytest.raises(FrameReadError, match="white level"):
        to_float(np.zeros((H, W), np.uint8), black_level=10, white_level=10)


def test_mosaic_stack_samples_the_layout() -> None:
    stack = np.arange(4 * 4 * 4 * 3, dtype=np.float32).reshape(4, 4, 4, 3)
    raw = mosaic_stack(stack, layout=MYR)
    # IMX250MYR: R90 R45 G90 G45 / R135 R0 G135 G0 / G90 G45 B90 B45 / G135 G0 B135 B0
    assert raw[0, 0] == stack[2, 0, 0, 0] and raw[0, 1] == stack[1, 0, 1, 0]
    assert raw[0, 2] == stack[2, 0, 2, 1] and raw[1, 1] == stack[0, 1, 1, 0]
    assert raw[2, 2] == stack[2, 2, 2, 2] and raw[3, 3] == stack[0, 3, 3, 2]
    assert raw[3, 1] == stack[0, 3, 1, 1]
    with pytest.raises(MethodError, match=r"\(4, H, W, 3\)"):
        mosaic_stack(stack[..., 0], layout=MYR)
    with pytest.raises(MethodError, match=r"\(4, H, W\)"):
        mosaic_stack(stack, layout=MZR)


def test_stack_from_stokes_round_trip_through_bilinear_cells() -> None:
    """A sanity link between the synthetic model and demosaicking: cell-resolution
    stacks of a uniform scene are exactly the model's four intensities."""
    st = stack_from_stokes(np.full((H, W), 0.8), np.float64(0.5), np.float64(1.0))
    c = demosaic(mosaic_stack(st, layout=MZR), layout=MZR, resolution="cell")
    want = 0.4 * (1 + 0.5 * np.cos(2 * np.deg2rad([0, 45, 90, 135]) - 2.0))
    np.testing.assert_allclose(c[:, 3, 3], want, atol=1e-6)
