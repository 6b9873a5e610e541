"""The camera protocol: frame-id gap counting, the frame queue, backend dispatch, the settings."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from polcam.camera.base import (
    Camera,
    CameraNotFoundError,
    CameraSettings,
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


def test_configure_takes_a_settings_value_or_keywords_and_refuses_unknown_names():
    cam = _Source("test")
    base = CameraSettings(exposure_us=100.0, roi=(0, 0, 8, 8))
    # the backend's _configure gets one CameraSettings (here: echoed back as its set fields)
    assert cam.configure(base) == {"exposure_us": 100.0, "roi": (0, 0, 8, 8)}
    assert cam.configure(base, exposure_us=5.0, trigger="free") == {"exposure_us": 5.0, "roi": (0, 0, 8, 8),
                                                                    "trigger": "free"}
    assert base.exposure_us == 100.0  # the value given is not changed
    assert cam.configure(gain_db=2.0) == {"gain_db": 2.0}
    assert cam.configure() == {}
    with pytest.raises(TypeError, match=r"unknown camera settings \['exposure'\].*exposure_us"):
        cam.configure(exposure=5.0)


def test_settings_and_keywords_configure_a_real_backend_alike(tmp_path):
    from polcam.camera.replay import ReplayCamera
    from polcam.frame import Frame
    from polcam.io import write_frame
    from polcam.mosaic import parse_layout

    mosaic = np.arange(16 * 24, dtype=np.uint16).reshape(16, 24)
    write_frame(tmp_path / "f.npy", Frame(mosaic=mosaic, layout=parse_layout("imx250myr"), bit_depth=12))
    results = []
    for how in ("settings", "keywords"):
        with ReplayCamera(tmp_path) as cam:
            roi, trigger = (6, 4, 13, 9), "software"
            s = (cam.configure(CameraSettings(roi=roi, trigger=trigger, exposure_us=10.0)) if how == "settings"
                 else cam.configure(roi=roi, trigger=trigger, exposure_us=10.0))
            cam.start()
            cam.trigger()
            frame = cam.read(timeout=2.0)
            cam.stop()
        results.append((s, frame.mosaic))
    (s1, m1), (s2, m2) = results
    assert s1 == s2 and s1["roi"] == [4, 4, 12, 8] and s1["ignored"] == ["exposure_us"]
    np.testing.assert_array_equal(m1, mosaic[4:12, 4:16])
    np.testing.assert_array_equal(m2, m1)
