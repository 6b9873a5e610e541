"""Contract tests generated from the registry: every demosaicing method, every kind of layout,
against known answers (a method registered later is tested here without a new test)."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.demosaicing import DEMOSAIC_METHODS, demosaic, mosaic_stack
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout
from polcam.polarimetry import aolp, dolp, stokes
from polcam.synth.patterns import uniform_scene

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


@pytest.mark.parametrize("lay", [MZR, LAYOUTS[3], LAYOUTS[9]], ids=lambda x: x.name)
@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
def test_mono_methods_are_exact_on_affine_images(lay: Layout, method: str, affine_stack) -> None:
    """Bilinear interpolation reproduces affine functions; so does EARI, whose guide is
    then the centred intensity and whose residual slope is 0 (no Laplacian energy)."""
    truth = affine_stack(lay, H, W)
    est = demosaic(mosaic_stack(truth, layout=lay), layout=lay, method=method)
    np.testing.assert_allclose(est[:, B:-B, B:-B], truth[:, B:-B, B:-B], atol=2e-5)


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
