"""Tests of polcam.bench.calibration (small sizes; the figures in docs come from the full run)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from polcam.bench.calibration import VARIANTS, format_markdown, run, smooth_scene, stokes_errors
from polcam.calibration.__main__ import main as module_main
from polcam.polarimetry import stokes


@pytest.fixture(scope="module")
def small():
    return run(layouts=("imx250mzr",), size=32, dark_frames=16, flat_frames=64, angles=8, per_angle=8,
               scene_frames=4)


def test_run_reports_every_variant_and_the_calibration_wins(small):
    rows = small["stokes"]
    assert [(r["resolution"], r["variant"]) for r in rows] == [(res, v) for res in ("cell", "full") for v in VARIANTS]
    by = {(r["resolution"], r["variant"]): r for r in rows}
    for res in ("cell", "full"):
        assert by[(res, "mosaic")]["dolp_mean"] < by[(res, "uncalibrated")]["dolp_mean"]
        assert by[(res, "stack")]["aolp_mean"] < by[(res, "uncalibrated")]["aolp_mean"]
    p = small["precision"][0]
    assert p["hot_found"] == p["hot_planted"] and p["hot_false"] == 0
    text = format_markdown(small)
    assert "| imx250mzr | cell | mosaic |" in text and "hot found / planted" in text


def test_stokes_errors_are_zero_for_the_truth_and_measure_a_known_offset():
    s0, s1, s2 = smooth_scene(16, 16, seed=0)
    a = np.mod(0.5 * np.arctan2(s2, s1), np.pi)
    p = np.hypot(s1, s2) / s0
    angles = np.deg2rad([0, 45, 90, 135])
    stack = np.stack([s0 / 2 * (1 + p * np.cos(2 * t - 2 * a)) for t in angles])
    assert stokes_errors(stack, (s0, s1, s2)) == pytest.approx((0.0, 0.0), abs=1e-9)
    turned = np.stack([s0 / 2 * (1 + p * np.cos(2 * t - 2 * (a + np.deg2rad(3)))) for t in angles])
    assert stokes_errors(turned, (s0, s1, s2))[1] == pytest.approx(3.0, abs=1e-6)
    st = stokes(stack)
    np.testing.assert_allclose(st.s1, s1, atol=1e-12)


def test_smooth_scene_ranges():
    s0, s1, s2 = smooth_scene(64, 64, seed=1, color=True)
    assert s0.shape == (64, 64, 3) and s0.min() > 0.04 and s0.max() < 0.73
    assert np.all(np.hypot(s1, s2) <= 0.95 * s0 + 1e-12)


def test_module_entry_point_writes_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert module_main(["bench", "--layouts", "imx250mzr", "--size", "16", "--dark-frames", "4",
                        "--flat-frames", "8", "--angles", "8", "--per-angle", "2", "--scene-frames", "2",
                        "--json", str(out)]) == 0
    assert "| layout | resolution |" in capsys.readouterr().out
    assert json.loads(out.read_text())["settings"]["size"] == 16
