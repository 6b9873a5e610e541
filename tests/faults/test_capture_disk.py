"""Capture on a full disk, a read-only folder, a new folder on a read-only disk; progress lines.

A real tmpfs where the machine allows mounting, else the same errors injected at the OS boundary
of the capture process (tests/faults/_capture_helpers.py).  The camera is Aravis' Fake camera.
"""

from __future__ import annotations

import time

import pytest

from tests.faults._capture_helpers import (
    FAKE,
    capture_cmd,
    check_accounted,
    env_with_tmpdir,
    finish,
    inject_env,
    needs_aravis,
    small_disk,
    start,
    summary_from,
    visible_frames,
)

PROGRESS = " fps, saved "  # in every progress line


@needs_aravis
def test_full_disk_stops_the_capture_at_once_and_says_where_and_why(tmp_path):
    disk = tmp_path / "disk"
    with small_disk(disk, 2048) as mounted:  # room for about 30 frames of 64 KiB
        out = disk / "out"
        env = env_with_tmpdir(tmp_path, None if mounted else inject_env(tmp_path, disk, "ENOSPC", files=40))
        t0 = time.monotonic()
        proc = start(capture_cmd("Fake_1", out, *FAKE, "--frame-rate", "50", "--duration", "30", "--quiet"),
                     env=env)
        stdout, stderr = finish(proc, timeout=60)
        elapsed = time.monotonic() - t0
        text = stdout + stderr
        assert proc.returncode == 5, text
        assert "Traceback" not in stderr and PROGRESS not in stderr
        # within a second of the failure: the whole run, start-up included, is far below --duration
        assert elapsed < 15, elapsed
        assert f"writing frames to {out} failed: No space left on device (ENOSPC)" in stderr
        summary = summary_from(out, text)
        assert summary["stop_reason"] == f"write failed: {out}: No space left on device (ENOSPC)"
        assert summary["duration_s"] < 10
        assert summary["frames_save_failed"] >= 1 and summary["write_error"]["folder"] == str(out)
        assert summary["write_error_to_stop_s"] < 1.0  # acquisition stopped within a second of the failure
        assert summary["frames_saved"] >= 5
        check_accounted(out, summary)
        if summary["summary_file"] != str(out / "summary.json"):  # the full disk refused it too
            assert summary["summary_file"].startswith(str(tmp_path / "tmpdir"))
            assert f"summary written to {summary['summary_file']}" in stderr


@pytest.mark.slow
@needs_aravis
def test_continue_live_keeps_the_live_view_going_without_saving(tmp_path):
    disk = tmp_path / "disk"
    rrd = tmp_path / "live.rrd"
    with small_disk(disk, 1024) as mounted:  # about 15 frames
        out = disk / "out"
        env = env_with_tmpdir(tmp_path, None if mounted else inject_env(tmp_path, disk, "ENOSPC", files=20))
        proc = start(capture_cmd("Fake_1", out, *FAKE, "--frame-rate", "30", "--duration", "2", "--quiet",
                                 "--on-write-error", "continue-live", "--separate", "imin", "--rerun", str(rrd)),
                     env=env)
        stdout, stderr = finish(proc, timeout=90)
        text = stdout + stderr
        assert proc.returncode == 5, text
        assert "Traceback" not in stderr and PROGRESS not in stderr  # --quiet: errors only
        assert "frames are no longer saved, the live view goes on" in stderr and str(out) in stderr
        summary = summary_from(out, text)
        assert summary["stop_reason"] == "duration"  # it ran to its end
        assert summary["frames_unsaved"] >= 10  # received after the failure, shown, not saved
        assert summary["frames_processed"] > summary["frames_saved"]
        check_accounted(out, summary)
    assert rrd.stat().st_size > 0


@needs_aravis
def test_read_only_folder_is_refused_before_the_first_frame(tmp_path):
    disk = tmp_path / "disk"
    with small_disk(disk, 256, readonly=True, make=("out",)) as mounted:
        out = disk / "out"
        env = None if mounted else inject_env(tmp_path, disk, "EROFS")
        proc = start(capture_cmd("Fake_1", out, *FAKE, "--frames", "5"), env=env)
        stdout, stderr = finish(proc)
        assert proc.returncode == 2, stdout + stderr
        assert "Traceback" not in stderr
        assert f"{out}: cannot write frames into the output folder: Read-only file system (EROFS)" in stderr
        assert "capturing from" not in stdout  # refused before the camera started
        assert visible_frames(out) == [] and not list(out.glob("*.json"))


@needs_aravis
def test_new_folder_on_a_read_only_disk_is_refused_with_its_reason(tmp_path):
    disk = tmp_path / "disk"
    with small_disk(disk, 256, readonly=True) as mounted:
        out = disk / "new" / "out"
        env = None if mounted else inject_env(tmp_path, disk, "EROFS")
        proc = start(capture_cmd("Fake_1", out, *FAKE, "--frames", "5"), env=env)
        stdout, stderr = finish(proc)
        assert proc.returncode == 2, stdout + stderr
        assert "Traceback" not in stderr
        assert f"{out}: cannot create the output folder: Read-only file system (EROFS)" in stderr
        assert not out.exists()


@needs_aravis
def test_progress_prints_about_once_a_second(tmp_path):
    # (--quiet silencing them: the other tests of this file run quiet and assert no such line)
    out = tmp_path / "out"
    proc = start(capture_cmd("Fake_1", out, *FAKE, "--frame-rate", "20", "--duration", "2.6"))
    stdout, stderr = finish(proc)
    assert proc.returncode == 0, stderr
    lines = [line for line in stderr.splitlines() if PROGRESS in line]
    assert len(lines) == 2, stderr  # at 1 and 2 s
    check_accounted(out, summary_from(out, stdout))
