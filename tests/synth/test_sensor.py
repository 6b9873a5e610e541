"""Tests of polcam.synth.sensor: the synthetic imperfect sensor follows its stated model."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.calibration.model import nominal_orientation
from polcam.errors import PolcamError
from polcam.synth.sensor import ImperfectSensor


def test_random_sensor_has_the_planted_statistics():
    s = ImperfectSensor.random("imx250mzr", 64, 64, seed=0)
    assert np.std(s.gain) == pytest.approx(0.05, rel=0.1)
    assert s.diattenuation.min() >= 49 / 51 and s.diattenuation.max() <= 299 / 301
    dev = np.mod(s.orientation_deg - nominal_orientation(s.layout, 64, 64) + 90, 180) - 90
    ai = s.layout.angle_index(64, 64)
    for k, off in enumerate((1.5, -2.0, 2.5, -1.0)):
        assert dev[ai == k].mean() == pytest.approx(off, abs=0.15)
    assert 0.001 < s.hot.mean() < 0.006
    extra = (s.dark - s.offset)[s.hot]
    assert extra.min() >= 80 - 1e-9 and extra.max() <= 800 + 1e-9


def test_frames_follow_the_forward_model_and_noise():
    s = ImperfectSensor.random("imx250myr", 8, 8, seed=1, hot_fraction=0.0)
    stokes_in = (0.6, 0.2, -0.1)
    n = 4000
    counts = s.expose(stokes_in, n=n, rng=2).astype(np.float64)
    v = s.signal(stokes_in)
    scale = s.span / s.full_well
    want_mean = s.dark + v * s.span
    want_var = (v * s.full_well + s.read_noise**2) * scale**2 + 1 / 12
    np.testing.assert_allclose(counts.mean(0), want_mean, atol=5 * np.sqrt(want_var.max() / n))
    np.testing.assert_allclose(counts.var(0), want_var, rtol=0.15)
    f = s.frame(counts[0].astype(np.uint16))
    assert f.layout == s.layout and f.black_level == 64.0 and f.metadata["camera_id"] == "synthetic-imx250"


def test_colour_scene_maps_pick_the_pixels_filter():
    s = ImperfectSensor.random("imx250myr", 8, 8, seed=3).ideal()
    s0 = np.zeros((8, 8, 3))
    s0[..., 1] = 1.0  # green only
    v = s.signal((s0, 0.0, 0.0))
    green = s.layout.channel_index(8, 8) == 1
    np.testing.assert_allclose(v[green], 0.5)
    np.testing.assert_allclose(v[~green], 0.0)
    with pytest.raises(PolcamError, match="expected \\(8, 8, 3\\)"):
        s.signal((np.zeros((4, 4, 3)), 0, 0))


def test_ideal_sensor_and_shape_checks():
    s = ImperfectSensor.random("imx250mzr", 8, 8, seed=4)
    ideal = s.ideal()
    assert np.all(ideal.gain == 1) and np.all(ideal.diattenuation == 1) and not ideal.hot.any()
    np.testing.assert_array_equal(ideal.dark, 64.0)
    with pytest.raises(PolcamError, match="offset of shape"):
        ImperfectSensor("imx250mzr", np.ones((4, 4)), np.ones((4, 4)), np.zeros((4, 4)), np.zeros((2, 2)),
                        np.zeros((4, 4)))
