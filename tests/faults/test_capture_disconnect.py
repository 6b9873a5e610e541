"""A camera that goes away mid-capture: the GigE Vision emulator on 127.0.0.1 killed with SIGKILL."""

from __future__ import annotations

import time

from polcam.camera.emulator import gige_emulator
from tests.faults._capture_helpers import (
    FAKE,
    capture_cmd,
    check_accounted,
    finish,
    needs_emulator,
    start,
    summary_from,
    wait_for_frames,
)


@needs_emulator
def test_disconnect_ends_the_capture_promptly_with_its_summary(tmp_path):
    out = tmp_path / "out"
    with gige_emulator() as dev:
        proc = start(capture_cmd(dev, out, *FAKE, "--frame-rate", "20", "--duration", "60", "--packet-size", "1400",
                                 "--quiet"))
        try:
            wait_for_frames(proc, out, 10)
        except BaseException:
            finish(proc, timeout=1)
            raise
        dev.process.kill()  # the cable comes out
        t_kill = time.monotonic()
        stdout, stderr = finish(proc, timeout=60)
        after = time.monotonic() - t_kill
    text = stdout + stderr
    assert proc.returncode == 4, text
    assert "Traceback" not in stderr and "GError" not in stderr
    # Aravis' GVCP requests give up after 2.5 s; seen here: 5-6 s from the kill to the exit
    assert after < 12, after
    assert f"camera {dev} disconnected: " in stderr
    summary = summary_from(out, text)
    assert summary["stop_reason"].startswith("camera disconnected: ")
    assert summary["camera"]["id"] == dev and summary["camera"]["model"]  # read before it went away
    assert summary["frames_saved"] >= 10 and summary["frames_incomplete"] == 0
    check_accounted(out, summary)
