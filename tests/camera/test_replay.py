"""The file-backed replay camera (``replay:DIR``)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from polcam.camera.base import CameraNotFoundError, CameraSettingError
from polcam.camera.replay import ReplayCamera
from polcam.errors import PixelFormatError
from polcam.frame import Frame
from polcam.io import read_frame, write_frame
from polcam.mosaic import parse_layout


def _folder(tmp_path, n=4, *, ext=".npy", shape=(16, 24), layout="imx250myr", bit_depth=12, **meta):
    rng = np.random.default_rng(7)
    folder = tmp_path / "in"
    folder.mkdir()
    mosaics = []
    for i in range(n):
        m = rng.integers(0, 2**bit_depth, shape).astype(np.uint16 if bit_depth > 8 else np.uint8)
        write_frame(folder / f"f{i:02d}{ext}", Frame(m, layout=layout, bit_depth=bit_depth,
                                                     metadata={"frame_id": 1000 + i, **meta}))
        mosaics.append(m)
    return folder, mosaics


def test_plays_every_file_in_order_with_metadata(tmp_path):
    folder, mosaics = _folder(tmp_path, exposure_us=1500.0, camera_id="LUCID-123")
    with ReplayCamera(folder) as cam:
        assert cam.layout == parse_layout("imx250myr")
        cam.start()
        frames = list(cam.frames(timeout=1.0))
        cam.stop()
        st = cam.stats()
    assert len(frames) == len(mosaics) == st.good
    assert st.dropped == 0 and st.incomplete == 0
    for i, (f, m) in enumerate(zip(frames, mosaics)):
        np.testing.assert_array_equal(f.mosaic, m)
        assert f.layout == parse_layout("imx250myr") and f.bit_depth == 12
        md = f.metadata
        assert md["frame_id"] == i and md["source_frame_id"] == 1000 + i
        assert md["camera_id"] == f"replay:{folder}" and md["source_camera_id"] == "LUCID-123"
        assert md["exposure_us"] == 1500.0 and md["source"].endswith(f"f{i:02d}.npy")
    stamps = [f.metadata["timestamp_ns"] for f in frames]
    assert stamps == sorted(stamps)


def test_raw_dumps_carry_their_bytes(tmp_path):
    folder, mosaics = _folder(tmp_path, n=2, ext=".raw", pixel_format="Mono12p")
    with ReplayCamera(folder) as cam:
        cam.start()
        frames = list(cam.frames(timeout=1.0))
    for f, src in zip(frames, sorted(folder.glob("*.raw"))):
        assert f.payload == src.read_bytes()
        assert f.metadata["pixel_format"] == "Mono12p"




def _triggered(cam):
    cam.trigger()
    frame = cam.read(timeout=5.0)
    assert frame is not None
    return frame


def test_a_loop_plays_the_first_pass_again_from_memory(tmp_path):
    # once read, a looping replay does not decode the files again: a file changed on disk after
    # the first pass is still played as it was then, with its bytes, and the frames are read-only
    folder, mosaics = _folder(tmp_path, n=2, ext=".raw", pixel_format="Mono12p")
    files = sorted(folder.glob("*.raw"))
    original = [f.read_bytes() for f in files]
    with ReplayCamera(folder, loop=True) as cam:
        cam.configure(trigger="software")  # one file read per trigger: none read ahead
        cam.start()
        first = [_triggered(cam) for _ in range(2)]
        for f in files:
            f.write_bytes(bytes(len(original[0])))  # all zeros now
        later = [_triggered(cam) for _ in range(4)]
        cam.stop()
    for i, f in enumerate(first + later):
        np.testing.assert_array_equal(f.mosaic, mosaics[i % 2])
        assert f.payload == original[i % 2]
        assert not f.mosaic.flags.writeable
    assert [f.metadata["frame_id"] for f in first + later] == list(range(6))


def test_a_loop_over_the_memory_budget_reads_the_rest_again(tmp_path, monkeypatch):
    import polcam.camera.replay as replay

    folder, mosaics = _folder(tmp_path, n=3)
    monkeypatch.setattr(replay, "LOOP_CACHE_BYTES", mosaics[0].nbytes)  # room for the first file only
    with ReplayCamera(folder, loop=True) as cam:
        cam.configure(trigger="software")
        cam.start()
        first = [_triggered(cam) for _ in range(3)]
        for f in sorted(folder.glob("*.npy"))[1:]:
            np.save(f, np.zeros_like(mosaics[0]))
        later = [_triggered(cam) for _ in range(3)]
        cam.stop()
    for f, m in zip(first, mosaics):
        np.testing.assert_array_equal(f.mosaic, m)
    np.testing.assert_array_equal(later[0].mosaic, mosaics[0])  # kept
    assert not later[1].mosaic.any() and not later[2].mosaic.any()  # read again: the new contents
    assert later[1].mosaic.flags.writeable


def test_a_single_pass_keeps_nothing(tmp_path):
    folder, _ = _folder(tmp_path, n=2)
    with ReplayCamera(folder) as cam:
        cam.start()
        frames = list(cam.frames(timeout=1.0))
        assert cam._kept == {}
    assert all(f.mosaic.flags.writeable for f in frames)


def test_paced_replay_drops_frames_a_slow_consumer_misses(tmp_path):
    folder, _ = _folder(tmp_path, n=12)
    with ReplayCamera(folder, frame_rate=200.0, queue_frames=1) as cam:
        cam.start()
        received = 0
        while not cam.exhausted:
            if cam.read(timeout=0.05) is not None:
                received += 1
                time.sleep(0.03)  # slower than the camera
        st = cam.stats()
    # every frame is either received or counted as dropped
    assert received + st.dropped == st.good == 12
    assert st.queue_overflow == st.dropped


def test_roi_crops_and_shifts_the_layout(tmp_path):
    folder, mosaics = _folder(tmp_path, n=1, shape=(16, 24), roi=[100, 50, 24, 16])
    with ReplayCamera(folder) as cam:
        settings = cam.configure(roi=(6, 4, 13, 9))  # aligned down to whole colour cells: (4, 4, 12, 8)
        assert settings["roi"] == [4, 4, 12, 8]
        cam.start()
        (f,) = list(cam.frames(timeout=1.0))
    np.testing.assert_array_equal(f.mosaic, mosaics[0][4:12, 4:16])
    # an offset of 4 keeps the colour phase of imx250myr
    assert f.layout == parse_layout("imx250myr")
    assert f.metadata["roi"] == [104, 54, 12, 8]


def test_roi_under_mirroring_maps_back_to_the_sensor(tmp_path):
    folder, mosaics = _folder(tmp_path, n=1, shape=(16, 24), layout="imx250mzr",
                              roi=[10, 20, 24, 16], reverse_x=True)
    with ReplayCamera(folder) as cam:
        cam.configure(roi=(2, 0, 8, 16))
        cam.start()
        (f,) = list(cam.frames(timeout=1.0))
    np.testing.assert_array_equal(f.mosaic, mosaics[0][:, 2:10])
    # image columns 2..9 of a mirrored 24-wide ROI are sensor columns 10 + (24 - 10) .. 10 + 21
    assert f.metadata["roi"] == [10 + 24 - 2 - 8, 20, 8, 16]


def test_software_trigger_releases_one_frame_each(tmp_path):
    folder, _ = _folder(tmp_path, n=3)
    with ReplayCamera(folder) as cam:
        cam.configure(trigger="software")
        cam.start()
        assert cam.read(timeout=0.2) is None
        cam.trigger()
        first = cam.read(timeout=5.0)
        assert first is not None and first.metadata["frame_id"] == 0
        assert cam.read(timeout=0.2) is None


def test_layout_override_and_ignored_settings(tmp_path):
    folder, _ = _folder(tmp_path, n=1, layout="imx250mzr")
    with ReplayCamera(folder) as cam:
        s = cam.configure(layout="mono:0,45,135,90", exposure_us=10.0, gain_db=2.0)
        assert s["layout"] == "mono:0,45,135,90"
        assert set(s["ignored"]) == {"exposure_us", "gain_db"}
        cam.start()
        (f,) = list(cam.frames(timeout=1.0))
    assert f.layout == parse_layout("mono:0,45,135,90")


def test_unreadable_file_counts_as_incomplete(tmp_path):
    folder, _ = _folder(tmp_path, n=2)
    (folder / "f01.npy").write_bytes(b"\x93NUMPY garbage")
    with ReplayCamera(folder) as cam:
        cam.start()
        frames = list(cam.frames(timeout=1.0))
        st = cam.stats()
    assert len(frames) == 1 and st.incomplete == 1 and st.by_status["unreadable"] == 1


def test_errors(tmp_path):
    with pytest.raises(CameraNotFoundError, match="does not exist"):
        ReplayCamera(tmp_path / "nope").open()
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraNotFoundError, match="no raw frames"):
        ReplayCamera(tmp_path / "empty").open()
    folder, _ = _folder(tmp_path, n=1)
    with ReplayCamera(folder) as cam:
        with pytest.raises(PixelFormatError, match="Mono8"):
            cam.configure(pixel_format="Mono8")
        with pytest.raises(CameraSettingError, match="trigger"):
            cam.configure(trigger="Line0")
        with pytest.raises(CameraSettingError, match="does not fit"):
            cam.configure(roi=(0, 0, 400, 400))
    with pytest.raises(CameraSettingError, match="frame rate"):
        ReplayCamera(folder, frame_rate=0)


def test_read_frame_of_replayed_frame_round_trips(tmp_path):
    # the replayed Frame writes back to the same counts (what capture relies on)
    folder, mosaics = _folder(tmp_path, n=1)
    with ReplayCamera(folder) as cam:
        cam.start()
        (f,) = list(cam.frames(timeout=1.0))
    write_frame(tmp_path / "out.npy", f)
    np.testing.assert_array_equal(read_frame(tmp_path / "out.npy").mosaic, mosaics[0])
