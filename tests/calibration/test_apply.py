"""Tests of polcam.calibration.apply: mosaic corrections, polarimetric correction, Stokes errors."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.calibration import _scene, make_calibration, stokes_errors
from polcam.calibration.apply import apply_calibration, correct_stack, effective_model, fill_defects
from polcam.calibration.model import nominal_orientation
from polcam.calibration.store import Calibration, CalibrationError
from polcam.demosaicing import demosaic
from polcam.frame import Frame
from polcam.mosaic import parse_layout
from polcam.polarimetry import stokes
from polcam.synth.sensor import ImperfectSensor


def true_calibration(sensor: ImperfectSensor, *, defects: np.ndarray | None = None) -> Calibration:
    """A calibration holding the sensor's planted maps (flat 1: the polarizer gain carries everything)."""
    h, w = sensor.shape
    bad = np.zeros((h, w), bool) if defects is None else defects
    return Calibration(
        layout=sensor.layout, height=h, width=w, bit_depth=sensor.bit_depth, black_level=sensor.black_level,
        white_level=sensor.white_level, camera_id=sensor.metadata["camera_id"],
        exposure_us=sensor.metadata["exposure_us"], gain_db=sensor.metadata["gain_db"],
        maps={"dark": sensor.dark.astype(np.float32), "dark_noise": np.zeros((h, w), np.float32), "hot": bad,
              "gain": sensor.gain.astype(np.float32), "diattenuation": sensor.diattenuation.astype(np.float32),
              "orientation_deg": sensor.orientation_deg.astype(np.float32),
              "residual": np.zeros((h, w), np.float32), "outlier": np.zeros((h, w), bool)})


def noise_free_frame(sensor: ImperfectSensor, stokes_in) -> Frame:
    counts = sensor.dark + sensor.signal(stokes_in) * sensor.span
    return sensor.frame(counts.astype(np.float32))


# ----------------------------------------------------------------- defects
def test_fill_defects_interpolates_from_same_class_neighbours():
    lay = parse_layout("imx250myr")
    yy, xx = np.mgrid[0:24, 0:24]
    # a mosaic that is linear within each (angle, colour) class, different between classes
    cls = lay.angle_index(24, 24) + 4 * lay.channel_index(24, 24)
    ramp = 0.3 * yy + 0.7 * xx + 100.0 * cls
    bad = np.zeros((24, 24), bool)
    bad[[9, 10, 14], [9, 9, 15]] = True  # isolated within their classes: the symmetric mean is exact
    out = fill_defects(np.where(bad, 1e6, ramp), bad, lay)
    np.testing.assert_allclose(out[~bad], ramp[~bad])
    np.testing.assert_allclose(out[bad], ramp[bad], atol=1e-9)
    # a 3x3 cluster of one class is filled from the outside in (exact for a per-class constant)
    const = 100.0 * cls
    cluster = np.zeros((24, 24), bool)
    cluster[4:13:4, 4:13:4] = True
    np.testing.assert_allclose(fill_defects(np.where(cluster, -5.0, const), cluster, lay), const)
    # on the ramp, cluster pixels get values of their neighbourhood
    near = fill_defects(np.where(cluster, 1e6, ramp), cluster, lay)
    assert np.abs(near - ramp)[cluster].max() < 4.0


# -------------------------------------------------------- exact behaviour
def test_ideal_calibration_leaves_the_frame_unchanged_but_for_the_black_level():
    sensor = ImperfectSensor.random("imx250mzr", 16, 16, seed=0).ideal()
    raw = sensor.expose((0.9, 0.2, -0.1), n=1, rng=1)[0]
    cal = true_calibration(sensor)
    out = apply_calibration(sensor.frame(raw), cal)
    np.testing.assert_allclose(out.mosaic, raw - sensor.black_level, atol=1e-3)
    assert out.black_level == 0.0 and out.white_level == sensor.white_level - sensor.black_level
    np.testing.assert_allclose(out.normalized(), sensor.frame(raw).normalized(), atol=1e-6)


@pytest.mark.parametrize("layout", ["imx250mzr", "imx250myr", "mono:0,45,135,90"])
def test_true_model_gives_exact_stokes_per_super_pixel(layout):
    sensor = ImperfectSensor.random(layout, 16, 16, seed=1)
    s_in = (0.8, 0.8 * 0.4 * np.cos(1.0), 0.8 * 0.4 * np.sin(1.0))
    if sensor.layout.is_color:  # an RGB scene: each channel its own S0, shared polarization
        scale = np.array([0.6, 1.0, 0.8])
        s_in = tuple(np.broadcast_to(np.asarray(s) * scale, (16, 16, 3)) for s in s_in)
    frame = noise_free_frame(sensor, s_in)
    cal = true_calibration(sensor)
    fixed = demosaic(apply_calibration(frame, cal), method="bilinear", resolution="cell")
    before = demosaic(sensor.frame(frame.mosaic), method="bilinear", resolution="cell")
    truth = [np.asarray(s) for s in s_in]
    for est, tol in ((stokes(fixed), 1e-5), (stokes(before), None)):
        errs = [np.abs(e - (t if t.ndim == 0 else t[::2, ::2])).max() for e, t in zip(est, truth, strict=True)]
        if tol is None:
            assert max(errs) > 5e-3  # without calibration the error is large
        else:
            assert max(errs) < tol


def test_stack_correction_equals_mosaic_correction_at_cell_resolution():
    sensor = ImperfectSensor.random("imx250mzr", 16, 20, seed=2)
    cal = true_calibration(sensor)
    raw = sensor.frame(sensor.expose((0.9, 0.3, 0.2), n=1, rng=3)[0])
    a = demosaic(apply_calibration(raw, cal), method="bilinear", resolution="cell")
    b = correct_stack(demosaic(apply_calibration(raw, cal, polarimetric="none"), method="bilinear",
                               resolution="cell"), cal, resolution="cell")
    np.testing.assert_allclose(a, b, atol=2e-6)


@pytest.mark.parametrize("layout", ["imx250mzr", "imx250myr"])
def test_both_corrections_are_exact_on_a_uniform_scene_at_full_resolution(layout):
    sensor = ImperfectSensor.random(layout, 24, 24, seed=3, hot_fraction=0.0)
    s_in = (0.7, -0.2, 0.25)
    frame = noise_free_frame(sensor, s_in)
    cal = true_calibration(sensor)
    mosaic_way = demosaic(apply_calibration(frame, cal), method="bilinear")
    stack_way = correct_stack(demosaic(apply_calibration(frame, cal, polarimetric="none"), method="bilinear"), cal)
    for st in (mosaic_way, stack_way):
        s = stokes(st.astype(np.float64))
        for est, t in zip(s, s_in, strict=True):
            np.testing.assert_allclose(est, t, atol=2e-5)


def test_defective_pixels_get_their_class_median_model():
    sensor = ImperfectSensor.random("imx250mzr", 16, 16, seed=4)
    bad = np.zeros((16, 16), bool)
    bad[3, 5] = True
    cal = true_calibration(sensor, defects=bad)
    cal.maps["gain"][3, 5] = 0.0  # garbage under a defect must not matter
    g, d, t = effective_model(cal)
    cls = sensor.layout.angle_index(16, 16) == sensor.layout.angle_index(16, 16)[3, 5]
    assert g[3, 5] == pytest.approx(np.median(sensor.gain[cls & ~bad]), rel=1e-6)
    assert d[3, 5] == pytest.approx(np.median(sensor.diattenuation[cls & ~bad]), rel=1e-6)
    assert abs(t[3, 5] - nominal_orientation(sensor.layout, 16, 16)[3, 5]) < 5
    frame = noise_free_frame(sensor, (0.8, 0.1, 0.1))
    frame.mosaic[3, 5] = 4000.0  # a hot pixel's reading
    out = apply_calibration(frame, cal)
    assert np.all(np.isfinite(out.mosaic)) and out.mosaic.max() < 0.9 * sensor.span
    assert out.metadata["calibration"]["defects_filled"] == 1


# ----------------------------------------------------- the target
@pytest.mark.parametrize("layout", ["imx250mzr", "imx250myr"])
def test_stokes_errors_fall_at_least_fivefold_on_a_new_scene(layout):
    """Calibrate from frames (dark 32, flat 128, polarizer 12 angles x 8), then a new scene, 16 frames averaged."""
    sensor = ImperfectSensor.random(layout, 64, 64, seed=5)
    cal, _ = make_calibration(sensor, seed=5, dark_frames=32, flat_frames=128, angles=12, per_angle=8)
    s = _scene(sensor, 6)
    counts = sensor.expose(s, n=16, rng=7).astype(np.float64).mean(axis=0)
    frame = sensor.frame(counts.astype(np.float32))
    truth = tuple(x.reshape(32, 2, 32, 2, *x.shape[2:]).mean(axis=(1, 3)) for x in s)
    before = stokes_errors(demosaic(frame, method="bilinear", resolution="cell"), truth, border=2)
    after = stokes_errors(demosaic(apply_calibration(frame, cal), method="bilinear", resolution="cell"),
                          truth, border=2)
    assert before[0] / after[0] >= 5.0, (before, after)   # DoLP
    assert before[1] / after[1] >= 5.0, (before, after)   # AoLP


# ------------------------------------------------------------- bad input
def test_mismatched_frames_and_bad_options_are_refused():
    sensor = ImperfectSensor.random("imx250mzr", 16, 16, seed=8)
    cal = true_calibration(sensor)
    other = ImperfectSensor.random("imx250mzr", 16, 16, seed=8, metadata={"camera_id": "B"})
    with pytest.raises(CalibrationError, match="camera_id mismatch.*'B'.*'synthetic-imx250'"):
        apply_calibration(other.frame(np.zeros((16, 16), np.uint16)), cal)
    with pytest.raises(CalibrationError, match="size mismatch"):
        apply_calibration(np.zeros((16, 20), np.uint16), cal)
    with pytest.raises(CalibrationError, match="polarimetric 'stack'"):
        apply_calibration(np.zeros((16, 16), np.uint16), cal, polarimetric="stack")
    with pytest.raises(CalibrationError, match=r"stack of shape \(4, 16, 16\): expected \(4, 8, 8\)"):
        correct_stack(np.zeros((4, 16, 16), np.float32), cal, resolution="cell")
    dark_only = Calibration(layout="imx250mzr", height=16, width=16,
                            maps={k: cal.maps[k] for k in ("dark", "dark_noise", "hot")})
    with pytest.raises(CalibrationError, match="no polarizer calibration"):
        correct_stack(np.zeros((4, 16, 16), np.float32), dark_only)
    out = apply_calibration(np.full((16, 16), 100, np.uint16), dark_only)  # dark only: no polarimetric step
    assert out.metadata["calibration"]["stages"] == ["dark"] and out.metadata["calibration"]["polarimetric"] is None


def test_bare_array_gets_the_calibrations_levels_and_layout():
    sensor = ImperfectSensor.random("imx250myr", 16, 16, seed=9)
    cal = true_calibration(sensor)
    out = apply_calibration(np.full((16, 16), 1000, np.uint16), cal, polarimetric="none")
    assert out.layout == sensor.layout and out.bit_depth == 12
    np.testing.assert_allclose(out.mosaic[~sensor.hot], (1000 - sensor.dark)[~sensor.hot], rtol=1e-6)
