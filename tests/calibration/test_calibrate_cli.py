"""Tests of polcam.calibration.cli: ``polcam calibrate dark|flat|polarizer`` on frames in folders."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from polcam.calibration.cli import add_calibrate_parser, angle_from_name, angle_of, main
from polcam.calibration.simulate import ImperfectSensor
from polcam.calibration.store import CalibrationError, load_calibration
from polcam.io import write_frame
from polcam.io.sidecar import read_sidecar, sidecar_path, write_sidecar

SIZE = 16


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="polcam")
    add_calibrate_parser(p.add_subparsers(dest="command", required=True))
    return p


def run(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("calib")
    sensor = ImperfectSensor.random("imx250mzr", SIZE, SIZE, seed=0, hot_fraction=0.0)
    for seed, (name, stokes_in, n) in enumerate((("dark", (0, 0, 0), 8), ("flat", (1.4, 0, 0), 8))):
        (root / name).mkdir()
        for i, fr in enumerate(sensor.frames(stokes_in, n=n, rng=seed)):
            write_frame(root / name / f"{name}_{i:03d}.png", fr)
    (root / "pol").mkdir()
    (root / "pol_sidecar").mkdir()
    for a in np.arange(8) * 22.5:
        r = np.deg2rad(2 * a)
        for j, fr in enumerate(sensor.frames((0.8, 0.8 * np.cos(r), 0.8 * np.sin(r)), n=2, rng=int(a * 10))):
            write_frame(root / "pol" / f"pol_{a:05.1f}deg_{j}.png", fr)
            path = write_frame(root / "pol_sidecar" / f"shot_{int(a * 10):04d}_{j}.tif", fr)
            side = read_sidecar(path)
            write_sidecar(path, {**side, "polarizer_deg": float(a)})
    return root, sensor


def test_dark_flat_polarizer_chain_writes_one_file(folders, tmp_path, capsys):
    root, sensor = folders
    assert run(["calibrate", "dark", str(root / "dark"), "-o", str(tmp_path / "dark.npz")]) == 0
    assert run(["calibrate", "flat", str(root / "flat"), "-o", str(tmp_path / "flat.npz"),
                "--calibration", str(tmp_path / "dark.npz")]) == 0
    assert run(["calibrate", "polarizer", str(root / "pol"), "-o", str(tmp_path / "sub" / "cal.npz"),
                "--calibration", str(tmp_path / "flat.npz")]) == 0
    out = capsys.readouterr().out
    assert "polarizer: 16 frames ->" in out and "orientation_offset_deg" in out
    cal = load_calibration(tmp_path / "sub" / "cal.npz")
    assert cal.applied_stages == ["dark", "flat", "polarizer"]
    assert cal.camera_id == "synthetic-imx250" and str(cal.layout) == "imx250mzr" and cal.shape == (SIZE, SIZE)
    assert cal.stages["polarizer"]["angles_deg"] == [0.0, 22.5, 45.0, 67.5, 90.0, 112.5, 135.0, 157.5]
    assert len(cal.stages["dark"]["inputs"]) == 8
    # the maps mean something: 16 frames cannot reach the precision, but the offsets show
    offsets = cal.stages["polarizer"]["statistics"]["orientation_offset_deg"]
    assert offsets["0"] == pytest.approx(1.5, abs=0.5) and offsets["45"] == pytest.approx(-2.0, abs=0.5)


def test_angles_from_sidecars_give_the_same_fit(folders, tmp_path):
    root, _ = folders
    assert run(["calibrate", "polarizer", str(root / "pol"), "-o", str(tmp_path / "a.npz")]) == 0
    assert run(["calibrate", "polarizer", str(root / "pol_sidecar"), "-o", str(tmp_path / "b.npz"),
                "--angles-from", "sidecar", "--json"]) == 0
    a, b = load_calibration(tmp_path / "a.npz"), load_calibration(tmp_path / "b.npz")
    np.testing.assert_allclose(a.maps["orientation_deg"], b.maps["orientation_deg"], atol=1e-4)


def test_existing_output_needs_force(folders, tmp_path):
    root, _ = folders
    target = tmp_path / "dark.npz"
    target.write_bytes(b"keep me")
    with pytest.raises(CalibrationError, match="output exists.*--force"):
        run(["calibrate", "dark", str(root / "dark"), "-o", str(target)])
    assert target.read_bytes() == b"keep me"
    assert run(["calibrate", "dark", str(root / "dark"), "-o", str(target), "--force"]) == 0
    assert load_calibration(target).has("dark")


def test_missing_or_conflicting_angles_name_the_file(folders, tmp_path):
    root, sensor = folders
    d = tmp_path / "frames"
    d.mkdir()
    fr = sensor.frames((0.8, 0, 0), n=1, rng=0)[0]
    path = write_frame(d / "frame_3_7.png", fr)
    with pytest.raises(CalibrationError, match="frame_3_7.png: polarizer angle unknown"):
        angle_of(path)
    write_sidecar(path, {**read_sidecar(path), "polarizer_deg": 30.0})
    assert angle_of(path) == 30.0
    path2 = write_frame(d / "pol_45deg.png", fr)
    write_sidecar(path2, {**read_sidecar(path2), "polarizer_deg": 40.0})
    with pytest.raises(CalibrationError, match="40 in the sidecar but 45 in the file name"):
        angle_of(path2)
    assert angle_of(path2, source="name") == 45.0 and angle_of(path2, source="sidecar") == 40.0
    write_sidecar(path2, {**read_sidecar(path2), "polarizer_deg": "north"})
    with pytest.raises(CalibrationError, match="'north': expected a finite number"):
        angle_of(path2)
    write_frame(d / "capture.png", fr)
    with pytest.raises(CalibrationError, match="capture.png: polarizer angle unknown"):
        run(["calibrate", "polarizer", str(d), "-o", str(tmp_path / "x.npz")])
    assert sidecar_path(path).exists()


def test_too_few_angles_and_empty_folders_are_clear_errors(folders, tmp_path, capsys):
    root, _ = folders
    few = sorted((root / "pol").glob("pol_0[0-4]*.png"))  # 0, 22.5, 45 degrees
    with pytest.raises(CalibrationError, match="3 distinct polarizer angles"):
        run(["calibrate", "polarizer", *map(str, few), "-o", str(tmp_path / "x.npz")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(CalibrationError, match="no raw frames found"):
        run(["calibrate", "dark", str(tmp_path / "empty"), "-o", str(tmp_path / "x.npz")])
    with pytest.raises(CalibrationError, match="no such file or folder"):
        run(["calibrate", "dark", str(tmp_path / "nowhere"), "-o", str(tmp_path / "x.npz")])
    # the standalone entry point turns errors into exit status 2 and a message
    assert main(["dark", str(tmp_path / "empty"), "-o", str(tmp_path / "x.npz")]) == 2
    assert "error:" in capsys.readouterr().err


def test_flat_with_a_dark_of_another_size_is_refused(folders, tmp_path):
    root, _ = folders
    other = ImperfectSensor.random("imx250mzr", SIZE, SIZE + 4, seed=1)
    (tmp_path / "d").mkdir()
    for i, fr in enumerate(other.frames((0, 0, 0), n=2, rng=1)):
        write_frame(tmp_path / "d" / f"d{i}.png", fr)
    assert run(["calibrate", "dark", str(tmp_path / "d"), "-o", str(tmp_path / "dark.npz")]) == 0
    with pytest.raises(CalibrationError, match="size mismatch: .*flat_000.png has size 16x16, calibration .* "
                                               "is for 20x16"):
        run(["calibrate", "flat", str(root / "flat"), "-o", str(tmp_path / "f.npz"),
             "--calibration", str(tmp_path / "dark.npz")])


def test_help_says_frames_come_from_files_not_a_live_camera(capsys):
    with pytest.raises(SystemExit):
        parser().parse_args(["calibrate", "polarizer", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "not part of this command yet" in text and "polarizer_deg" in text and "--polarizer-dolp" in text


@pytest.mark.parametrize(("stem", "angle"), [
    ("pol_045deg", 45.0), ("angle_22.5deg_003", 22.5), ("p_135DEG", 135.0), ("angle_090", 90.0),
    ("frame_12_045", None), ("pol_10deg_20deg", None), ("nothing", None),
])
def test_angle_from_name(stem, angle):
    assert angle_from_name(stem) == angle


def test_json_output_is_valid(folders, tmp_path, capsys):
    root, _ = folders
    assert run(["calibrate", "dark", str(root / "dark"), "-o", str(tmp_path / "d.npz"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["stages"]["dark"]["frames"] == 8
