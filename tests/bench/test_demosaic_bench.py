"""Smoke test of the demosaicing benchmark, and checks of its metrics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from polcam.bench.demosaic import (
    AOLP_MIN_DOLP,
    format_markdown,
    load_real_stack,
    polanalyser_order,
    quality,
    run,
)
from polcam.cli import main
from polcam.errors import MethodError
from polcam.synth.patterns import SCENES, stack_from_stokes


def test_quality_closed_forms() -> None:
    rng = np.random.default_rng(0)
    s0 = rng.uniform(0.3, 0.9, size=(40, 40))
    gt = stack_from_stokes(s0, np.float64(0.5), np.float64(0.7))
    # a constant offset d on every image: PSNR 10 log10(1 / d^2); S0 moves by 2 d on range 2
    d = 0.01
    q = quality(gt, gt + np.float32(d), border=4)
    for key in ("psnr_i0", "psnr_i45", "psnr_i90", "psnr_i135", "psnr_s0"):
        assert q[key] == pytest.approx(40.0, abs=1e-3)
    # a pure AoLP rotation by 10 degrees leaves S0 and DoLP and costs exactly 10 degrees
    rot = stack_from_stokes(s0, np.float64(0.5), np.float64(0.7 + np.deg2rad(10.0)))
    q = quality(gt, rot, border=4)
    assert q["aolp_mae_deg"] == pytest.approx(10.0, abs=1e-3)
    assert q["psnr_s0"] > 100 and q["psnr_dolp"] > 90 and q["aolp_fraction"] == 1.0
    # the error is taken modulo 180 degrees: 0.1 and pi - 0.1 rad are 0.2 rad apart
    a = stack_from_stokes(s0, np.float64(0.5), np.float64(0.1))
    b = stack_from_stokes(s0, np.float64(0.5), np.float64(np.pi - 0.1))
    assert quality(a, b, border=4)["aolp_mae_deg"] == pytest.approx(np.degrees(0.2), abs=1e-3)
    # below the DoLP threshold no pixel counts
    weak = stack_from_stokes(s0, np.float64(AOLP_MIN_DOLP / 2), np.float64(0.7))
    q = quality(weak, weak, border=4)
    assert q["aolp_fraction"] == 0.0 and math.isnan(q["aolp_mae_deg"])
    with pytest.raises(MethodError, match="cannot be compared"):
        quality(gt, gt[:, :-2])


def test_polanalyser_order_is_measured() -> None:
    pa = pytest.importorskip("polanalyser")
    order = polanalyser_order(pa)
    # polanalyser documents angles 0-45-90-135 and OpenCV's BGR
    assert order == {"angles": [0, 1, 2, 3], "channels": [2, 1, 0]}


def test_smoke_run_and_report(tmp_path: Path) -> None:
    pytest.importorskip("polanalyser")
    methods = ("bilinear", "eari", "polanalyser")
    rows = run(data_dir=None, size=48, seed=1, methods=methods, speed=True,
               speed_shape=(32, 48), repeats=1)
    kinds = [r["kind"] for r in rows]
    assert kinds.count("polanalyser_order") == 1
    quality_rows = [r for r in rows if r["kind"] == "quality"]
    speed_rows = [r for r in rows if r["kind"] == "speed"]
    assert len(quality_rows) == 2 * len(SCENES) * len(methods)
    assert len(speed_rows) == 2 * len(methods)
    for r in quality_rows:
        assert r["height"] == r["width"] == 48
        assert all(np.isfinite(r[k]) for k in ("psnr_i0", "psnr_s0", "psnr_dolp", "aolp_mae_deg"))
    for r in speed_rows:
        assert r["fps"] > 0 and r["seconds_min"] <= r["seconds"] and r["cpu_seconds"] > 0
    # polanalyser's mono demosaicking is the same bilinear interpolation as polcam's, so with its
    # angle order applied the two must agree: a wrong order would cost tens of dB
    by = {(r["layout"], r["scene"], r["method"]): r for r in quality_rows}
    for scene in SCENES:
        ours = by[("imx250mzr", scene, "bilinear")]
        theirs = by[("imx250mzr", scene, "polanalyser")]
        assert abs(ours["psnr_s0"] - theirs["psnr_s0"]) < 0.1
        assert abs(ours["psnr_i45"] - theirs["psnr_i45"]) < 0.1
    text = format_markdown(rows)
    assert "Layout `imx250mzr`" in text and "Layout `imx250myr`" in text
    assert "**mean of 4** | **eari**" in text and "frames per second" in text
    assert "polanalyser output order, measured" in text


def test_unknown_method_is_refused() -> None:
    with pytest.raises(MethodError, match="'nearest'"):
        run(data_dir=None, size=16, seed=0, methods=("nearest",), speed=False)


def test_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rows.json"
    assert main(["bench", "demosaic", "--size", "32", "--methods", "bilinear", "eari", "--layouts", "imx250mzr",
                 "--no-speed", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| smooth | eari |" in text
    rows = json.loads(out.read_text())
    assert {r["method"] for r in rows} == {"bilinear", "eari"}


def test_polcam_bench_demosaic_is_the_same_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from polcam.cli import main as polcam_main

    out = tmp_path / "rows.json"
    assert polcam_main(["bench", "demosaic", "--size", "32", "--methods", "bilinear", "--layouts", "imx250mzr",
                        "--no-speed", "--json", str(out)]) == 0
    assert "| smooth | bilinear |" in capsys.readouterr().out
    assert {r["method"] for r in json.loads(out.read_text())} == {"bilinear"}
    # the folder of real stacks under either spelling; a missing one is an error naming it
    assert polcam_main(["bench", "demosaic", "--data", str(tmp_path / "nowhere")]) == 2
    assert "nowhere: not a folder" in capsys.readouterr().err
    assert polcam_main(["bench", "demosaic", "--data-dir", str(tmp_path / "nowhere")]) == 2


def test_real_stack_loads(shared_data: Path) -> None:
    if not (shared_data / "real-color-stack").is_dir():
        pytest.skip("real-color-stack not in the shared data")
    st = load_real_stack(shared_data)
    assert st.shape == (4, 1088, 1456, 3) and st.dtype == np.float32
    assert 0.0 <= st.min() and st.max() <= 1.0
    # a real measurement: I0 + I90 and I45 + I135 agree on average to a few grey levels
    assert abs(float((st[0] + st[2]).mean() - (st[1] + st[3]).mean())) < 0.02


def test_all_real_stacks_are_measured(shared_data: Path) -> None:
    """Every real stack found is a scene (colour for the colour layout, luminance for mono), and the
    report gives the mean over the real scenes and over the synthetic ones apart."""
    from polcam.bench.demosaic import REAL_SCENES, load_real_stacks

    found = [name for name, _ in load_real_stacks(shared_data)]
    if not found:
        pytest.skip("no real stacks in the shared data")
    assert set(found) <= set(REAL_SCENES)
    rows = run(data_dir=shared_data, size=64, seed=0, methods=("bilinear",),
               layouts=("imx250mzr", "imx250myr"), speed=False)
    scenes = {(r["layout"], r["scene"]) for r in rows}
    for name in found:
        assert ("imx250mzr", name) in scenes and ("imx250myr", name) in scenes
    text = format_markdown(rows)
    assert f"**mean of {len(found)} real** | **bilinear**" in text
    assert f"**mean of {len(SCENES)} synthetic** | **bilinear**" in text
