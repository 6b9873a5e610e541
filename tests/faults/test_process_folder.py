"""polcam process, items 6 and 7: one run per output folder (a lock naming its holder; a dead
holder's lock taken over), and an output folder that cannot take the outputs refused before any work."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import pytest

from tests.faults._process_helpers import (
    SLOW,
    check_accounted,
    check_consistent,
    enospc_site,
    finish,
    kill_group,
    make_frames,
    reap_group,
    run,
    small_disk,
    start,
    wait_for,
)


def test_second_run_on_the_same_folder_is_refused_and_a_dead_runs_lock_taken_over(tmp_path):
    frames = make_frames(tmp_path / "raw", 4)
    out = tmp_path / "out"
    a = start(tmp_path / "raw", out, "--workers", "1", *SLOW)
    try:
        wait_for(lambda: (out / ".polcam-process.lock").is_file() and (out / ".polcam-summary.reserve").is_file(),
                 60, "the first run to start")
        lock = json.loads((out / ".polcam-process.lock").read_text())
        assert lock["pid"] == a.pid and lock["host"] and lock["started"]
        temps_before = sorted(p.name for p in out.rglob(".*"))
        code, _, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")
        assert code == 2, err
        assert f"PID {a.pid}" in err and "in use by another polcam process run" in err
        assert len(err.strip().splitlines()) == 1
        assert not (out / "summary.json").exists()
        assert set(temps_before) <= {p.name for p in out.rglob(".*")} | {".polcam-summary.reserve"}
        kill_group(a, signal.SIGKILL)                 # the holder dies without releasing the lock
        finish(a)
    finally:
        reap_group(a)
    assert json.loads((out / ".polcam-process.lock").read_text())["pid"] == a.pid   # left behind
    code, _, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")
    assert code == 0, err
    assert f"took over the lock left by PID {a.pid}" in err
    by = check_accounted(out, frames)
    assert by["done"] | by["skipped"] == {p.name for p in frames}
    assert len(check_consistent(out)) == 4
    assert not (out / ".polcam-process.lock").exists()


def test_read_only_output_is_refused_before_any_work(tmp_path):
    make_frames(tmp_path / "raw", 3, size=64)
    with small_disk(tmp_path, "1m") as (disk, site):
        out = disk / "out"
        if site is None:
            out.mkdir()
            subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True, capture_output=True)
            want = "Read-only file system"
        else:                                         # no mount here: a full disk injected instead
            site = enospc_site(tmp_path, disk, 0)
            want = "No space left on device"
        t0 = time.monotonic()
        code, _, err = run(tmp_path / "raw", out, "--workers", "1", *SLOW, extra_path=site)
        took = time.monotonic() - t0
        assert code == 2, err
        assert f"{out}: cannot " in err and want in err
        assert len(err.strip().splitlines()) == 1
        assert took < 20                              # three frames would take longer than that
        assert not [p for p in out.iterdir()] if out.exists() else True


def test_no_room_for_one_frame_is_refused_before_any_work(tmp_path):
    make_frames(tmp_path / "raw", 2)
    with small_disk(tmp_path, "256k") as (disk, site):
        if site is not None:
            pytest.skip("needs a real small file system (mount refused here): free space is read from it")
        out = disk / "out"
        code, _, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin", "--resolution", "full")
        assert code == 2, err
        assert f"{out}: no room for one frame" in err and "MB are free" in err
        assert [p.name for p in out.iterdir()] == []
        # at cell resolution a frame fits: the same folder takes the run
        code, _, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")
        assert code == 0, err
        assert len(check_consistent(out)) == 2
