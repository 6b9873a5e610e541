"""The GigE Vision emulator helper: the process is gone after the block, whatever happens in it."""

from __future__ import annotations

from pathlib import Path

import pytest

from polcam.camera import aravis_available
from polcam.camera.emulator import emulator_available, gige_emulator

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
