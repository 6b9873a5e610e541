"""Aravis' GigE Vision camera emulator, started and stopped from Python.

``arv-fake-gv-camera-0.8`` (Debian package ``aravis-tools``) answers GVCP and
sends GVSP over a network interface exactly like a GigE Vision camera; on
loopback (``-i 127.0.0.1``) it is the way to exercise the real GigE code path
(packet size, packet loss, missing packets) without hardware.  Aravis sees it
as ``Aravis-Fake-<SERIAL>``.

Every emulator on a machine binds UDP port 3956 on 127.0.0.1, so two running
at once would answer each other's commands: :func:`gige_emulator` holds an
exclusive lock (``/tmp/polcam-gige-emulator.lock``) for as long as its
emulator runs, and always kills the process when the block ends.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from polcam.camera.aravis import list_devices, load_aravis
from polcam.errors import CameraUnavailableError

__all__ = ["EMULATOR", "EmulatorId", "emulator_available", "gige_emulator"]

#: The emulator's executable name (Aravis 0.8).
EMULATOR = "arv-fake-gv-camera-0.8"

_LOCK = Path(tempfile.gettempdir()) / "polcam-gige-emulator.lock"


def emulator_available() -> bool:
    """True when the emulator executable is on PATH."""
    return shutil.which(EMULATOR) is not None


class EmulatorId(str):
    """The Aravis device id of a running emulator (a ``str``), with its ``process``
    (:class:`subprocess.Popen`): a test kills it to pull the cable."""

    process: subprocess.Popen[bytes]


@contextlib.contextmanager
def _exclusive(timeout: float) -> Iterator[None]:
    fd = os.open(_LOCK, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise CameraUnavailableError(
                        f"another GigE emulator has held {_LOCK} for {timeout:g} s; try again later"
                    ) from None
                time.sleep(0.1)
        try:
            yield
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


@contextlib.contextmanager
def gige_emulator(*, serial: str | None = None, lost_per_thousand: int = 0,
                  start_timeout: float = 15.0, lock_timeout: float = 120.0) -> Iterator[EmulatorId]:
    """Run the GigE Vision emulator on 127.0.0.1 for the duration of a ``with`` block.

    Parameters
    ----------
    serial
        Serial number of the emulated camera (default: a random ``PC`` + 6 digits).
    lost_per_thousand
        GVSP packets the emulator drops per thousand (``-r``): ``3`` makes
        a good share of 512 x 512 frames incomplete.
    start_timeout
        Seconds to wait for Aravis to discover the emulator.
    lock_timeout
        Seconds to wait for another emulator (another test run) to finish.

    Yields
    ------
    EmulatorId
        The Aravis device id, ``Aravis-Fake-<serial>`` (a ``str``), with the
        emulator's ``process``.

    Raises
    ------
    CameraUnavailableError
        No emulator executable, Aravis missing, or the emulator did not show up.
    """
    exe = shutil.which(EMULATOR)
    if exe is None:
        raise CameraUnavailableError(
            f"{EMULATOR} is not installed (Debian package aravis-tools; see drivers/install.sh)"
        )
    load_aravis()
    serial = serial or f"PC{random.randrange(10**6):06d}"
    device_id = f"Aravis-Fake-{serial}"
    cmd = [exe, "-i", "127.0.0.1", "-s", serial]
    if lost_per_thousand:
        cmd += ["-r", str(int(lost_per_thousand))]
    with _exclusive(lock_timeout):
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            deadline = time.monotonic() + start_timeout
            while not any(d.id == device_id for d in list_devices()):
                if proc.poll() is not None:
                    raise CameraUnavailableError(f"{EMULATOR} exited at start (status {proc.returncode})")
                if time.monotonic() > deadline:
                    raise CameraUnavailableError(
                        f"{EMULATOR} did not appear as {device_id} within {start_timeout:g} s"
                    )
                time.sleep(0.2)
            dev = EmulatorId(device_id)
            dev.process = proc
            yield dev
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
