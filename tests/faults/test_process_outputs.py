"""polcam process, item 1: a frame's products and its meta.json never disagree (full disk, kill -9
mid-frame, a file changed afterwards), and a rerun never calls a half-written frame up to date."""

from __future__ import annotations

import random
import shutil
import signal
import time
from pathlib import Path

import pytest

from tests.faults._process_helpers import (
    SLOW,
    check_accounted,
    check_consistent,
    finish,
    kill_group,
    make_frames,
    reap_group,
    run,
    slow_writes_site,
    small_disk,
    start,
    summary,
    wait_for,
)


def test_full_disk_mid_frame_then_rerun(tmp_path):
    """A 1 MiB file system holds six cell-resolution frames; redoing them at full resolution fills it
    part-way through a frame.  Every frame is then whole or has no meta.json, the summary names the
    failures, and a cell rerun calls no frame up to date (each one was replaced or left unfinished)."""
    frames = make_frames(tmp_path / "raw", 6)
    with small_disk(tmp_path, "1m") as (disk, site):
        out = disk / "out"
        code, _, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin", extra_path=site)
        assert code == 0, err
        assert len(check_consistent(out)) == 6

        code, ev, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin", "--resolution", "full",
                            extra_path=site)
        assert code == 1, err
        s = summary(out)                                  # written although the disk is full
        by = check_accounted(out, frames, s)
        assert by["failed"] and by["done"], by            # the disk filled part-way through
        assert all("No space left on device" in f["error"] for f in s["failed"])
        assert {e["name"] for e in ev if e.get("status") == "failed"} == {Path(n).stem for n in by["failed"]}
        finished = check_consistent(out)
        assert sorted(finished) == sorted(Path(n).stem for n in by["done"])   # failed frames: no meta.json

        code, ev, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin", extra_path=site)
        s = summary(out)
        check_accounted(out, frames, s)
        assert s["skipped"] == 0, s                       # nothing from the full-size run passes for cell
        check_consistent(out)


def test_kill_9_while_a_frame_is_written(tmp_path):
    """kill -9 of the run's process group while a frame's files are being replaced (each file
    creation slowed to 0.3 s at the OS boundary): the frame is left without meta.json, every other
    folder matches its meta.json, and a rerun redoes exactly the frames not finished as asked."""
    frames = make_frames(tmp_path / "raw", 4)
    out = tmp_path / "out"
    code, _, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")
    assert code == 0, err
    site = slow_writes_site(tmp_path, out, 0.3)
    t0 = time.time()
    p = start(tmp_path / "raw", out, "--workers", "1", "--method", "imin", "--resolution", "full",
              extra_path=site)
    try:
        # the first product of a frame has been replaced: the frame is half-written
        wait_for(lambda: any(f.stat().st_mtime > t0 for f in out.glob("*/diffuse.exr")), 60, "a product written")
        kill_group(p, signal.SIGKILL)
        code, ev, _ = finish(p)
    finally:
        reap_group(p)
    assert code == -signal.SIGKILL
    half = [f.parent.name for f in out.glob("*/diffuse.exr") if f.stat().st_mtime > t0
            and not (f.parent / "meta.json").exists()]
    assert half, "the kill landed while a frame was being written"
    full_done = {e["name"] for e in ev if e.get("event") == "frame" and e["status"] == "done"}
    check_consistent(out)

    code, ev, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")
    assert code == 0, err
    s = summary(out)
    by = check_accounted(out, frames, s)
    assert not (by["skipped"] & {f"{n}.npy" for n in full_done | set(half)})
    assert len(check_consistent(out)) == 4


def test_a_changed_output_file_is_not_up_to_date(tmp_path):
    """A product file replaced after the run (another frame's file) fails the size/SHA-256 check:
    that frame is redone, the others stay up to date."""
    frames = make_frames(tmp_path / "raw", 3)
    out = tmp_path / "out"
    assert run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")[0] == 0
    shutil.copy(out / "f01" / "dolp.exr", out / "f00" / "dolp.exr")
    code, ev, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")
    assert code == 0, err
    by = check_accounted(out, frames)
    assert by["done"] == {"f00.npy"} and by["skipped"] == {"f01.npy", "f02.npy"}
    assert len(check_consistent(out)) == 3


@pytest.mark.slow
def test_kill_9_at_random_moments_soak(tmp_path):
    """Eight kill -9s of the process group at random moments of runs that alternate between cell and
    full resolution: after each, every folder matches its meta.json; a last run finishes them all."""
    frames = make_frames(tmp_path / "raw", 6)
    out = tmp_path / "out"
    rng = random.Random(29)
    for i in range(8):
        res = ("cell", "full")[i % 2]
        p = start(tmp_path / "raw", out, "--workers", "2", "--resolution", res, *SLOW)
        try:
            time.sleep(rng.uniform(1.0, 6.0))
            kill_group(p, signal.SIGKILL)
            finish(p)
        finally:
            reap_group(p)
        check_consistent(out)
    code, _, err = run(tmp_path / "raw", out, "--workers", "2", *SLOW, child=True)
    assert code == 0, err
    check_accounted(out, frames)
    assert len(check_consistent(out)) == 6
