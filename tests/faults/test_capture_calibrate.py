"""Live calibration (`polcam calibrate STAGE --device`) under the faults capture shares with it:
a --keep folder that fills up or cannot be written, and a camera that disconnects."""

from __future__ import annotations

import sys
import time

import pytest

from polcam.camera.emulator import gige_emulator
from tests.faults._capture_helpers import (
    FAKE,
    REPO,
    finish,
    inject_env,
    needs_aravis,
    needs_emulator,
    small_disk,
    start,
)

pytestmark = pytest.mark.slow  # the default run covers these faults through capture (tests/faults/test_capture_disk.py)


def _calibrate(device: str, out, keep, n: int, *extra: str) -> list[str]:
    return [sys.executable, "-m", "polcam", "calibrate", "dark", "--device", device, "--frames", str(n),
            "-o", str(out), "--keep", str(keep), *FAKE, "--exposure", "100", *extra]


def _kept_pairs_whole(keep) -> int:
    frames = {p.stem for p in keep.glob("dark_*.raw")}
    sidecars = {p.stem for p in keep.glob("dark_*.json")}
    assert frames == sidecars, (sorted(frames ^ sidecars))
    assert not list(keep.glob(".*")), "temporary files left"
    for stem in frames:
        assert (keep / f"{stem}.raw").stat().st_size == 256 * 256
    return len(frames)


@needs_aravis
def test_full_keep_folder_ends_the_calibration_saying_where_and_why(tmp_path):
    disk = tmp_path / "disk"
    out = tmp_path / "dark.npz"
    with small_disk(disk, 1024) as mounted:  # about 15 kept frames
        keep = disk / "keep"
        env = None if mounted else inject_env(tmp_path, disk, "ENOSPC", files=30)
        proc = start(_calibrate("Fake_1", out, keep, 200, "--frame-rate", "50"), env=env, cwd=REPO)
        stdout, stderr = finish(proc)
        assert proc.returncode == 2, stdout + stderr
        assert "Traceback" not in stderr
        assert f"{keep}: cannot keep calibration frame dark_" in stderr
        assert "No space left on device (ENOSPC)" in stderr and "no calibration written" in stderr
        n = _kept_pairs_whole(keep)
        assert 1 <= n < 200 and f"the {n} frames kept so far are in {keep}" in stderr
    assert not out.exists()


@needs_aravis
def test_read_only_keep_folder_is_refused_before_the_camera_opens(tmp_path):
    disk = tmp_path / "disk"
    out = tmp_path / "dark.npz"
    with small_disk(disk, 256, readonly=True) as mounted:
        keep = disk / "keep"
        env = None if mounted else inject_env(tmp_path, disk, "EROFS")
        proc = start(_calibrate("Fake_1", out, keep, 4), env=env, cwd=REPO)
        stdout, stderr = finish(proc)
    assert proc.returncode == 2, stdout + stderr
    assert "Traceback" not in stderr
    assert f"{keep}: --keep: cannot create the output folder: Read-only file system (EROFS)" in stderr
    assert not out.exists()


@needs_emulator
def test_disconnect_during_live_calibration_says_so_and_keeps_what_it_took(tmp_path):
    out = tmp_path / "dark.npz"
    keep = tmp_path / "keep"
    with gige_emulator() as dev:
        proc = start(_calibrate(dev, out, keep, 100000, "--frame-rate", "20", "--packet-size", "1400"), cwd=REPO)
        try:
            wait_for_frames_in(proc, keep, 5)
        except BaseException:
            finish(proc, timeout=1)
            raise
        dev.process.kill()
        t_kill = time.monotonic()
        stdout, stderr = finish(proc)
        after = time.monotonic() - t_kill
    assert proc.returncode == 2, stdout + stderr
    assert "Traceback" not in stderr and after < 12, after
    assert f"camera {dev} disconnected (" in stderr and "no calibration written" in stderr
    n = _kept_pairs_whole(keep)
    assert f"the {n} frames kept so far are in {keep}" in stderr
    assert not out.exists()


def wait_for_frames_in(proc, keep, n: int, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if keep.is_dir() and len(list(keep.glob("dark_*.raw"))) >= n:
            return
        if proc.poll() is not None:
            raise AssertionError(f"calibrate exited early: {proc.communicate()}")
        time.sleep(0.05)
    raise AssertionError(f"no {n} kept frames within {timeout} s")
