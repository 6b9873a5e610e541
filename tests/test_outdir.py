"""polcam.outdir: the output folder's lock, the up-front write/room check, the summary reserve."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest

from polcam.errors import FrameWriteError
from polcam.outdir import LOCK_NAME, OutputLock, OutputLocked, SummaryReserve, _proc_start, check_output


def test_lock_refuses_a_second_holder_and_is_released(tmp_path):
    with OutputLock(tmp_path) as lock:
        assert lock.taken_over is None
        info = json.loads((tmp_path / LOCK_NAME).read_text())
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname()
        with pytest.raises(OutputLocked, match=f"in use by another polcam process run: PID {os.getpid()} on"):
            OutputLock(tmp_path).acquire()
    assert not (tmp_path / LOCK_NAME).exists()
    OutputLock(tmp_path).acquire().release()


def test_lock_of_a_dead_process_is_taken_over_and_of_a_live_one_refused(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    (tmp_path / LOCK_NAME).write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "started": "x"}))
    with OutputLock(tmp_path) as lock:
        assert lock.taken_over["pid"] == pid
    # a live holder whose flock is not visible (a file system without flock): its PID decides
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / LOCK_NAME).write_text(json.dumps({"pid": live.pid, "host": socket.gethostname(),
                                                      "proc_start": _proc_start(live.pid), "started": "y"}))
        with pytest.raises(OutputLocked, match=f"PID {live.pid} on {socket.gethostname()}, started y"):
            OutputLock(tmp_path).acquire()
    finally:
        live.kill()
        live.wait()


def test_check_output_names_the_folder_and_reason(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(FrameWriteError, match=f"{blocker}: cannot create the output folder: .*EEXIST"):
        check_output(blocker)
    with pytest.raises(FrameWriteError, match=f"{tmp_path / 'new'}: no room for one frame: .* MB are free"):
        check_output(tmp_path / "new", frame_bytes=1 << 62)
    assert [p.name for p in (tmp_path / "new").iterdir()] == []          # the probe is removed


def test_summary_reserve_holds_room_until_released(tmp_path):
    r = SummaryReserve(tmp_path, frames=10)
    assert (tmp_path / ".polcam-summary.reserve").stat().st_size == 65536 + 10 * 1024
    r.release()
    r.release()
    assert not (tmp_path / ".polcam-summary.reserve").exists()
