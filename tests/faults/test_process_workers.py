"""polcam process, items 4 and 5: a dead worker or a signal to the process group never aborts the
batch without its summary; workers die with their parent and write nothing after it died."""

from __future__ import annotations

import os
import signal
import time

from tests.faults._process_helpers import (
    SLOW,
    alive,
    busy_worker,
    check_accounted,
    check_consistent,
    descendants,
    finish,
    frame_mtimes,
    kill_group,
    make_frames,
    reap_group,
    start,
    summary,
    wait_for,
)


def test_dead_worker_costs_its_frame_then_ctrl_c_stops_after_the_frames_in_progress(tmp_path):
    """kill -9 of a busy worker (what the out-of-memory killer does): its frame is reported failed
    with the reason and the batch goes on; then one SIGINT to the process group (a terminal's
    Ctrl-C) lets the frames in progress finish, starts no new one, writes the summary, exits 130.
    Twelve frames: on a fast machine a worker finishes one of six before the signal arrives, and all
    six could have started by then."""
    frames = make_frames(tmp_path / "raw", 12)
    out = tmp_path / "out"
    p = start(tmp_path / "raw", out, "--workers", "2", *SLOW)
    try:
        victim = busy_worker(p.pid)
        os.kill(victim, signal.SIGKILL)
        assert p.stdout is not None
        while True:                                   # the batch goes on: a frame finishes after it
            line = p.stdout.readline()
            assert line, "the run ended early"
            if '"status": "done"' in line and '"event": "frame"' in line:
                break
        busy_worker(p.pid)
        kill_group(p, signal.SIGINT)
        code, _, err = finish(p)
    finally:
        reap_group(p)
    assert code == 130, err
    assert "stopping after the frames in progress" in err
    assert "Traceback" not in err
    s = summary(out)
    by = check_accounted(out, frames, s)
    assert len(by["failed"]) == 1 and by["cancelled"] == set(), by
    assert "killed (SIGKILL" in s["failed"][0]["error"]
    assert by["not_started"], by                      # Ctrl-C came before the last frames
    assert len(by["done"]) >= 2 and s["interrupted"] is True
    assert sorted(check_consistent(out)) == sorted(n[:-4] for n in by["done"])


def test_sigterm_to_the_group_cancels_cleanly_exit_143(tmp_path):
    """SIGTERM to the process group (a job scheduler): the frames in progress are cancelled, none
    is started, the summary says so, exit 143, and no process of the run is left."""
    frames = make_frames(tmp_path / "raw", 6)
    out = tmp_path / "out"
    p = start(tmp_path / "raw", out, "--workers", "2", *SLOW)
    try:
        busy_worker(p.pid)
        family = descendants(p.pid)
        kill_group(p, signal.SIGTERM)
        t0 = time.monotonic()
        code, _, err = finish(p)
        took = time.monotonic() - t0
    finally:
        reap_group(p)
    assert code == 143, err
    assert took < 10
    assert "Traceback" not in err
    s = summary(out)
    by = check_accounted(out, frames, s)
    assert by["cancelled"] and s["interrupted"] is True, by
    assert all("SIGTERM" in c["reason"] for c in s["cancelled"])
    check_consistent(out)
    wait_for(lambda: not any(alive(q) for q in family), 5, "the run's processes to end")


def test_second_ctrl_c_stops_now(tmp_path):
    """Two SIGINTs to the process group: the second cancels the frames in progress at once."""
    frames = make_frames(tmp_path / "raw", 6)
    out = tmp_path / "out"
    p = start(tmp_path / "raw", out, "--workers", "2", "--method", "tensor", "--option", "max_iter=3000",
              "--option", "tol=0")  # long frames
    try:
        busy_worker(p.pid)
        kill_group(p, signal.SIGINT)
        time.sleep(0.3)
        kill_group(p, signal.SIGINT)
        t0 = time.monotonic()
        code, _, err = finish(p)
        took = time.monotonic() - t0
    finally:
        reap_group(p)
    assert code == 130, err
    assert took < 10 and "Traceback" not in err
    s = summary(out)
    by = check_accounted(out, frames, s)
    assert by["cancelled"] and not by["done"], by
    check_consistent(out)


def test_kill_9_of_process_takes_its_workers_along(tmp_path):
    """kill -9 of ``polcam process`` alone (not its group): the fork server, the workers and the
    resource tracker end within seconds, and no file is written in the output after the kill."""
    make_frames(tmp_path / "raw", 6)
    out = tmp_path / "out"
    p = start(tmp_path / "raw", out, "--workers", "2", *SLOW)
    try:
        busy_worker(p.pid)
        family = descendants(p.pid)
        assert len(family) >= 3                       # fork server, resource tracker, workers
        os.kill(p.pid, signal.SIGKILL)
        t_kill = time.time()
        p.communicate(timeout=30)
        wait_for(lambda: not any(alive(q) for q in family), 5, "the workers to die with their parent")
        time.sleep(1.0)                               # a surviving worker would finish a frame by now
        late = {f: t for f, t in frame_mtimes(out).items() if t > t_kill + 0.05}
        assert not late, late
    finally:
        reap_group(p)
    check_consistent(out)
