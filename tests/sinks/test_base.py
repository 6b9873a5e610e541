"""polcam.sinks.base: a sink defined here, in the test, passed through capture and process.

A new sink is one class with ``log`` and ``close``: the toy sinks below are handed to
``run_capture`` (every frame received), ``Capture(live_sink=...)`` (the live view) and
``process.run`` (every finished frame folder), and must see each frame once, at its index, and be
closed once, also when the run ends in an error.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from polcam.acquisition import Capture, CaptureOptions, run_capture
from polcam.camera import ReplayCamera
from polcam.errors import FrameWriteError
from polcam.frame import Frame
from polcam.io import read_frame, write_frame
from polcam.sinks.base import FanOut, Record, Sink, SinkBase


class Counting(SinkBase):
    """A toy sink: records the indices and records it is given, and how often it was closed."""

    def __init__(self, *, fail_at: int | None = None) -> None:
        self.indices: list[int] = []
        self.records: list[Record] = []
        self.closed = 0
        self.fail_at = fail_at
        self._lock = threading.Lock()

    def log(self, index: int, record: Record) -> None:
        if self.closed:
            raise AssertionError(f"frame {index} logged after close")
        if self.fail_at is not None and len(self.indices) == self.fail_at:
            raise RuntimeError(f"toy sink refuses frame {index}")
        with self._lock:
            self.indices.append(index)
            self.records.append(record)

    def close(self) -> None:
        self.closed += 1


def _replay_folder(tmp_path: Path, fixtures_dir: Path, n: int) -> tuple[Path, list[np.ndarray]]:
    """n distinct mono frames (the fixture rolled by whole layout periods), with sidecars."""
    src = read_frame(fixtures_dir / "raw" / "fruits_crop.png")
    folder = tmp_path / "replay"
    folder.mkdir()
    mosaics = []
    for i in range(n):
        mosaic = np.roll(src.mosaic, 4 * i, axis=1)
        write_frame(folder / f"f_{i:02d}.png", Frame(mosaic=mosaic, layout=src.layout, bit_depth=src.bit_depth,
                                                     black_level=src.black_level, white_level=src.white_level))
        mosaics.append(mosaic)
    return folder, mosaics


def test_a_toy_sink_is_a_sink():
    assert isinstance(Counting(), Sink)
    assert not isinstance(object(), Sink)


def test_capture_logs_every_frame_once_to_a_sink_and_closes_it_once(tmp_path, fixtures_dir):
    folder, mosaics = _replay_folder(tmp_path, fixtures_dir, n=5)
    toy = Counting()
    with ReplayCamera(folder) as cam:
        summary = run_capture(cam, out=tmp_path / "out", separate=None, sinks=[toy])
    assert summary["frames_received"] == summary["frames_saved"] == 5
    assert toy.indices == [0, 1, 2, 3, 4]
    assert toy.closed == 1
    for record, mosaic in zip(toy.records, mosaics):  # the frames as the camera sent them, in order
        assert record.frame is not None and record.products == {}
        np.testing.assert_array_equal(record.frame.mosaic, mosaic)
    # the saver (the capture's own file sink) wrote the same frames
    saved = sorted((tmp_path / "out").glob("frame_*.raw"))
    assert [p.stem for p in saved] == [f"frame_{i:06d}" for i in range(5)]


def test_appended_capture_logs_the_continued_numbering(tmp_path, fixtures_dir):
    folder, _ = _replay_folder(tmp_path, fixtures_dir, n=2)
    with ReplayCamera(folder) as cam:
        run_capture(cam, out=tmp_path / "out", separate=None)
    toy = Counting()
    with ReplayCamera(folder) as cam:
        run_capture(cam, out=tmp_path / "out", separate=None, append=True, sinks=[toy])
    assert toy.indices == [2, 3] and toy.closed == 1


def test_a_sink_that_fails_ends_the_capture_and_every_sink_is_closed_once(tmp_path, fixtures_dir):
    folder, _ = _replay_folder(tmp_path, fixtures_dir, n=6)
    failing, other = Counting(fail_at=2), Counting()
    out = tmp_path / "out"
    with ReplayCamera(folder) as cam:
        with pytest.raises(RuntimeError, match="toy sink refuses frame 2"):
            run_capture(cam, out=out, separate="imin", sinks=[failing, other])
        assert not cam.running  # acquisition stopped on the way out
    assert failing.indices == [0, 1] and failing.closed == 1
    assert other.indices == [0, 1] and other.closed == 1
    # the saver came before the toy sinks: frames 0, 1, 2 were handed to it and written
    assert sorted(p.name for p in out.glob("frame_*.raw")) == [f"frame_{i:06d}.raw" for i in range(3)]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporaries left


def test_a_capture_refused_before_the_camera_starts_still_closes_its_sinks(tmp_path, fixtures_dir):
    folder, _ = _replay_folder(tmp_path, fixtures_dir, n=2)
    toy = Counting()
    with ReplayCamera(folder) as cam:
        with pytest.raises(FrameWriteError, match="on_write_error 'later'"):
            run_capture(cam, out=tmp_path / "out", separate=None, on_write_error="later", sinks=[toy])
        assert not cam.running
    assert toy.indices == [] and toy.closed == 1


def test_a_live_sink_gets_the_maps_layers_and_statistics(tmp_path, fixtures_dir):
    folder, mosaics = _replay_folder(tmp_path, fixtures_dir, n=4)
    live = Counting()
    with ReplayCamera(folder) as cam:
        capture = Capture(cam, CaptureOptions(out=None, separate="imin"), live_sink=live)
        summary = capture.run()
    assert live.closed == 1
    maps = [(i, r) for i, r in zip(live.indices, live.records) if "s0" in r.products]
    stats = [r for r in live.records if r.stats]
    assert len(maps) == summary["frames_processed"] >= 1
    assert len(stats) == summary["frames_processed"]  # one statistics record per processed frame
    for index, record in maps:  # the raw frame as sent, its maps and the imin layers
        assert record.frame is not None
        np.testing.assert_array_equal(record.frame.mosaic, mosaics[index])
        assert {"s0", "dolp", "aolp", "diffuse", "specular"} <= set(record.products)
        h, w = mosaics[index].shape
        assert record.products["dolp"].shape == (h // 2, w // 2)


def test_process_logs_each_finished_frame_folder_once(tmp_path, fixtures_dir):
    from polcam import process as proc

    raw = tmp_path / "raw"
    raw.mkdir()
    src = read_frame(fixtures_dir / "raw" / "fruits_crop.png")
    for i in range(3):
        write_frame(raw / f"m{i}.npy", Frame(mosaic=np.roll(src.mosaic, 4 * i, axis=0)[:64, :64].copy(),
                                             layout=src.layout, bit_depth=src.bit_depth,
                                             black_level=src.black_level, white_level=src.white_level))
    (raw / "m1_bad.npy").write_bytes(b"not a frame")  # fails: never logged
    jobs, problems = proc.plan([raw], tmp_path / "out")
    assert not problems
    opts = proc.ProcessOptions(method="imin")
    toy = Counting()
    results = proc.run(jobs, opts, sinks=[toy])
    assert sorted(r["status"] for r in results) == ["done", "done", "done", "failed"]
    done = [i for i, job in enumerate(jobs) if job.name != "m1_bad"]
    assert sorted(toy.indices) == done and toy.closed == 1
    for index, record in zip(toy.indices, toy.records):
        assert record.name == jobs[index].name and record.folder == Path(jobs[index].target)
        assert (record.folder / "meta.json").is_file()  # logged once the frame was finished
    # a rerun skips the finished frames: they are logged again (up to date), the failure is not
    again = Counting()
    results = proc.run(jobs, opts, sinks=[again])
    assert sorted(r["status"] for r in results) == ["failed", "skipped", "skipped", "skipped"]
    assert sorted(again.indices) == done and again.closed == 1


def test_process_closes_its_sinks_when_a_sink_fails(tmp_path, fixtures_dir):
    from polcam import process as proc

    raw = tmp_path / "raw"
    raw.mkdir()
    src = read_frame(fixtures_dir / "raw" / "fruits_crop.png")
    for i in range(2):
        write_frame(raw / f"m{i}.npy", Frame(mosaic=src.mosaic[:32, :32 + 4 * i].copy(), layout=src.layout,
                                             bit_depth=src.bit_depth))
    jobs, _ = proc.plan([raw], tmp_path / "out")
    failing, other = Counting(fail_at=0), Counting()
    with pytest.raises(RuntimeError, match="toy sink refuses frame 0"):
        proc.run(jobs, proc.ProcessOptions(method="imin"), sinks=[other, failing])
    assert other.indices == [0] and failing.indices == []
    assert other.closed == failing.closed == 1


def test_fan_out_logs_in_order_and_closes_every_sink_despite_errors():
    order: list[str] = []

    class Named(SinkBase):
        def __init__(self, name: str, fail_close: bool = False) -> None:
            self.name, self.fail_close, self.closed = name, fail_close, 0

        def log(self, index: int, record: Record) -> None:
            order.append(f"{self.name}{index}")

        def close(self) -> None:
            self.closed += 1
            if self.fail_close:
                raise OSError(f"{self.name} cannot flush")

    a, b, c = Named("a", fail_close=True), Named("b", fail_close=True), Named("c")
    fan = FanOut([a, None, b, c])
    assert len(fan) == 3
    fan.log(0, Record())
    fan.log(1, Record())
    assert order == ["a0", "b0", "c0", "a1", "b1", "c1"]
    with pytest.raises(OSError, match="a cannot flush"):  # the first error, after all were closed
        with fan:
            pass
    assert a.closed == b.closed == c.closed == 1
