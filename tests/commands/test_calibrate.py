"""Tests of polcam.commands.calibrate and polcam.acquisition.calibration_frames: ``polcam calibrate dark|flat|polarizer`` on frames in folders and on
frames grabbed live from a camera (the replay camera playing those folders, and Aravis' Fake camera)."""

from __future__ import annotations

import argparse
import io
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from polcam.acquisition.calibration_frames import angle_from_name, angle_of
from polcam.calibration.store import CalibrationError, load_calibration
from polcam.camera import aravis_available
from polcam.commands.calibrate import add_calibrate_parser, main
from polcam.io import read_frame, write_frame
from polcam.io.sidecar import read_sidecar, sidecar_path, write_sidecar
from polcam.synth.sensor import ImperfectSensor

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


def test_help_names_both_sources_and_the_camera_options(capsys):
    with pytest.raises(SystemExit):
        parser().parse_args(["calibrate", "polarizer", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Give either FRAMES" in text and "--device ID --frames N" in text and "--keep DIR" in text
    assert "polarizer_deg" in text and "--polarizer-dolp" in text and "--angles" in text
    for flag in ("--pixel-format", "--exposure", "--gain", "--roi", "--timeout", "--packet-size"):
        assert flag in text


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


# ---------------------------------------------------------------------------
# frames grabbed live from a camera (--device): the replay camera and Aravis' Fake camera
# ---------------------------------------------------------------------------

ANGLES = "0,22.5,45,67.5,90,112.5,135,157.5"


def _maps_equal(a, b) -> None:
    assert sorted(a.maps) == sorted(b.maps)
    for name in a.maps:
        np.testing.assert_array_equal(a.maps[name], b.maps[name], err_msg=name)


def _chain(root, tmp_path, tag, live: bool, monkeypatch=None, keep=None) -> list[Path]:
    """dark -> flat -> polarizer from the folders, or live from replay cameras playing them."""
    out = [tmp_path / f"{tag}-{stage}.npz" for stage in ("dark", "flat", "pol")]
    base: list[str] = []
    for stage, folder, n, target in (("dark", "dark", "8", out[0]), ("flat", "flat", "8", out[1]),
                                      ("polarizer", "pol", "2", out[2])):
        if live:
            src = ["--device", f"replay:{root / folder}", "--frames", n]
            if stage == "polarizer":
                src += ["--angles", ANGLES]
                monkeypatch.setattr(sys, "stdin", io.StringIO("\n" * 8))
            if keep is not None:
                src += ["--keep", str(keep / stage)]
        else:
            src = [str(root / folder)]
        assert run(["calibrate", stage, *src, "-o", str(target), *base]) == 0
        base = ["--calibration", str(target)]
    return out


def test_live_chain_gives_the_folder_chain_maps(folders, tmp_path, monkeypatch, capsys):
    root, _ = folders
    disk = [load_calibration(p) for p in _chain(root, tmp_path, "disk", live=False)]
    capsys.readouterr()
    live = [load_calibration(p) for p in _chain(root, tmp_path, "live", live=True, monkeypatch=monkeypatch)]
    captured = capsys.readouterr()
    for a, b in zip(disk, live):
        _maps_equal(a, b)
        # the camera that exposed the frames (the recording's), not the replay
        assert b.camera_id == a.camera_id == "synthetic-imx250"
        assert (b.exposure_us, b.gain_db, b.layout) == (a.exposure_us, a.gain_db, a.layout)
    final = live[2]
    assert final.applied_stages == ["dark", "flat", "polarizer"]
    for stage, folder, n in (("dark", "dark", 8), ("flat", "flat", 8), ("polarizer", "pol", 16)):
        info = final.stages[stage]
        assert info["source"] == "camera" and info["device"] == f"replay:{root / folder}"
        assert info["camera_id"] == f"replay:{root / folder}" and info["camera"]["model"] == "replay"
        assert (info["frames"], info["frames_good"], info["frames_incomplete"], info["frames_dropped"]) == (n, n, 0, 0)
    assert final.stages["polarizer"]["frames_per_angle"] == 2
    assert final.stages["polarizer"]["angles_deg"] == [0.0, 22.5, 45.0, 67.5, 90.0, 112.5, 135.0, 157.5]
    # one prompt per angle on stderr; the report on stdout
    prompts = re.findall(r"set the polarizer to (\S+) deg and press Enter", captured.err)
    assert prompts == ANGLES.split(",")
    assert "polarizer: 16 frames from camera replay:" in captured.out and "(0 incomplete, 0 dropped)" in captured.out


def test_keep_writes_the_frames_to_redo_the_calibration_from_disk(folders, tmp_path, monkeypatch):
    root, _ = folders
    keep = tmp_path / "kept"
    live = _chain(root, tmp_path, "live", live=True, monkeypatch=monkeypatch, keep=keep)
    pol = sorted(p for p in (keep / "polarizer").iterdir() if p.suffix == ".raw")
    assert len(pol) == 16 and len(list((keep / "dark").glob("*.raw"))) == 8
    sources = sorted((root / "pol").glob("*.png"))  # the order the replay played them
    for path, src in zip(pol, sources):
        side = read_sidecar(path)
        assert side["polarizer_deg"] == angle_from_name(src.stem) and side["camera_id"] == "synthetic-imx250"
        np.testing.assert_array_equal(read_frame(path).mosaic, read_frame(src).mosaic)
    assert load_calibration(live[2]).stages["polarizer"]["inputs"] == [str(p) for p in pol]
    # redo the chain from the kept folders: the same maps
    redo = []
    base: list[str] = []
    for stage in ("dark", "flat", "polarizer"):
        target = tmp_path / f"redo-{stage}.npz"
        assert run(["calibrate", stage, str(keep / stage), "-o", str(target), *base]) == 0
        base = ["--calibration", str(target)]
        redo.append(load_calibration(target))
    for a, b in zip(redo, (load_calibration(p) for p in live)):
        _maps_equal(a, b)
    # a --keep folder holding frames already is refused before the camera is opened
    with pytest.raises(CalibrationError, match=r"kept/dark: --keep folder already holds 8 raw frame"):
        run(["calibrate", "dark", "--device", f"replay:{root / 'dark'}", "--frames", "8",
             "-o", str(tmp_path / "again.npz"), "--keep", str(keep / "dark")])


def test_end_of_input_at_a_prompt_writes_nothing(folders, tmp_path):
    # a real pipe that closes after three answers: the command stops at the fourth angle
    root, _ = folders
    out = tmp_path / "pol.npz"
    proc = subprocess.run(
        [sys.executable, "-m", "polcam.calibration", "polarizer", "--device", f"replay:{root / 'pol'}",
         "--frames", "2", "--angles", ANGLES, "-o", str(out)],
        input="\n\n\n", capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("press Enter") == 4
    assert "standard input ended before the polarizer was set to 67.5 deg (angle 4 of 8)" in proc.stderr
    assert "no calibration written" in proc.stderr and not out.exists()


def test_too_few_frames_are_refused(folders, tmp_path, monkeypatch):
    root, _ = folders
    out = tmp_path / "x.npz"
    with pytest.raises(CalibrationError, match=r"camera replay:.*dark ran out of frames after 8 of the 9 good "
                                               r"frames asked for the dark .*expected 9 good frames"):
        run(["calibrate", "dark", "--device", f"replay:{root / 'dark'}", "--frames", "9", "-o", str(out)])
    # a polarizer series: 16 files, 3 asked at each of 8 angles
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n" * 8))
    with pytest.raises(CalibrationError, match=r"after 1 of the 3 good frames asked for the polarizer at 112.5 deg"):
        run(["calibrate", "polarizer", "--device", f"replay:{root / 'pol'}", "--frames", "3", "--angles", ANGLES,
             "-o", str(out)])
    assert not out.exists()


def test_an_unreadable_frame_counts_as_incomplete_and_is_replaced(folders, tmp_path):
    # the replay camera reports a file it cannot read as an incomplete frame: the next good one is used
    root, _ = folders
    src = tmp_path / "darks"
    shutil.copytree(root / "dark", src)
    (src / "dark_003.png").write_bytes(b"not a png")
    (src / "dark_999.png").write_bytes((root / "dark" / "dark_003.png").read_bytes())
    (src / "dark_999.json").write_bytes((root / "dark" / "dark_003.json").read_bytes())
    out = tmp_path / "d.npz"
    assert run(["calibrate", "dark", "--device", f"replay:{src}", "--frames", "8", "-o", str(out)]) == 0
    info = load_calibration(out).stages["dark"]
    assert (info["frames_good"], info["frames_incomplete"], info["frames_dropped"]) == (8, 1, 0)
    _maps_equal(load_calibration(out), _disk_dark(root, tmp_path))


def _disk_dark(root, tmp_path):
    target = tmp_path / "disk-dark.npz"
    run(["calibrate", "dark", str(root / "dark"), "-o", str(target)])
    return load_calibration(target)


@pytest.mark.parametrize(("argv", "message"), [
    (["{root}/dark", "--device", "replay:{root}/dark", "--frames", "8"], "both FRAMES .* and --device"),
    ([], "no frames: give FRAMES .* or --device ID"),
    (["--device", "replay:{root}/dark"], "without --frames N"),
    (["--device", "replay:{root}/dark", "--frames", "0"], "--frames 0: expected a positive number"),
    (["{root}/dark", "--frames", "8"], "--frames given with FRAMES"),
    (["{root}/dark", "--keep", "k", "--exposure", "100"], "--keep, --exposure given with FRAMES"),
    (["--device", "replay:{root}/dark", "--frames", "2", "--recursive"], "--recursive given with --device"),
])
def test_the_source_must_be_frames_or_a_device(folders, tmp_path, argv, message):
    root, _ = folders
    out = tmp_path / "x.npz"
    with pytest.raises(CalibrationError, match=message):
        run(["calibrate", "dark", *[a.format(root=root) for a in argv], "-o", str(out)])
    assert not out.exists()


def test_live_polarizer_needs_good_angles(folders, tmp_path):
    root, _ = folders
    pol = ["calibrate", "polarizer", "--device", f"replay:{root / 'pol'}", "--frames", "2", "-o",
           str(tmp_path / "x.npz")]
    with pytest.raises(CalibrationError, match="without --angles"):
        run(pol)
    with pytest.raises(CalibrationError, match="'north' is not a number"):
        run([*pol, "--angles", "0,north,90"])
    with pytest.raises(CalibrationError, match="4 distinct polarizer angles"):  # before any prompt
        run([*pol, "--angles", "0,45,90,135"])


def test_grabber_takes_no_frame_exposed_before_enter(folders, tmp_path, monkeypatch):
    # a free-running camera (replay at a frame rate) keeps exposing while the polarizer turns: the grabber
    # stops it at every prompt, so every frame of an angle was taken after that angle's Enter
    from polcam.acquisition.calibration_frames import FrameGrabber
    from polcam.camera import ReplayCamera

    root, _ = folders
    enter_ns: list[int] = []

    class SlowOperator(io.StringIO):
        def readline(self, *args):
            time.sleep(0.15)  # a camera left running would queue stale frames meanwhile
            enter_ns.append(time.time_ns())
            return "\n"

    monkeypatch.setattr(sys, "stdin", SlowOperator())
    angles = [0.0, 45.0, 90.0]
    with ReplayCamera(root / "dark", frame_rate=200.0, loop=True) as cam:
        cam.configure()
        assert not cam.waits_for_reader
        grabber = FrameGrabber(cam, "polarizer")
        stamps = [f.metadata["timestamp_ns"] for f in grabber.polarizer_frames(angles, 3)]
    assert len(enter_ns) == 3 and len(stamps) == 9 and grabber.taken == 9
    for k in range(3):
        assert all(t > enter_ns[k] for t in stamps[3 * k:3 * k + 3])
        assert k == 2 or all(t < enter_ns[k + 1] for t in stamps[3 * k:3 * k + 3])


needs_aravis = pytest.mark.skipif(not aravis_available(), reason="Aravis 0.8 is not installed")


@needs_aravis
@pytest.mark.camera
def test_dark_from_the_aravis_fake_camera(tmp_path, capsys):
    """The Fake camera sends (x + y + frame id) mod 255 scaled by 1 + gain + log10(exposure / 10 ms),
    clamped to 0..255: at 100 us the scale is -1, every pixel 0, a capped lens. At its default
    exposure the bright ramp is refused as not dark, by its level, and no file is written."""
    out = tmp_path / "fake-dark.npz"
    assert run(["calibrate", "dark", "--device", "Fake_1", "--pixel-format", "Mono8", "--layout", "imx250mzr",
                "--roi", "0", "0", "64", "32", "--exposure", "100", "--frames", "4", "-o", str(out),
                "--keep", str(tmp_path / "k")]) == 0
    assert "dark: 4 frames from camera Fake_1" in capsys.readouterr().out
    cal = load_calibration(out)
    assert cal.camera_id == "Fake_1" and cal.shape == (32, 64) and str(cal.layout) == "imx250mzr"
    assert cal.roi == [0, 0, 64, 32] and cal.exposure_us == pytest.approx(100)
    info = cal.stages["dark"]
    assert info["device"] == "Fake_1" and info["camera_id"] == "Fake_1" and info["camera"]["vendor"] == "Aravis"
    assert info["frames_good"] == 4 and info["frames_incomplete"] == 0
    kept = sorted((tmp_path / "k").glob("*.raw"))
    assert len(kept) == 4
    for path in kept:  # the camera's bytes: the scaled ramp, clamped to 0
        assert np.frombuffer(path.read_bytes(), np.uint8).reshape(32, 64).max() == 0
    assert np.all(cal.maps["dark"] == 0)
    lit = tmp_path / "lit-dark.npz"
    with pytest.raises(CalibrationError, match=r"not a dark frame: mean level \d+(\.\d+)? counts, \d+\.\d% of the range"):
        run(["calibrate", "dark", "--device", "Fake_1", "--pixel-format", "Mono8", "--layout", "imx250mzr",
             "--roi", "0", "0", "64", "32", "--frames", "4", "-o", str(lit)])
    assert not lit.exists()


def test_standalone_command_exits_3_for_a_camera_that_is_not_there(tmp_path, capsys):
    # the same exit statuses as `polcam calibrate`: 3 when the camera cannot be had, and no file
    out = tmp_path / "dark.npz"
    rc = main(["dark", "--device", f"replay:{tmp_path / 'missing'}", "--frames", "2", "-o", str(out)])
    assert rc == 3 and "does not exist" in capsys.readouterr().err
    assert not out.exists()


def test_dark_of_lit_frames_is_refused_naming_the_frame_and_its_level(folders, tmp_path, capsys):
    """The flat frames (a lit, uniform field) given as darks: refused, nothing written."""
    from polcam.cli import main as polcam_main

    root, sensor = folders
    first = sorted((root / "flat").glob("*.png"))[0]
    mean = float(np.mean(read_frame(first).mosaic))
    target = tmp_path / "dark.npz"
    assert polcam_main(["calibrate", "dark", str(root / "flat"), "-o", str(target)]) == 2
    err = capsys.readouterr().err
    assert f"{first}: not a dark frame: mean level {mean:.4g} counts" in err
    assert not target.exists()
