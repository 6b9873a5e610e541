"""The GigE Vision emulator helper: the process is gone after the block, whatever happens in it."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from polcam.camera import aravis_available
from polcam.camera.emulator import EMULATOR, _pdeathsig_prefix, emulator_available, gige_emulator
from polcam.errors import CameraUnavailableError

pytestmark = [
    pytest.mark.camera,
    pytest.mark.skipif(not (aravis_available() and emulator_available()),
                       reason="Aravis GigE emulator not installed"),
]


def _running_with(serial: str) -> list[int]:
    pids = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmd = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if serial.encode() in cmd:
            pids.append(int(proc.name))
    return pids


def test_emulator_is_seen_and_stopped_even_after_an_error():
    serial = "PCT" + str(Path("/proc/self").resolve().name)[-6:]
    with pytest.raises(RuntimeError, match="boom"):
        with gige_emulator(serial=serial) as dev:
            assert dev == f"Aravis-Fake-{serial}"
            assert _running_with(serial)
            raise RuntimeError("boom")
    assert _running_with(serial) == []


def _wait_gone(serial: str, timeout: float = 10.0) -> list[int]:
    deadline = time.monotonic() + timeout
    while (pids := _running_with(serial)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return pids


def test_a_foreign_listener_on_the_gvcp_port_is_named_not_talked_to():
    # an emulator started outside the helper holds 127.0.0.1:3956: a second one would be
    # discovered under its own serial while the first took its commands (and streamed its frames)
    serial = "PCS" + str(os.getpid())[-6:]
    stray = subprocess.Popen([shutil.which(EMULATOR), "-i", "127.0.0.1", "-s", serial],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 10
        while not _running_with(serial) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # let it bind
        with pytest.raises(CameraUnavailableError, match=rf"127\.0\.0\.1:3956 .*held by pid {stray.pid} "):
            with gige_emulator(start_timeout=1.0):
                pass
    finally:
        stray.kill()
        stray.wait(timeout=5)
    with gige_emulator() as dev:  # free again: the helper's own emulator owns the port
        assert dev.process.poll() is None


@pytest.mark.skipif(not _pdeathsig_prefix(), reason="setpriv --pdeathsig (util-linux 2.33 or later) not available")
def test_the_emulator_dies_with_a_killed_parent():
    serial = "PCK" + str(os.getpid())[-6:]
    code = ("import sys, time\n"
            "from polcam.camera.emulator import gige_emulator\n"
            f"with gige_emulator(serial={serial!r}):\n"
            "    print('up', flush=True)\n"
            "    time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              cwd=Path(__file__).resolve().parents[2])
    try:
        assert parent.stdout.readline().strip() == "up"
        assert _running_with(serial)
        parent.send_signal(signal.SIGKILL)  # no finally, no atexit
        parent.wait(timeout=10)
        assert _wait_gone(serial) == []
    finally:
        parent.kill()
        parent.wait(timeout=10)
        parent.stdout.close()
        for pid in _running_with(serial):  # an orphan would hold the port for every later test
            os.kill(pid, signal.SIGKILL)
