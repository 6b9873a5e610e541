"""``polcam capture``: live maps, lossless saving, the replay and Aravis cameras end to end,
Rerun output, clean stops on SIGTERM and no partial files on SIGKILL, errors, and the live view
corrected by a calibration (``--calibration``) while the saved frames stay raw."""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from polcam import polarimetry as st
from polcam.acquisition import FrameSaver, StopRequest, run_capture
from polcam.camera import AravisCamera, ReplayCamera, aravis_available
from polcam.camera.emulator import emulator_available, gige_emulator
from polcam.commands.capture import add_capture_parser, main
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.errors import FrameWriteError, LayoutError, MethodError
from polcam.frame import Frame
from polcam.io import read_frame, read_sidecar, write_frame
from polcam.mosaic import parse_layout
from polcam.pipeline import live_maps

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "fixtures" / "raw"

needs_aravis = pytest.mark.skipif(not aravis_available(), reason="Aravis 0.8 is not installed")
needs_emulator = pytest.mark.skipif(
    not (aravis_available() and emulator_available()), reason="Aravis GigE emulator not installed"
)


def _visible_frames(out: Path) -> list[str]:
    return sorted(p.name for p in out.glob("frame_*") if p.suffix != ".json")


def _hidden(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.name.startswith("."))


def _ramp(side: dict) -> np.ndarray:
    """Aravis' fake camera image in Mono8: (x + y + frame id) mod 255."""
    x0, y0, w, h = side["roi"]
    y, x = np.mgrid[y0:y0 + h, x0:x0 + w]
    return ((x + y + side["frame_id"]) % 255).astype(np.uint8)


# ---------------------------------------------------------------------------
# live maps against the reference implementation
# ---------------------------------------------------------------------------

def test_live_maps_mono_equal_the_reference_path():
    rng = np.random.default_rng(0)
    raw = rng.integers(64, 4096, (48, 80)).astype(np.uint16)
    lay = parse_layout("mono:45,90,0,135")
    black, white = 64.0, 4095.0
    m = live_maps(raw, lay, black_level=black, white_level=white)
    stack = demosaic((raw.astype(np.float64) - black) / (white - black), layout=lay, resolution="cell")
    s = st.stokes(stack)
    assert m.ic.shape == (24, 40) and m.scale == 1.0
    np.testing.assert_allclose(m.ic, s.s0 / 2, atol=1e-6)
    np.testing.assert_allclose(m.dolp, st.dolp(s), atol=2e-6)
    da = np.abs(np.angle(np.exp(2j * (m.aolp - st.aolp(s))))) / 2  # difference modulo pi
    assert da.max() < 1e-4
    assert m.aolp.min() >= 0 and m.aolp.max() < np.pi
    np.testing.assert_allclose(m.diffuse, np.maximum(st.imin(stack), 0), atol=1e-6)
    np.testing.assert_allclose(m.diffuse + m.specular, s.s0 / 2, atol=1e-6)


def test_live_maps_imin_layers_equal_the_imin_method():
    from polcam.separation import separate

    rng = np.random.default_rng(1)
    stack = rng.random((4, 16, 20)).astype(np.float32)
    raw = np.rint(mosaic_stack(stack, layout="imx250mzr") * 255).astype(np.uint8)
    cell = demosaic(raw, layout="imx250mzr", resolution="cell")
    ref = separate(cell, method="imin")
    m = live_maps(raw, parse_layout("imx250mzr"))
    np.testing.assert_allclose(m.diffuse, ref.diffuse, atol=1e-6)
    np.testing.assert_allclose(m.specular, ref.specular, atol=1e-6)


@pytest.mark.parametrize("layout", ["imx250myr", "color:45,90,0,135:GBRG", "color:90,45,135,0:BGGR"])
def test_live_maps_colour_on_uniform_colour(layout):
    # each channel: its own Ic, Isv, phase, uniform over the image
    ic = np.array([0.55, 0.35, 0.2])
    isv = np.array([0.2, 0.1, 0.05])
    phi = np.deg2rad([30.0, 40.0, 100.0])
    t = np.deg2rad([0, 45, 90, 135])[:, None]
    vals = ic + isv * np.cos(2 * t - 2 * phi)  # (4 angles, 3 channels)
    stack = np.broadcast_to(vals[:, None, None, :], (4, 32, 48, 3))
    raw = np.rint(mosaic_stack(stack, layout=layout) * 4095).astype(np.uint16)
    m = live_maps(raw, parse_layout(layout), white_level=4095)
    inner = (slice(2, -2), slice(2, -2))
    assert m.ic.shape == (16, 24, 3) and m.ic.dtype == np.uint8
    np.testing.assert_allclose(m.normalized("ic")[inner], np.broadcast_to(ic, (12, 20, 3)), atol=1.01 / 255)
    imin = np.maximum(ic - isv, 0)
    np.testing.assert_allclose(m.normalized("diffuse")[inner], np.broadcast_to(imin, (12, 20, 3)),
                               atol=1.01 / 255)
    np.testing.assert_allclose(m.normalized("specular")[inner], np.broadcast_to(ic - imin, (12, 20, 3)),
                               atol=2.01 / 255)
    # DoLP / AoLP of the luminance-weighted Stokes vector (R + 2G + B) / 4
    w = np.array([1, 2, 1]) / 4
    s0 = 2 * ic @ w
    s1 = (2 * isv * np.cos(2 * phi)) @ w
    s2 = (2 * isv * np.sin(2 * phi)) @ w
    assert np.abs(m.dolp[inner] - np.hypot(s1, s2) / s0).max() < 2e-3
    aolp = np.mod(0.5 * np.arctan2(s2, s1), np.pi)
    assert np.abs(np.angle(np.exp(2j * (m.aolp[inner] - aolp)))).max() / 2 < 2e-3


@pytest.mark.parametrize("layout", ["mono:45,90,0,135", "imx250myr"])
def test_live_maps_of_a_float_mosaic_equal_those_of_its_counts(layout):
    # a calibrated mosaic is float32 counts above the dark: the same maps as the integer counts
    rng = np.random.default_rng(2)
    raw = rng.integers(64, 4096, (32, 48)).astype(np.uint16)
    lay = parse_layout(layout)
    ref = live_maps(raw, lay, black_level=64.0, white_level=4095.0)
    got = live_maps(raw.astype(np.float32) - 64.0, lay, black_level=0.0, white_level=4095.0 - 64.0)
    assert got.ic.shape == ref.ic.shape and got.ic.dtype == ref.ic.dtype and got.scale == ref.scale
    np.testing.assert_allclose(got.dolp, ref.dolp, atol=1e-5)
    da = np.abs(np.angle(np.exp(2j * (got.aolp.astype(np.float64) - ref.aolp)))) / 2
    assert da[ref.dolp > 1e-3].max() < 1e-4
    for name in ("ic", "diffuse", "specular"):  # colour: 8-bit values, rounding may differ by one step
        np.testing.assert_allclose(got.normalized(name), ref.normalized(name), atol=1.01 * ref.scale + 1e-6)
    # float64 is accepted too; a float mosaic needs its white level
    np.testing.assert_allclose(live_maps(raw.astype(np.float64) - 64.0, lay, white_level=4031.0).dolp, got.dolp,
                               atol=1e-6)
    with pytest.raises(LayoutError, match="white level"):
        live_maps(raw.astype(np.float32), lay)


def test_live_maps_refuse_bad_input():
    lay = parse_layout("imx250mzr")
    with pytest.raises(LayoutError, match="uint8/uint16"):
        live_maps(np.zeros((8, 8), np.int32), lay)
    with pytest.raises(LayoutError, match="uint8/uint16"):
        live_maps(np.zeros((8, 8), np.float16), lay)
    with pytest.raises(LayoutError, match="even"):
        live_maps(np.zeros((9, 8), np.uint8), lay)
    with pytest.raises(LayoutError, match="white level"):
        live_maps(np.zeros((8, 8), np.uint8), lay, black_level=10, white_level=10)


# ---------------------------------------------------------------------------
# saving
# ---------------------------------------------------------------------------

def test_saver_writes_payload_bytes_and_sidecars(tmp_path):
    from polcam.camera.base import CapturedFrame

    mosaic = np.arange(24, dtype=np.uint16).reshape(4, 6) * 100
    payload = mosaic.astype("<u2").tobytes()
    f = CapturedFrame(mosaic=mosaic, layout="imx250mzr", bit_depth=12,
                      metadata={"pixel_format": "Mono12", "frame_id": 9}, payload=payload)
    saver = FrameSaver(tmp_path, ".raw", workers=2)
    assert saver.put(0, f)
    assert saver.put(1, Frame(mosaic=mosaic, layout="imx250mzr", bit_depth=12))  # no payload: write_frame
    saver.close()
    assert sorted(saver.saved) == ["frame_000000.raw", "frame_000001.raw"]
    assert (tmp_path / "frame_000000.raw").read_bytes() == payload
    side = read_sidecar(tmp_path / "frame_000000.raw")
    assert side["frame_id"] == 9 and side["pixel_format"] == "Mono12" and side["layout"] == "imx250mzr"
    for name in saver.saved:
        back = read_frame(tmp_path / name)
        np.testing.assert_array_equal(back.mosaic, mosaic)
    assert _hidden(tmp_path) == []


# ---------------------------------------------------------------------------
# the replay camera end to end
# ---------------------------------------------------------------------------

def _replay_folder(tmp_path: Path, fixture: str, n: int = 3) -> tuple[Path, list[Frame]]:
    """n distinct frames made from a fixture (rolled by whole layout periods), with sidecars."""
    src = read_frame(FIXTURES / f"{fixture}.png")
    folder = tmp_path / f"replay-{fixture}"
    folder.mkdir()
    frames = []
    for i in range(n):
        f = Frame(mosaic=np.roll(src.mosaic, 4 * i, axis=1), layout=src.layout, bit_depth=src.bit_depth,
                  black_level=src.black_level, white_level=src.white_level,
                  metadata={k: v for k, v in src.metadata.items() if k in ("pixel_format", "vendor", "roi")})
        write_frame(folder / f"{fixture}_{i:02d}.png", f)
        frames.append(f)
    return folder, frames


def test_replay_capture_saves_frames_identical_to_the_inputs(tmp_path):
    folder, inputs = _replay_folder(tmp_path, "fruits_crop", n=3)
    out = tmp_path / "out"
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=out, separate=None, rerun=None)
    assert summary["stop_reason"] == "end of stream"
    assert summary["frames_good"] == summary["frames_received"] == summary["frames_saved"] == 3
    assert summary["frames_dropped"] == summary["frames_incomplete"] == 0
    assert summary["files"] == _visible_frames(out) == [f"frame_{i:06d}.raw" for i in range(3)]
    for name, src in zip(summary["files"], inputs):
        back = read_frame(out / name)
        np.testing.assert_array_equal(back.mosaic, src.mosaic)
        assert back.layout == src.layout and back.bit_depth == src.bit_depth
        assert back.metadata["pixel_format"] == "Polarized8"
        side = read_sidecar(out / name)
        assert side["camera_id"] == f"replay:{folder}" and side["roi"] == [1024, 256, 640, 512]
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["files"] == summary["files"]


@pytest.mark.parametrize("fmt,ext", [("npy", ".npy"), ("tiff", ".tif")])
def test_other_lossless_formats(tmp_path, fmt, ext):
    folder, inputs = _replay_folder(tmp_path, "synthetic_bunny5", n=2)
    out = tmp_path / "out"
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=out, save_format=fmt, separate=None)
    assert summary["files"] == [f"frame_{i:06d}{ext}" for i in range(2)]
    for name, src in zip(summary["files"], inputs):
        np.testing.assert_array_equal(read_frame(out / name).mosaic, src.mosaic)


def _rrd_frames(path: Path) -> dict[str, set[int]]:
    import rerun.chunk as ch

    frames: dict[str, set[int]] = defaultdict(set)
    for chunk in ch.RrdReader(path).stream():
        if chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        if "frame" in rb.schema.names:
            frames[str(chunk.entity_path)] |= set(rb.column("frame").to_pylist())
    return frames


@pytest.mark.parametrize("method", ["imin", "shen13"])
def test_replay_capture_with_separation_writes_the_rerun_recording(tmp_path, method):
    folder, _ = _replay_folder(tmp_path, "synthetic_bunny5", n=4)
    rrd = tmp_path / "live.rrd"
    with ReplayCamera(folder, frame_rate=20.0) as cam:
        summary = run_capture(cam, out=tmp_path / "out", separate=method, rerun=rrd, raw_every=1)
    assert summary["frames_saved"] == 4
    processed = summary["frames_processed"]
    assert processed >= 1 and processed + summary["frames_skipped"] == summary["frames_received"] == 4
    assert summary["separations"] >= 1 and summary["separation_errors"] == []
    frames = _rrd_frames(rrd)
    shown = frames["/polarization/s0"]
    assert len(shown) == processed and shown <= {0, 1, 2, 3}
    for entity in ("/polarization/dolp", "/polarization/aolp", "/camera/raw", "/stats/fps",
                   "/stats/dropped", "/stats/incomplete"):
        assert frames[entity] == shown, entity
    assert len(frames["/layers/diffuse"]) == len(frames["/layers/specular"]) == summary["separations"]
    assert frames["/layers/diffuse"] <= shown
    if method != "imin":
        assert len(frames["/stats/separation_seconds"]) == summary["separations"]


def test_separation_options_reach_the_live_method_and_are_checked_first(tmp_path):
    folder, _ = _replay_folder(tmp_path, "synthetic_bunny5", n=2)
    # a device name no backend accepts: each live run fails on it, so the errors prove the
    # option reached the method (with or without PyTorch installed)
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=None, separate="tensor", separate_options={"device": "nonsense"})
    assert summary["separation_options"] == {"device": "nonsense"}
    assert summary["separations"] == 0 and summary["separation_errors"]
    assert all("device 'nonsense'" in e for e in summary["separation_errors"])
    # a valid option: separations run, and the summary records it
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=None, separate="tensor", separate_options={"max_iter": 3})
    assert summary["separations"] >= 1 and summary["separation_errors"] == []
    assert summary["separation_options"] == {"max_iter": 3}
    # refused before the camera starts: nothing is written
    for sep, opts, match in [("tensor", {"speed": 9}, "takes no option 'speed'"),
                             ("imin", {"max_iter": 3}, "live imin layers take no options"),
                             (None, {"max_iter": 3}, "without a separation method")]:
        out = tmp_path / f"out-{sep}"
        with ReplayCamera(folder) as cam:
            with pytest.raises(MethodError, match=match):
                run_capture(cam, out=out, separate=sep, separate_options=opts)
        assert not out.exists()


def test_cli_separate_option_is_parsed_and_recorded(tmp_path):
    from polcam.commands.capture import main

    folder, _ = _replay_folder(tmp_path, "synthetic_bunny5", n=2)
    out = tmp_path / "out"
    assert main(["--device", f"replay:{folder}", "--frames", "2", "--out", str(out), "--separate", "tensor",
                 "--separate-option", "max_iter=3", "--separate-option", "tile=[16, 16]", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["separation_options"] == {"max_iter": 3, "tile": [16, 16]}
    assert main(["--device", f"replay:{folder}", "--frames", "1", "--no-save", "--separate", "tensor",
                 "--separate-option", "max_iter", "--quiet"]) == 2


def test_existing_frames_need_append(tmp_path):
    folder, _ = _replay_folder(tmp_path, "fruits_crop", n=1)
    out = tmp_path / "out"
    with ReplayCamera(folder) as cam:
        run_capture(cam, out=out, separate=None)
    with ReplayCamera(folder) as cam:
        with pytest.raises(FrameWriteError, match="--append"):
            run_capture(cam, out=out, separate=None)
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=out, separate=None, append=True)
    assert summary["files"] == ["frame_000001.raw"]
    assert _visible_frames(out) == ["frame_000000.raw", "frame_000001.raw"]


def test_stop_request_ends_the_capture(tmp_path):
    folder, _ = _replay_folder(tmp_path, "fruits_crop", n=2)
    stop = StopRequest()
    stop.request("test stop")
    with ReplayCamera(folder, loop=True) as cam:
        summary = run_capture(cam, out=tmp_path / "out", separate=None, stop=stop)
    assert summary["stop_reason"] == "test stop"
    assert summary["frames_saved"] == summary["frames_received"] == len(summary["files"])


def test_live_processing_needs_a_layout_and_a_suitable_method(tmp_path):
    folder = tmp_path / "plain"
    folder.mkdir()
    write_frame(folder / "a.npy", Frame(mosaic=np.zeros((8, 8), np.uint8)))
    with ReplayCamera(folder) as cam:
        with pytest.raises(LayoutError, match="--layout"):
            run_capture(cam, out=None, separate="imin")
    mono, _ = _replay_folder(tmp_path, "fruits_crop", n=1)
    with ReplayCamera(mono) as cam:
        with pytest.raises(MethodError, match="colour"):
            run_capture(cam, out=None, separate="tensor")


# ---------------------------------------------------------------------------
# Aravis: the in-process Fake camera and the GigE Vision emulator
# ---------------------------------------------------------------------------

@needs_aravis
@pytest.mark.camera
def test_fake_camera_capture_saves_what_the_buffers_carried(tmp_path):
    out = tmp_path / "out"
    with AravisCamera("Fake_1", n_buffers=8) as cam:
        cam.configure(pixel_format="Mono8", layout="imx250mzr", roi=(0, 0, 128, 64), frame_rate=100)
        summary = run_capture(cam, out=out, frames=12, separate="imin", idle_timeout=30)
    assert summary["stop_reason"] == "frames" and summary["error"] is None
    assert summary["frames_received"] == summary["frames_saved"] == 12
    assert summary["frames_good"] >= 12 and summary["frames_incomplete"] == 0
    assert summary["files"] == _visible_frames(out)
    ids = []
    for name in summary["files"]:
        side = read_sidecar(out / name)
        data = (out / name).read_bytes()
        assert len(data) == 128 * 64
        np.testing.assert_array_equal(np.frombuffer(data, np.uint8).reshape(64, 128), _ramp(side))
        assert side["layout"] == "imx250mzr" and side["pixel_format"] == "Mono8"
        ids.append(side["frame_id"])
    assert len(set(ids)) == 12


@needs_emulator
@pytest.mark.camera
def test_gige_emulator_capture_with_packet_loss(tmp_path):
    out = tmp_path / "out"
    with gige_emulator(lost_per_thousand=3) as dev:
        with AravisCamera(dev, packet_size=1400, n_buffers=8) as cam:
            cam.configure(pixel_format="Mono8", layout="imx250mzr", roi=(0, 0, 512, 512), frame_rate=50)
            summary = run_capture(cam, out=out, frames=15, separate=None, idle_timeout=30)
    assert summary["error"] is None and summary["frames_saved"] == summary["frames_received"] == 15
    # about 4 in 10 frames lose a packet at this size: counted, never saved
    assert summary["frames_incomplete"] >= 1
    # every incomplete frame is counted under its buffer status: lost packets here, and on a
    # loaded machine sometimes a buffer that timed out waiting for its resent packets
    bad = {k: v for k, v in summary["by_status"].items() if k not in ("success", "aborted", "cleared")}
    assert sum(bad.values()) == summary["frames_incomplete"]
    assert set(bad) <= {"missing-packets", "timeout"} and bad.get("missing-packets", 0) >= 1
    assert summary["stream"]["n_missing_packets"] >= bad.get("missing-packets", 0)
    assert summary["files"] == _visible_frames(out)
    for name in summary["files"]:  # every saved frame is complete and exact
        side = read_sidecar(out / name)
        got = np.frombuffer((out / name).read_bytes(), np.uint8).reshape(512, 512)
        np.testing.assert_array_equal(got, _ramp(side))


# ---------------------------------------------------------------------------
# signals: a capture subprocess stopped with SIGTERM or killed with SIGKILL
# ---------------------------------------------------------------------------

def _start_capture(folder: Path, out: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "polcam.capture", "--device", f"replay:{folder}", "--loop",
           "--frame-rate", "40", "--out", str(out), "--separate", "none", "--quiet", "--timeout", "60"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=REPO, start_new_session=True)


def _wait_for_frames(proc: subprocess.Popen, out: Path, n: int, timeout: float = 90.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if out.is_dir() and len(_visible_frames(out)) >= n:
            return
        if proc.poll() is not None:
            raise AssertionError(f"capture exited early: {proc.communicate()}")
        time.sleep(0.05)
    raise AssertionError(f"no {n} frames in {timeout} s")


def _stop(proc: subprocess.Popen) -> None:
    """Kill the capture if it still runs, and close its pipes."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)


def _signal_folder(tmp_path: Path) -> tuple[Path, list[np.ndarray]]:
    folder = tmp_path / "in"
    folder.mkdir()
    rng = np.random.default_rng(5)
    mosaics = []
    for i in range(4):
        m = rng.integers(0, 4096, (128, 160)).astype(np.uint16)
        write_frame(folder / f"f{i}.npy", Frame(mosaic=m, layout="imx250mzr", bit_depth=12))
        mosaics.append(m)
    return folder, mosaics


def test_sigterm_stops_cleanly_and_the_summary_matches_the_files(tmp_path):
    folder, mosaics = _signal_folder(tmp_path)
    out = tmp_path / "out"
    proc = _start_capture(folder, out)
    try:
        _wait_for_frames(proc, out, 5)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        _stop(proc)
    assert proc.returncode == 0, stderr
    assert "signal SIGTERM" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stop_reason"] == "signal SIGTERM"
    files = _visible_frames(out)
    assert summary["files"] == files and summary["frames_saved"] == len(files) >= 5
    assert summary["frames_unsaved"] == 0 and summary["frames_save_failed"] == 0
    assert _hidden(out) == []
    for name in files:  # frame i of the loop is input file i mod 4
        side = read_sidecar(out / name)
        np.testing.assert_array_equal(read_frame(out / name).mosaic, mosaics[side["frame_id"] % 4])


def test_sigkill_leaves_no_partial_frame(tmp_path):
    folder, mosaics = _signal_folder(tmp_path)
    out = tmp_path / "out"
    proc = _start_capture(folder, out)
    try:
        _wait_for_frames(proc, out, 5)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=30)
    finally:
        _stop(proc)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "summary.json").exists()
    files = _visible_frames(out)
    assert len(files) >= 5
    for name in files:  # every frame file on disk is complete, with its sidecar
        side = read_sidecar(out / name)
        assert side is not None
        np.testing.assert_array_equal(read_frame(out / name).mosaic, mosaics[side["frame_id"] % 4])
    # temporaries of the interrupted writes are hidden, and a kill between the sidecar's rename and
    # the frame's can leave that sidecar alone; the next capture there removes both
    leftovers = _hidden(out)
    assert all(n.startswith(".frame_") for n in leftovers)
    stems = {Path(f).stem for f in files}
    orphans = sorted(p.name for p in out.glob("frame_*.json") if p.stem not in stems)
    assert len(orphans) <= 4  # at most the frames the 4 writer threads were writing
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=out, separate=None, append=True)
    assert summary["stale_temporaries_removed"] == len(leftovers) + len(orphans)
    assert _hidden(out) == []
    stems = {Path(f).stem for f in _visible_frames(out)}
    assert {p.stem for p in out.glob("frame_*.json")} == stems  # the orphan went (its number is reused)


# ---------------------------------------------------------------------------
# the command line: errors that say what to do
# ---------------------------------------------------------------------------

def test_parser_accepts_the_documented_flags():
    p = argparse.ArgumentParser()
    add_capture_parser(p.add_subparsers())
    args = p.parse_args(["capture", "--device", "Fake_1", "--frames", "5", "--out", "x", "--pixel-format",
                         "Mono8", "--layout", "imx250mzr", "--exposure", "1000", "--gain", "2",
                         "--separate", "none", "--rerun", "a.rrd", "--roi", "0", "0", "64", "32",
                         "--calibration", "cam.npz"])
    assert (args.device, args.frames, args.roi, args.separate) == ("Fake_1", 5, [0, 0, 64, 32], "none")
    assert args.calibration == Path("cam.npz")
    with pytest.raises(SystemExit):
        p.parse_args(["capture", "--device", "x", "--frames", "2", "--duration", "3"])


def test_unknown_device_says_how_to_list_cameras(tmp_path, capsys):
    rc = main(["--device", "NoSuchCamera-4242", "--frames", "1", "--no-save", "--quiet"])
    err = capsys.readouterr().err
    if aravis_available():
        assert rc == 3 and "polcam devices" in err and "NoSuchCamera-4242" in err
    else:
        assert rc == 3 and "install" in err
    rc = main(["--device", f"replay:{tmp_path / 'missing'}", "--no-save", "--quiet"])
    assert rc == 3 and "does not exist" in capsys.readouterr().err


@needs_aravis
@pytest.mark.camera
def test_unsupported_pixel_format_lists_the_supported_ones(capsys):
    rc = main(["--device", "Fake_1", "--pixel-format", "RGB8", "--layout", "imx250mzr", "--frames", "1",
               "--no-save", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "RGB8" in err and "supported" in err
    assert "Mono8" in err and "Mono16" in err and "BayerRG8" in err


def test_bad_numbers_are_refused(tmp_path, capsys):
    folder, _ = _replay_folder(tmp_path, "fruits_crop", n=1)
    assert main(["--device", f"replay:{folder}", "--frames", "0", "--no-save"]) == 2
    assert "--frames" in capsys.readouterr().err


def test_capture_command_on_replay(tmp_path, capsys):
    folder, inputs = _replay_folder(tmp_path, "fruits_crop", n=2)
    out = tmp_path / "out"
    rc = main(["--device", f"replay:{folder}", "--out", str(out), "--format", "npy", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0 and "end of stream" in text and "saved 2" in text
    assert _visible_frames(out) == ["frame_000000.npy", "frame_000001.npy"]
    for i, src in enumerate(inputs):
        np.testing.assert_array_equal(np.load(out / f"frame_{i:06d}.npy"), src.mosaic)


# ---------------------------------------------------------------------------
# --calibration: the live view of a miscalibrated sensor, corrected
# ---------------------------------------------------------------------------

CAL_SIZE = 32  # sensor pixels (16 x 16 polarizer cells)


def _cell_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stokes maps constant over each 2x2 cell: S0 0.9, DoLP 0.15..0.45 along x, AoLP 0..180 along y.

    Returns the (H, W) maps S0, S1, S2 of the sensor and, per cell, the true DoLP and AoLP (radians).
    """
    n = CAL_SIZE // 2
    dolp = np.broadcast_to(np.linspace(0.15, 0.45, n)[None, :], (n, n))
    aolp = np.broadcast_to(np.deg2rad(np.arange(n) * 180.0 / n + 5.0)[:, None], (n, n))
    s0 = np.full((n, n), 0.9)
    s1, s2 = s0 * dolp * np.cos(2 * aolp), s0 * dolp * np.sin(2 * aolp)
    up = [np.repeat(np.repeat(m, 2, axis=0), 2, axis=1) for m in (s0, s1, s2)]
    return (up[0], up[1], up[2]), dolp, aolp


@pytest.fixture(scope="module")
def miscalibrated(tmp_path_factory):
    """A replay folder of a synthetic scene seen by an imperfect sensor, and that sensor's calibration file."""
    from polcam.calibration import calibrate_dark, calibrate_flat, calibrate_polarizer, save_calibration
    from polcam.synth.sensor import ImperfectSensor

    root = tmp_path_factory.mktemp("miscalibrated")
    sensor = ImperfectSensor.random("imx250mzr", CAL_SIZE, CAL_SIZE, seed=11)
    dark = calibrate_dark(sensor.frames((0, 0, 0), n=16, rng=1))
    flat = calibrate_flat(sensor.frames((1.2, 0, 0), n=32, rng=2), base=dark)
    angles = np.repeat(np.arange(16) * 11.25, 16)
    frames = (fr for a in np.arange(16) * 11.25
              for fr in sensor.frames((0.8, 0.8 * np.cos(np.deg2rad(2 * a)), 0.8 * np.sin(np.deg2rad(2 * a))),
                                      n=16, rng=int(a * 100)))
    cal = calibrate_polarizer(frames, angles, base=flat)
    cal_file = save_calibration(root / "camera.npz", cal)
    scene, dolp, aolp = _cell_scene()
    for name, seen_by in (("scene", sensor), ("ideal", sensor.ideal())):  # ideal: the same noise, no flaws
        (root / name).mkdir()
        for i, fr in enumerate(seen_by.frames(scene, n=12, rng=3)):
            write_frame(root / name / f"scene_{i:02d}.png", fr)
    return root / "scene", cal_file, dolp, aolp


def _rrd_images(path: Path, entity: str, prefix: str) -> dict[int, np.ndarray]:
    """{frame: (h, w) or (h, w, channels) uint8 image} of one entity of a .rrd, read back with Rerun's reader."""
    import rerun.chunk as ch

    out: dict[int, np.ndarray] = {}
    for chunk in ch.RrdReader(path).stream():
        if chunk.is_static or str(chunk.entity_path) != entity:
            continue
        rb = chunk.to_record_batch()
        if f"{prefix}:buffer" not in rb.schema.names:
            continue
        for i, frame in enumerate(rb.column("frame").to_pylist()):
            fmt = rb.column(f"{prefix}:format")[i].as_py()[0]
            buf = np.asarray(rb.column(f"{prefix}:buffer")[i].as_py()[0], dtype=np.uint8)
            img = buf.reshape(fmt["height"], fmt["width"], -1)
            out[frame] = img[..., 0] if img.shape[2] == 1 else img
    return out


def _live_errors(rrd: Path, dolp_true: np.ndarray, aolp_true: np.ndarray) -> tuple[float, float, int]:
    """Mean |DoLP error| and mean |AoLP error| (degrees) of the logged live maps, over the frames logged."""
    dolp_ids = _rrd_images(rrd, "/polarization/dolp", "SegmentationImage")
    aolp_ids = _rrd_images(rrd, "/polarization/aolp", "SegmentationImage")
    assert dolp_ids and sorted(dolp_ids) == sorted(aolp_ids)
    e_dolp, e_aolp = [], []
    for k in dolp_ids:
        dolp = (dolp_ids[k].astype(np.float64) - 1) / 254            # class 1 + round(254 DoLP)
        aolp = np.deg2rad(aolp_ids[k].astype(np.float64) - 1)        # class 1 + round(degrees)
        e_dolp.append(np.abs(dolp - dolp_true).mean())
        e_aolp.append(np.rad2deg(np.abs(np.angle(np.exp(2j * (aolp - aolp_true)))) / 2).mean())
    return float(np.mean(e_dolp)), float(np.mean(e_aolp)), len(dolp_ids)


def test_calibrated_live_view_is_closer_to_the_truth_and_raw_stays_raw(miscalibrated, tmp_path, capsys):
    import hashlib

    folder, cal_file, dolp_true, aolp_true = miscalibrated
    runs = {}
    for name, extra in (("raw", []), ("calibrated", ["--calibration", str(cal_file)])):
        out, rrd = tmp_path / name, tmp_path / f"{name}.rrd"
        rc = main(["--device", f"replay:{folder}", "--out", str(out), "--rerun", str(rrd), "--view-scale", "1",
                   "--quiet", *extra])
        assert rc == 0, capsys.readouterr().err
        runs[name] = (out, json.loads((out / "summary.json").read_text()), _live_errors(rrd, dolp_true, aolp_true))
    (out0, sum0, (d0, a0, n0)), (out1, sum1, (d1, a1, n1)) = runs["raw"], runs["calibrated"]
    ideal = tmp_path / "ideal.rrd"  # the noise floor: an ideal sensor with the same noise, uncalibrated
    assert main(["--device", f"replay:{folder.parent / 'ideal'}", "--no-save", "--rerun", str(ideal),
                 "--view-scale", "1", "--quiet"]) == 0
    d2, a2, n2 = _live_errors(ideal, dolp_true, aolp_true)
    print(f"live view, mean |error| per frame over {n0} / {n1} / {n2} frames: DoLP {d0:.4f} -> {d1:.4f} "
          f"(ideal sensor {d2:.4f}), AoLP {a0:.2f} -> {a1:.2f} deg (ideal sensor {a2:.2f})")
    # the uncalibrated sensor's fixed pattern is gone: what is left is about the ideal sensor's noise
    assert d1 < d0 / 3 and a1 < a0 / 3
    assert d1 < 1.3 * d2 and a1 < 1.3 * a2
    # raw is raw: the saved files are the same bytes either way, and the camera's counts
    assert sum0["frames_saved"] == sum1["frames_saved"] == 12 and sum0["files"] == sum1["files"]
    for name in sum0["files"]:
        assert (out0 / name).read_bytes() == (out1 / name).read_bytes()
        src = read_frame(folder / f"scene_{int(name[6:12]):02d}.png")
        np.testing.assert_array_equal(read_frame(out1 / name).mosaic, src.mosaic)
        s0, s1 = read_sidecar(out0 / name), read_sidecar(out1 / name)
        s0.pop("timestamp_ns"), s1.pop("timestamp_ns")
        assert s0 == s1 and "calibration" not in s1
    # the summary records the calibration file and its SHA-256, as process does in meta.json
    assert sum1["calibration"] == str(cal_file)
    assert sum1["calibration_sha256"] == hashlib.sha256(cal_file.read_bytes()).hexdigest()
    assert sum1["calibration_stages"] == ["dark", "flat", "polarizer"]
    assert sum0["calibration"] is None and sum0["calibration_sha256"] is None


def _mismatched(root: Path, kind: str) -> Path:
    """A calibration file that does not fit the miscalibrated scene: another size, layout or camera."""
    from polcam.calibration import Calibration, save_calibration

    h, w, layout, camera = CAL_SIZE, CAL_SIZE, "imx250mzr", "synthetic-imx250"
    if kind == "size":
        w += 8
    elif kind == "layout":
        layout = "mono:45,90,0,135"
    else:
        camera = "another-camera"
    cal = Calibration(layout=layout, height=h, width=w, bit_depth=12, camera_id=camera,
                      maps={"dark": np.full((h, w), 64.0, np.float32), "dark_noise": np.ones((h, w), np.float32),
                            "hot": np.zeros((h, w), bool)})
    return save_calibration(root / f"other-{kind}.npz", cal)


@pytest.mark.parametrize(("kind", "message"), [
    ("size", r"size mismatch: the frame has size 32x32, calibration .*other-size.npz is for 40x32"),
    ("layout", r"layout mismatch: camera replay:.* sends layout imx250mzr, calibration .*other-layout.npz is "
               r"for mono:45,90,0,135"),
    ("camera", r"camera_id mismatch: the frame has camera_id 'synthetic-imx250', calibration .*other-camera.npz "
               r"is for 'another-camera'"),
])
def test_a_calibration_that_does_not_fit_is_refused_before_anything_is_saved(miscalibrated, tmp_path, capsys,
                                                                              kind, message):
    from polcam.calibration import CalibrationError, load_calibration

    folder, _, _, _ = miscalibrated
    cal = load_calibration(_mismatched(tmp_path, kind))
    out, rrd = tmp_path / "out", tmp_path / "live.rrd"
    with ReplayCamera(folder) as cam:
        with pytest.raises(CalibrationError, match=message):
            run_capture(cam, out=out, separate="imin", rerun=rrd, calibration=cal)
    assert not out.exists() and not rrd.exists()  # what it created is gone again: nothing half-written
    # the command: an error exit, the message on stderr, no frame and no summary
    (tmp_path / "kept").mkdir()
    rc = main(["--device", f"replay:{folder}", "--out", str(tmp_path / "kept"), "--calibration",
               str(tmp_path / f"other-{kind}.npz"), "--quiet"])
    assert rc == 2 and re.search(message, capsys.readouterr().err)
    assert list((tmp_path / "kept").iterdir()) == []


def test_capture_calibration_file_errors_name_the_file(miscalibrated, tmp_path, capsys):
    folder, _, _, _ = miscalibrated
    rc = main(["--device", f"replay:{folder}", "--no-save", "--calibration", str(tmp_path / "none.npz"), "--quiet"])
    assert rc == 2 and "none.npz: calibration file not found" in capsys.readouterr().err


def test_calibrated_colour_capture_separates_the_corrected_stack(tmp_path):
    # colour sensor, a separation method on its own thread: the layers it logs are those of the
    # corrected mosaic (apply_calibration, then the bilinear cell stack), not of the raw one
    from polcam.calibration import apply_calibration, calibrate_dark, calibrate_polarizer, save_calibration
    from polcam.separation import separate
    from polcam.sinks.rerun import unit_u8
    from polcam.synth.sensor import ImperfectSensor

    sensor = ImperfectSensor.random("imx250myr", 16, 16, seed=5, hot_fraction=0.0)
    dark = calibrate_dark(sensor.frames((0, 0, 0), n=4, rng=1))
    angles = np.repeat(np.arange(8) * 22.5, 2)
    frames = (fr for a in np.arange(8) * 22.5
              for fr in sensor.frames((0.8, 0.8 * np.cos(np.deg2rad(2 * a)), 0.8 * np.sin(np.deg2rad(2 * a))),
                                      n=2, rng=int(a * 10)))
    cal = calibrate_polarizer(frames, angles, base=dark)
    save_calibration(tmp_path / "cal.npz", cal)
    folder = tmp_path / "scene"
    folder.mkdir()
    rgb = np.stack([np.full((16, 16), v) for v in (0.9, 0.6, 0.3)], axis=-1)
    scene = (rgb, 0.3 * rgb, 0.1 * rgb)
    raw = sensor.frames(scene, n=1, rng=2)[0]
    write_frame(folder / "scene.png", raw)
    rrd = tmp_path / "live.rrd"
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=None, separate="shen13", rerun=rrd, view_scale=1.0,
                              calibration=cal)
    assert summary["separations"] == 1 and summary["separation_errors"] == [] and summary["error"] is None
    logged = _rrd_images(rrd, "/layers/diffuse", "Image")[0]
    assert logged.shape == (8, 8, 3)
    fixed = apply_calibration(read_frame(folder / "scene.png"), cal)
    want = separate(np.clip(demosaic(fixed, method="bilinear", resolution="cell"), 0.0, 1.0), method="shen13")
    np.testing.assert_array_equal(logged, unit_u8(want.diffuse))
    unfixed = separate(np.clip(demosaic(raw, method="bilinear", resolution="cell"), 0.0, 1.0), method="shen13")
    assert not np.array_equal(logged, unit_u8(unfixed.diffuse))


def test_live_separation_holds_the_first_frames_illuminant(tmp_path):
    # a method that estimates the illuminant gets the first frame's estimate on every later frame
    # (a static scene's light does not change; its per-frame estimate flips with the noise)
    folder, _ = _replay_folder(tmp_path, "synthetic_bunny5", n=3)
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=None, separate="polarized-residual")
    held = summary["separation_illuminant_held"]
    assert summary["separations"] >= 1 and summary["separation_errors"] == []
    assert len(held) == 3 and all(v > 0 for v in held) and abs(np.mean(held) - 1) < 1e-6
    assert summary["separation_options"] == {}                  # what the user gave, not what was held
    with ReplayCamera(folder) as cam:
        each = run_capture(cam, out=None, separate="polarized-residual", hold_illuminant=False)
    assert each["separation_illuminant_held"] is None and each["separations"] >= 1
    with ReplayCamera(folder) as cam:
        given = run_capture(cam, out=None, separate="polarized-residual",
                            separate_options={"illuminant": [1.0, 1.0, 1.0]})
    assert given["separation_illuminant_held"] is None
    with ReplayCamera(folder) as cam:                             # a method with no illuminant option
        other = run_capture(cam, out=None, separate="shen13")
    assert other["separation_illuminant_held"] is None and other["separation_errors"] == []


def test_the_held_illuminant_reaches_every_later_separation(tmp_path):
    from polcam import separation
    from polcam.acquisition.live import LiveProcessor

    calls: list[dict] = []

    @separation.register("test-illuminant-probe", kind="stack", options=("illuminant",))
    def probe(stack, **options):
        calls.append(dict(options))
        return stack.mean(axis=0), {"illuminant": [1.2, 1.0, 0.8]}

    try:
        folder, frames = _replay_folder(tmp_path, "synthetic_bunny5", n=3)
        live = LiveProcessor(frames[0].layout, separate="test-illuminant-probe", workers=1)
        for i, f in enumerate(frames):
            live.offer(i, f)
            deadline = time.monotonic() + 30
            while live.separations < i + 1 and time.monotonic() < deadline:
                time.sleep(0.01)
        live.close()
    finally:
        separation.unregister("test-illuminant-probe")
    assert live.separation_errors == [] and len(calls) == 3
    assert calls[0] == {} and calls[1] == calls[2] == {"illuminant": [1.2, 1.0, 0.8]}
    assert live.held_illuminant == [1.2, 1.0, 0.8]
