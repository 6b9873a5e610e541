"""The live rates of ``polcam capture``: maps (frames whose S0, DoLP and AoLP were computed and
logged) and layers (frames separated) per second, in the summary, printed, and plotted live at
``/stats/maps_fps`` and ``/stats/layers_fps``."""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from polcam.acquisition import run_capture
from polcam.camera import ReplayCamera
from polcam.commands.capture import main
from polcam.frame import Frame
from polcam.io import read_frame, write_frame

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "raw"


def _replay_folder(tmp_path: Path, n: int = 3) -> Path:
    """n distinct small colour frames (IMX250MYR, 256 x 256) with sidecars."""
    src = read_frame(FIXTURES / "synthetic_bunny5.png")
    folder = tmp_path / "replay"
    folder.mkdir()
    for i in range(n):
        write_frame(folder / f"f_{i:02d}.png",
                    Frame(mosaic=np.roll(src.mosaic, 4 * i, axis=1), layout=src.layout, bit_depth=src.bit_depth,
                          black_level=src.black_level, white_level=src.white_level))
    return folder


def _scalars(path: Path) -> dict[str, dict[int, list[float]]]:
    """{entity: {frame: [values logged at that frame]}} of the scalar entities of a .rrd."""
    import rerun.chunk as ch

    out: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    for chunk in ch.RrdReader(path).stream():
        if chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        cols = [c for c in rb.schema.names if c.startswith("Scalars:")]
        if not cols or "frame" not in rb.schema.names:
            continue
        for frame, value in zip(rb.column("frame").to_pylist(), rb.column(cols[0]).to_pylist(), strict=True):
            if value is not None:
                out[str(chunk.entity_path)][frame] += [float(v) for v in value]
    return out


def _frames(path: Path, entity: str) -> set[int]:
    import rerun.chunk as ch

    frames: set[int] = set()
    for chunk in ch.RrdReader(path).stream():
        if not chunk.is_static and str(chunk.entity_path) == entity:
            frames |= set(chunk.to_record_batch().column("frame").to_pylist())
    return frames


@pytest.mark.parametrize("method", ["imin", "default"])
def test_summary_and_recording_hold_the_two_live_rates(tmp_path, method):
    folder = _replay_folder(tmp_path)
    rrd = tmp_path / "live.rrd"
    out = tmp_path / "out"
    with ReplayCamera(folder, frame_rate=30.0, loop=True) as cam:
        summary = run_capture(cam, out=out, frames=24, separate=method, rerun=rrd)
    assert summary["separation"] == ("imin" if method == "imin" else "wen21")  # the colour default
    assert summary["separation_errors"] == [] and summary["error"] is None
    maps, layers = summary["maps_frames"], summary["layers_frames"]
    assert maps == summary["frames_processed"] and layers == summary["separations"]
    assert 1 <= layers <= maps <= summary["frames_received"] == 24
    if method == "imin":  # the imin layers come with every frame's maps
        assert layers == maps
    elapsed = summary["duration_s"]
    assert summary["maps_fps"] == pytest.approx(maps / elapsed, rel=1e-12)
    assert summary["layers_fps"] == pytest.approx(layers / elapsed, rel=1e-12)
    on_disk = json.loads((out / "summary.json").read_text())
    for key in ("maps_frames", "maps_fps", "layers_frames", "layers_fps"):
        assert on_disk[key] == summary[key], key

    scalars = _scalars(rrd)
    shown = _frames(rrd, "/polarization/s0")
    separated = _frames(rrd, "/layers/diffuse")
    assert len(shown) == maps and len(separated) == layers
    # one maps rate per frame whose maps were logged; the layers rate with it, and with each separation
    assert set(scalars["/stats/maps_fps"]) == shown
    assert set(scalars["/stats/layers_fps"]) == shown | separated
    assert set(scalars["/stats/fps"]) == shown  # the camera's rate stays where it was
    assert all(v > 0 and np.isfinite(v) for vs in scalars["/stats/maps_fps"].values() for v in vs)
    # the layers rate logged with a frame's layers counts them
    assert all(max(scalars["/stats/layers_fps"][i]) > 0 for i in separated)
    if method == "imin":
        # imin: no frame has a layers rate of zero once its own layers are logged
        assert all(vs[-1] > 0 for vs in scalars["/stats/layers_fps"].values())


def test_capture_prints_the_live_rates(tmp_path, capsys):
    folder = _replay_folder(tmp_path, n=2)
    assert main(["--device", f"replay:{folder}", "--frames", "2", "--no-save", "--separate", "imin",
                 "--quiet"]) == 0
    printed = capsys.readouterr().out
    line = next(ln for ln in printed.splitlines() if ln.startswith("live rates:"))
    assert "maps " in line and "layers " in line and "imin" in line
    n_maps = int(line.split("maps ")[1].split("(")[1].split(" frames")[0])
    n_layers = int(line.split("layers ")[1].split("(")[1].split(" frames")[0])
    assert 1 <= n_layers == n_maps <= 2


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread niceness is Linux's")
def test_the_separation_thread_runs_below_the_maps():
    from polcam.acquisition.live import SEPARATION_NICENESS, LiveProcessor
    from polcam.mosaic import parse_layout

    live = LiveProcessor(parse_layout("imx250myr"), separate="wen21", workers=1)
    try:
        sep = live._sep_thread
        assert sep is not None
        base = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        want = min(19, base + SEPARATION_NICENESS)
        for _ in range(200):  # the thread lowers its own priority as it starts
            if os.getpriority(os.PRIO_PROCESS, sep.native_id) == want:
                break
            time.sleep(0.01)
        assert os.getpriority(os.PRIO_PROCESS, sep.native_id) == want
        (maps_thread,) = live._threads
        assert os.getpriority(os.PRIO_PROCESS, maps_thread.native_id) == base
        assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base
    finally:
        live.close()


@pytest.mark.parametrize("method", [None, "wen21"])
def test_maps_leave_room_for_the_layers(method):
    """With a separation thread the maps start at most MAPS_FPS_WITH_LAYERS frames a second, however
    fast frames come; without one they take every frame they can."""
    from polcam.acquisition.live import MAPS_FPS_WITH_LAYERS, LiveProcessor

    src = read_frame(FIXTURES / "synthetic_bunny5.png")
    small = Frame(mosaic=np.ascontiguousarray(src.mosaic[:64, :64]), layout=src.layout, bit_depth=src.bit_depth,
                  black_level=src.black_level, white_level=src.white_level)
    live = LiveProcessor(src.layout, separate=method, workers=2)
    try:
        t0 = time.monotonic()
        i = 0
        while time.monotonic() - t0 < 1.5:  # frames offered far faster than 25 a second
            live.offer(i, small)
            i += 1
            time.sleep(0.002)
    finally:
        live.close(finish=False)
    elapsed = time.monotonic() - t0
    if method is None:
        assert live.processed > MAPS_FPS_WITH_LAYERS * elapsed + 2  # 64 x 64 maps: well over 25 fps
    else:
        assert 3 <= live.processed <= MAPS_FPS_WITH_LAYERS * elapsed + 2
        assert live.separations >= 1
