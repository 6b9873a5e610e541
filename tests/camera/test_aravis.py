"""Device discovery through the real Aravis stack (its in-process Fake camera)."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from polcam.camera import aravis_available, list_devices
from polcam.errors import CameraUnavailableError

needs_aravis = pytest.mark.skipif(not aravis_available(), reason="Aravis 0.8 is not installed")


@needs_aravis
def test_fake_camera_is_listed():
    devices = list_devices(fake=True)
    fake = [d for d in devices if d.id == "Fake_1"]
    assert fake, devices
    assert fake[0].vendor == "Aravis" and fake[0].protocol == "Fake"


def test_missing_aravis_gives_install_instructions():
    # a fresh interpreter with Aravis disabled: polcam imports, the camera command explains itself
    code = (
        "import polcam, polcam.polarimetry\n"
        "from polcam.cli import main\n"
        "raise SystemExit(main(['devices']))\n"
    )
    env = {"POLCAM_NO_ARAVIS": "1", "PATH": "/usr/bin:/bin"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 3
    assert "drivers/install.sh" in proc.stderr and "Aravis" in proc.stderr


def test_load_error_type(monkeypatch):
    import polcam.camera.aravis_lib as arv

    monkeypatch.setattr(arv, "_ARAVIS", None)
    monkeypatch.setenv("POLCAM_NO_ARAVIS", "1")
    with pytest.raises(CameraUnavailableError, match="install"):
        arv.load_aravis()


# ---------------------------------------------------------------------------
# The Aravis backend against Aravis' own fakes
# ---------------------------------------------------------------------------

import numpy as np  # noqa: E402

from polcam.camera import AravisCamera, CameraNotFoundError, CameraSettingError  # noqa: E402
from polcam.camera.emulator import emulator_available, gige_emulator  # noqa: E402
from polcam.errors import LayoutError, PixelFormatError  # noqa: E402
from polcam.mosaic import parse_layout  # noqa: E402

needs_emulator = pytest.mark.skipif(
    not (aravis_available() and emulator_available()), reason="Aravis GigE emulator not installed"
)


def _ramp(frame) -> np.ndarray:
    """What Aravis' fake cameras send in Mono8: (x + y + frame id) mod 255 (gain 0, 10 ms exposure)."""
    h, w = frame.shape
    x0, y0 = frame.metadata["roi"][:2]
    y, x = np.mgrid[y0:y0 + h, x0:x0 + w]
    return ((x + y + frame.metadata["frame_id"]) % 255).astype(np.uint8)


@needs_aravis
@pytest.mark.camera
def test_fake_camera_frames_are_the_fake_pattern():
    with AravisCamera("Fake_1", n_buffers=4) as cam:
        s = cam.configure(pixel_format="Mono8", layout="imx250mzr", roi=(0, 0, 64, 32), frame_rate=100)
        assert s["roi"] == [0, 0, 64, 32] and s["layout"] == "imx250mzr"
        cam.start()
        frames = []
        for f in cam.frames(timeout=1.0, idle_timeout=20):
            frames.append(f)
            if len(frames) == 5:
                break
        cam.stop()
        st = cam.stats()
    ids = [f.metadata["frame_id"] for f in frames]
    assert len(set(ids)) == 5
    for f in frames:
        assert f.mosaic.dtype == np.uint8 and f.shape == (32, 64) and f.bit_depth == 8
        np.testing.assert_array_equal(f.mosaic, _ramp(f))
        assert f.payload == f.mosaic.tobytes()  # Mono8: the buffer bytes are the image
        assert f.layout == parse_layout("imx250mzr")
        md = f.metadata
        assert md["pixel_format"] == "Mono8" and md["vendor"] == "Aravis" and md["camera_id"] == "Fake_1"
        assert md["timestamp_ns"] > 0 and md["exposure_us"] == 10000.0
    assert st.good >= 5 and st.incomplete == 0
    assert st.stream["n_completed_buffers"] >= 5


@needs_aravis
@pytest.mark.camera
def test_fake_camera_mono16_frames():
    with AravisCamera("Fake_1", n_buffers=4) as cam:
        cam.configure(pixel_format="Mono16", layout="imx250mzr", roi=(0, 0, 48, 28))
        cam.start()
        f = cam.read(timeout=20.0)
        cam.stop()
    assert f is not None and f.mosaic.dtype == np.uint16 and f.shape == (28, 48) and f.bit_depth == 16
    np.testing.assert_array_equal(f.mosaic, np.frombuffer(f.payload, "<u2").reshape(28, 48))
    assert len(f.payload) == 28 * 48 * 2


@needs_aravis
@pytest.mark.camera
def test_colour_roi_is_aligned_to_whole_colour_cells():
    with AravisCamera("Fake_1", n_buffers=4) as cam:
        # offsets and sizes are rounded down to the colour period (4) of imx250myr
        s = cam.configure(pixel_format="BayerRG8", layout="imx250myr", roi=(7, 6, 51, 30))
        assert s["roi"] == [4, 4, 48, 28]
        assert cam.layout == parse_layout("imx250myr")
        cam.start()
        f = cam.read(timeout=20.0)
        cam.stop()
    assert f is not None and f.shape == (28, 48) and f.layout == parse_layout("imx250myr")
    assert f.metadata["roi"] == [4, 4, 48, 28]


@needs_aravis
@pytest.mark.camera
def test_mono_roi_offsets_are_aligned_to_whole_cells():
    with AravisCamera("Fake_1") as cam:
        cam.configure(pixel_format="Mono8", layout="imx250mzr", roi=(2, 0, 64, 32))
        assert cam.layout == parse_layout("imx250mzr")  # an even offset keeps the phase
        # odd offsets are rounded down to whole 2x2 cells, so the phase never changes
        s = cam.configure(roi=(3, 1, 65, 33))
        assert s["roi"] == [2, 0, 64, 32] and s["layout"] == "imx250mzr"


@needs_aravis
@pytest.mark.camera
def test_unsupported_pixel_format_lists_the_supported_ones():
    with AravisCamera("Fake_1") as cam:
        with pytest.raises(PixelFormatError) as exc:
            cam.configure(pixel_format="PolarizeMono12p")
        msg = str(exc.value)
        assert "does not offer" in msg and "Mono8" in msg and "Mono16" in msg and "BayerRG8" in msg
        # offered by the camera but not a raw mosaic polcam reads
        with pytest.raises(PixelFormatError, match="does not read.*supported.*Mono8"):
            cam.configure(pixel_format="RGB8")
        assert "RGB8" not in cam.readable_formats()


@needs_aravis
@pytest.mark.camera
def test_plain_format_needs_a_layout():
    with AravisCamera("Fake_1") as cam:
        with pytest.raises(LayoutError, match="--layout"):
            cam.configure(pixel_format="Mono8")


@needs_aravis
@pytest.mark.camera
def test_no_camera_with_that_id():
    with pytest.raises(CameraNotFoundError, match="polcam devices"):
        AravisCamera("NoSuchCamera-4242").open()


@needs_aravis
@pytest.mark.camera
def test_bad_settings_name_the_setting():
    with AravisCamera("Fake_1") as cam:
        with pytest.raises(CameraSettingError, match="trigger 'Line7'.*Line0"):
            cam.configure(pixel_format="Mono8", layout="imx250mzr", trigger="Line7")
        with pytest.raises(CameraSettingError, match="ReverseX"):
            cam.configure(reverse_x=True)
        with pytest.raises(CameraSettingError, match="ROI"):
            cam.configure(roi=(0, 0, 4096, 4096))


@needs_aravis
@pytest.mark.camera
def test_software_trigger_fires_single_frames():
    with AravisCamera("Fake_1", n_buffers=4) as cam:
        cam.configure(pixel_format="Mono8", layout="imx250mzr", roi=(0, 0, 32, 32), trigger="software")
        cam.start()
        got = []
        for _ in range(2):
            cam.trigger()
            f = cam.read(timeout=20.0)
            assert f is not None
            got.append(f.metadata["frame_id"])
        cam.stop()
        cam.configure(trigger="free")
    assert got[1] > got[0]


@needs_emulator
@pytest.mark.camera
def test_gige_emulator_with_packet_loss_counts_incomplete_frames():
    # 512x512 Mono8 in ~190 packets of 1400 bytes; 3 lost per thousand: about 4 in 10 frames incomplete
    with gige_emulator(lost_per_thousand=3) as dev:
        with AravisCamera(dev, packet_size=1400, n_buffers=8) as cam:
            assert cam.info["protocol"] == "GigEVision" and cam.info["packet_size"] == 1400
            cam.configure(pixel_format="Mono8", layout="imx250mzr", roi=(0, 0, 512, 512), frame_rate=50)
            cam.start()
            good = []
            deadline = time.monotonic() + 60
            while len(good) < 20 and time.monotonic() < deadline:
                f = cam.read(timeout=1.0)
                if f is not None:
                    good.append(f)
                if len(good) >= 5 and cam.stats().incomplete >= 3:
                    break
            cam.stop()
            st = cam.stats()
    assert good, "no complete frame from the emulator"
    for f in good:  # every frame handed on is complete and exact
        np.testing.assert_array_equal(f.mosaic, _ramp(f))
    assert st.incomplete >= 1
    # every incomplete frame is counted under its buffer's status: mostly missing packets, and a
    # timeout when the lost packet was the frame's leader or trailer (the buffer never closes)
    assert st.by_status.get("missing-packets", 0) >= 1
    errors = {k: v for k, v in st.by_status.items() if k not in ("success", "aborted", "cleared")}
    assert sum(errors.values()) == st.incomplete, st.by_status
    assert st.stream["n_missing_packets"] > 0
    assert st.good >= len(good)
