"""Layouts, their geometry under ROI offsets and mirroring, and the pixel-format registry."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from polcam.demosaicing import demosaic
from polcam.errors import LayoutError, PixelFormatError
from polcam.mosaic import (
    ANGLES,
    PIXEL_FORMATS,
    Layout,
    layout_for_format,
    parse_layout,
    pixel_format,
    supported_pixel_formats,
)
from polcam.polarimetry import aolp, dolp


def test_named_layouts_match_the_sensor_datasheet():
    # IMX250MZR: row 0 = 90 45, row 1 = 135 0
    mzr = parse_layout("imx250mzr")
    np.testing.assert_array_equal(
        np.array(ANGLES)[mzr.angle_index(2, 2)], [[90, 45], [135, 0]]
    )
    assert not mzr.is_color and mzr.period == 2
    # IMX250MYR 4x4: R90 R45 G90 G45 / R135 R0 G135 G0 / G90 G45 B90 B45 / G135 G0 B135 B0
    myr = parse_layout("IMX250MYR")
    ang = np.array(ANGLES)[myr.angle_index(4, 4)]
    col = np.array(list("RGB"))[myr.channel_index(4, 4)]
    got = [[f"{c}{a}" for c, a in zip(crow, arow)] for crow, arow in zip(col, ang)]
    assert got == [
        ["R90", "R45", "G90", "G45"],
        ["R135", "R0", "G135", "G0"],
        ["G90", "G45", "B90", "B45"],
        ["G135", "G0", "B135", "B0"],
    ]


@pytest.mark.parametrize(
    "text",
    ["imx250mzr", "imx250myr", "mono:0,45,135,90", "color:45,90,0,135:GBRG", "colour:90,45,135,0:bggr"],
)
def test_parse_and_name_round_trip(text):
    lay = parse_layout(text)
    assert parse_layout(lay.name) == lay
    assert parse_layout(lay.short_name) == lay


@pytest.mark.parametrize(
    "text, phrase",
    [
        ("imx999", "not understood"),
        ("mono:0,45,90,90", "not a permutation"),
        ("mono:0,45,90,135:RGGB", "no Bayer order"),
        ("color:0,45,90,135", "needs a Bayer order"),
        ("color:0,45,90,135:RGBX", "Bayer order"),
        ("mono:0,30,90,135", "not a permutation"),
    ],
)
def test_bad_layouts_are_refused_with_the_reason(text, phrase):
    with pytest.raises(LayoutError, match=phrase):
        parse_layout(text)


def _readout(sensor_map: np.ndarray, ox: int, oy: int, w: int, h: int, rx: bool, ry: bool) -> np.ndarray:
    """Cut an ROI from a per-pixel sensor map and mirror it (independent of Layout)."""
    roi = sensor_map[oy:oy + h, ox:ox + w]
    if rx:
        roi = roi[:, ::-1]
    if ry:
        roi = roi[::-1, :]
    return roi


def _mirror_label(angle: np.ndarray, times: int) -> np.ndarray:
    return (180 - angle) % 180 if times % 2 else angle


@pytest.mark.parametrize("name", ["imx250mzr", "imx250myr", "color:45,0,90,135:GRBG"])
def test_roi_and_mirroring_keep_every_pixel_labelled_right(name):
    sensor = parse_layout(name)
    H, W = 24, 28
    s_angle = np.array(ANGLES)[sensor.angle_index(H, W)]
    s_col = sensor.channel_index(H, W)
    step = 2 if sensor.is_color else 1
    for ox, oy, rx, ry, w, h in itertools.product(
        range(0, 6, step), range(0, 6, step), (False, True), (False, True), (12, 14), (8, 10)
    ):
        if sensor.is_color and (w % 2 or h % 2):
            continue
        lay = sensor.for_readout(offset_x=ox, offset_y=oy, width=w, height=h, reverse_x=rx, reverse_y=ry)
        want_angle = _mirror_label(_readout(s_angle, ox, oy, w, h, rx, ry), int(rx) + int(ry))
        want_col = _readout(s_col, ox, oy, w, h, rx, ry)
        np.testing.assert_array_equal(np.array(ANGLES)[lay.angle_index(h, w)], want_angle,
                                      err_msg=f"{name} roi ({ox},{oy},{w},{h}) reverse {rx},{ry}")
        np.testing.assert_array_equal(lay.channel_index(h, w), want_col)


def test_colour_roi_offset_of_two_swaps_red_and_green():
    lay = parse_layout("imx250myr").shifted(2, 0)
    assert lay.bayer == "GRBG"
    assert lay.angles == (90, 45, 135, 0)


def test_odd_offset_on_colour_is_refused():
    with pytest.raises(LayoutError, match="odd offset"):
        parse_layout("imx250myr").for_readout(offset_x=1)


@pytest.mark.parametrize("name", ["imx250mzr", "imx250myr"])
@pytest.mark.parametrize("theta_deg", [10.0, 60.0, 100.0, 160.0])
@pytest.mark.parametrize("rx, ry, ox, oy", [(False, False, 0, 0), (True, False, 2, 0),
                                            (False, True, 0, 4), (True, True, 4, 2)])
def test_aolp_is_reported_in_the_image_frame(name, theta_deg, rx, ry, ox, oy):
    """Uniform light polarized at theta on the sensor; mirrored readouts see -theta."""
    sensor = parse_layout(name)
    H, W = 40, 48
    theta = np.deg2rad(theta_deg)
    rho = 0.6
    a = np.deg2rad(np.array(ANGLES)[sensor.angle_index(H, W)])
    sensor_img = 0.4 * (1 + rho * np.cos(2 * a - 2 * theta))
    w, h = 32, 24
    img = _readout(sensor_img, ox, oy, w, h, rx, ry)
    lay = sensor.for_readout(offset_x=ox, offset_y=oy, width=w, height=h, reverse_x=rx, reverse_y=ry)
    stack = demosaic(img.astype(np.float32), layout=lay, method="bilinear")
    expect = theta_deg if (int(rx) + int(ry)) % 2 == 0 else (180 - theta_deg) % 180
    got = np.rad2deg(aolp(stack))[4:-4, 4:-4]
    diff = np.abs((got - expect + 90) % 180 - 90)
    assert diff.max() < 0.05
    np.testing.assert_allclose(dolp(stack)[4:-4, 4:-4], rho, atol=1e-4)


def test_pixel_formats_are_looked_up_by_name_and_vendor():
    lucid = pixel_format("PolarizeMono12p", "LUCID Vision Labs")
    assert (lucid.bit_depth, lucid.packing, lucid.kind) == (12, "12p", "polar-mono")
    assert layout_for_format(lucid) == parse_layout("imx250mzr")
    flir = pixel_format("BayerRGPolarized8", "Teledyne FLIR LLC")
    assert layout_for_format(flir) == parse_layout("imx250myr")
    tis = pixel_format("PolarizedBayerBG8", "The Imaging Source Europe GmbH")
    assert layout_for_format(tis).bayer == "BGGR"  # the vendor's colour phase, not the MYR default
    # standard names work for any vendor, the layout must then be given
    mono = pixel_format("Mono12Packed", "Basler")
    assert mono.packing == "12packed"
    with pytest.raises(LayoutError, match="--layout"):
        layout_for_format(mono)
    assert layout_for_format(mono, "imx250mzr") == parse_layout("imx250mzr")


def test_same_code_different_vendors_is_never_resolved_by_number():
    # LUCID's PolarizeMono8 shares 0x81080001 with other vendors' formats: the registry keys by name+vendor
    codes = [f for f in PIXEL_FORMATS.values() if f.code == 0x81080001]
    assert [f.name for f in codes] == ["PolarizeMono8"]
    with pytest.raises(PixelFormatError, match="not supported"):
        pixel_format("PolarizeMono8", "The Imaging Source Europe GmbH")
    with pytest.raises(PixelFormatError, match="Polarized8"):
        pixel_format("Polarized8", "LUCID Vision Labs")


def test_unknown_pixel_format_lists_the_supported_ones():
    with pytest.raises(PixelFormatError) as err:
        pixel_format("YUV422_8", "FLIR")
    assert "YUV422_8" in str(err.value) and "BayerRGPolarized12p" in str(err.value)
    assert "PolarizeMono8" not in supported_pixel_formats("FLIR")


def test_derived_and_angle_formats():
    stokes_fmt = pixel_format("PolarizedStokes_S0_S1_S2_Mono8", "LUCID Vision Labs")
    with pytest.raises(PixelFormatError, match="raw polarization format"):
        layout_for_format(stokes_fmt)
    planes = pixel_format("PolarizedAngles_0d_45d_90d_135d_BayerRG8", "LUCID Vision Labs")
    assert planes.frame_bytes(8, 4) == 8 * 4 * 4
    assert layout_for_format(planes) == parse_layout("color:0,45,135,90:RGGB")


@pytest.mark.parametrize("packing_name, w, h, expect", [
    ("Mono8", 2448, 2048, 2448 * 2048),
    ("Mono12p", 2448, 2048, 2448 * 2048 * 3 // 2),
    ("Mono10p", 2448, 2048, 2448 * 2048 * 5 // 4),
    ("Mono16", 2448, 2048, 2448 * 2048 * 2),
])
def test_frame_bytes(packing_name, w, h, expect):
    assert pixel_format(packing_name).frame_bytes(w, h) == expect


def test_layout_value_object():
    assert Layout((90, 45, 135, 0)) == parse_layout("imx250mzr")
    assert str(parse_layout("mono:90,45,135,0")) == "imx250mzr"
    with pytest.raises(LayoutError):
        Layout((0, 0, 0, 0))
