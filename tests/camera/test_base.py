"""The camera protocol: frame-id gap counting, the frame queue, backend dispatch."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from polcam.camera.base import (
    Camera,
    CameraNotFoundError,
    CapturedFrame,
    FrameIdTracker,
)
from polcam.camera.registry import open_camera


def test_frame_id_gaps_counted():
    t = FrameIdTracker()
    assert [t.see(i) for i in (10, 11, 12, 15, 16, 20)] == [0, 0, 0, 2, 0, 3]
    assert t.missing == 5


def test_frame_id_gige_wrap_skips_zero():
    # GigE Vision block ids: 65535 is followed by 1 (0 is never used)
    t = FrameIdTracker()
    assert [t.see(i) for i in (65534, 65535, 1, 2)] == [0, 0, 0, 0]
    assert t.see(5) == 2
    t2 = FrameIdTracker()
    t2.see(65533)
    assert t2.see(2) == 2 + 1  # 65534, 65535 and 1 are missing
    assert t2.missing == 3


def test_frame_id_reset_is_not_loss():
    t = FrameIdTracker()
    t.see(500)
    assert t.see(3) == 0  # acquisition restarted: counter reset
    assert t.see(4) == 0


class _Source(Camera):
    """A minimal backend: frames are pushed by the test through _deliver."""

    layout = None  # type: ignore[assignment]

    def open(self):
        self._opened = True
        return self

    def close(self):
        self._opened = False

    def _configure(self, settings):
        return settings.given()

    def _start(self):
        pass

    def _stop(self):
        self._finished.set()


def _frame(i: int) -> CapturedFrame:
    return CapturedFrame(mosaic=np.full((4, 4), i, dtype=np.uint8), metadata={"frame_id": i})


def test_full_queue_drops_and_counts_without_blocking():
    cam = _Source("test", queue_frames=3)
    with cam:
        cam.start()
        results = [cam._deliver(_frame(i)) for i in range(5)]
        assert results == [True, True, True, False, False]
        st = cam.stats()
        assert (st.good, st.dropped, st.queue_overflow) == (5, 2, 2)
        got = [int(cam.read(timeout=1.0).mosaic[0, 0]) for _ in range(3)]
        assert got == [0, 1, 2]  # first in, first out; the late ones were dropped
        assert cam.read(timeout=0.01) is None


def test_blocking_delivery_waits_for_room_and_gives_up_on_stop():
    cam = _Source("test", queue_frames=1)
    stop = threading.Event()
    with cam:
        cam.start()
        assert cam._deliver(_frame(0), block=True, stop=stop)
        stop.set()  # the queue is full and stop is set: the frame is dropped, counted
        assert not cam._deliver(_frame(1), block=True, stop=stop)
        assert cam.stats().dropped == 1


def test_frames_iterator_ends_when_source_is_exhausted():
    cam = _Source("test", queue_frames=4)
    with cam:
        cam.start()
        for i in range(3):
            cam._deliver(_frame(i))
        cam._finished.set()
        assert [f.metadata["frame_id"] for f in cam.frames(timeout=0.05)] == [0, 1, 2]


def test_frames_iterator_idle_timeout():
    cam = _Source("test")
    with cam:
        cam.start()
        with pytest.raises(TimeoutError, match="no frame"):
            next(cam.frames(timeout=0.02, idle_timeout=0.05))


def test_open_camera_dispatch(tmp_path):
    from polcam.camera.replay import ReplayCamera

    cam = open_camera(f"replay:{tmp_path}")
    assert isinstance(cam, ReplayCamera) and cam.folder == tmp_path
    with pytest.raises(CameraNotFoundError, match="polcam devices"):
        open_camera("  ")


class _Triggered(_Source):
    """Each software trigger delivers one frame (a camera in software-trigger mode)."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.fired = 0

    def trigger(self):
        self.fired += 1
        self._deliver(_frame(self.fired))


def test_poll_frames_yields_none_between_frames_and_ends_with_the_source():
    cam = _Source("test", queue_frames=4)
    with cam:
        cam.start()
        reads = cam.poll_frames(poll=0.01)
        assert next(reads) is None                   # an empty wait: the caller checks its stop conditions
        cam._deliver(_frame(7))
        assert next(reads).metadata["frame_id"] == 7
        cam._finished.set()
        assert list(reads) == []                     # exhausted: the loop ends


def test_poll_frames_fires_the_software_trigger_once_per_frame():
    cam = _Triggered("test", queue_frames=4)
    with cam:
        cam.start()
        reads = cam.poll_frames(poll=0.05, software_trigger=True)
        got = [next(reads).metadata["frame_id"] for _ in range(3)]
        assert got == [1, 2, 3] and cam.fired == 3


def test_poll_frames_idle_timeout_names_the_camera():
    from polcam.camera.base import FrameTimeout

    cam = _Source("cam-7")
    with cam:
        cam.start()
        with pytest.raises(FrameTimeout, match="camera cam-7: no frame for 0.05 s"):
            for _ in cam.poll_frames(poll=0.02, idle_timeout=0.05):
                pass
