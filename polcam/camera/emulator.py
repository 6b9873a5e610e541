"""Aravis' GigE Vision camera emulator, started and stopped from Python.

``arv-fake-gv-camera-0.8`` (Debian package ``aravis-tools``) answers GVCP and
sends GVSP over a network interface exactly like a GigE Vision camera; on
loopback (``-i 127.0.0.1``) it is the way to exercise the real GigE code path
(packet size, packet loss, missing packets) without hardware.  Aravis sees it
as ``Aravis-Fake-<SERIAL>``.

Every emulator on a machine binds UDP port 3956 (GVCP) on 127.0.0.1, and
one that finds the port taken still answers discovery while the commands go
to whoever holds the port.  So :func:`gige_emulator`

- holds an exclusive lock (``/tmp/polcam-gige-emulator.lock``) for as long as
  its emulator runs;
- waits for the port to be free before it starts one, and checks that its own
  emulator is the one bound to it (Linux ``/proc``) before it yields;
- always stops the process when the block ends, and starts it with a parent
  death signal (``setpriv --pdeathsig KILL``, util-linux) so that a killed
  Python process does not leave an emulator holding the port.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
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

#: The GVCP port and its address as ``/proc/net/udp`` writes it (127.0.0.1 and
#: 0.0.0.0, both of which hold 127.0.0.1:3956).
GVCP_PORT = 3956
_GVCP_LOCAL = {f"0100007F:{GVCP_PORT:04X}", f"00000000:{GVCP_PORT:04X}"}


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


def _gvcp_socket_inodes() -> set[int] | None:
    """Inodes of the UDP sockets bound to 127.0.0.1:3956, or None without ``/proc``."""
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    inodes = set()
    for line in lines:
        fields = line.split()
        if len(fields) > 9 and fields[1] in _GVCP_LOCAL:
            inodes.add(int(fields[9]))
    return inodes


def _socket_inodes_of(pid: int) -> set[int]:
    inodes = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    try:
        fds = list(fd_dir.iterdir())
    except OSError:
        return inodes
    for fd in fds:
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(int(target[8:-1]))
    return inodes


def _holders(inodes: set[int]) -> str:
    """'pid 123 (arv-fake-gv-camera-0.8 -i ...)' for the processes we may look into."""
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit() and _socket_inodes_of(int(proc.name)) & inodes:
            try:
                cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
            except OSError:
                cmd = "?"
            found.append(f"pid {proc.name} ({cmd})")
    return ", ".join(found) or "a process this user cannot see"


def _wait_for_free_port(timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while (inodes := _gvcp_socket_inodes()):
        if time.monotonic() > deadline:
            raise CameraUnavailableError(
                f"UDP 127.0.0.1:{GVCP_PORT} (GVCP) is held by {_holders(inodes)}; an emulator started "
                "now would answer discovery while that process took its commands: stop it first"
            )
        time.sleep(0.2)


def _check_owner(proc: subprocess.Popen[bytes]) -> None:
    inodes = _gvcp_socket_inodes()
    if inodes is None:  # no /proc: nothing to check
        return
    if not inodes & _socket_inodes_of(proc.pid):
        raise CameraUnavailableError(
            f"{EMULATOR} (pid {proc.pid}) did not bind UDP 127.0.0.1:{GVCP_PORT}; "
            f"it is held by {_holders(inodes) if inodes else 'nobody'}"
        )


@functools.lru_cache(maxsize=1)
def _pdeathsig_prefix() -> tuple[str, ...]:
    """``setpriv --pdeathsig KILL --`` where setpriv has that option (util-linux 2.33 on), else nothing."""
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return ()
    prefix = (setpriv, "--pdeathsig", "KILL", "--")
    try:
        ok = subprocess.run([*prefix, "true"], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    return prefix if ok else ()


def _command(exe: str, serial: str, lost_per_thousand: int) -> list[str]:
    cmd = [exe, "-i", "127.0.0.1", "-s", serial]
    if lost_per_thousand:
        cmd += ["-r", str(int(lost_per_thousand))]
    return [*_pdeathsig_prefix(), *cmd]  # killed with us, even by SIGKILL (kept across exec)


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
        No emulator executable, Aravis missing, the emulator did not show up,
        or another process holds UDP 127.0.0.1:3956 (named in the message).
    """
    exe = shutil.which(EMULATOR)
    if exe is None:
        raise CameraUnavailableError(
            f"{EMULATOR} is not installed (Debian package aravis-tools; see drivers/install.sh)"
        )
    load_aravis()
    serial = serial or f"PC{random.randrange(10**6):06d}"
    device_id = f"Aravis-Fake-{serial}"
    cmd = _command(exe, serial, lost_per_thousand)
    with _exclusive(lock_timeout):
        _wait_for_free_port(start_timeout)
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
            _check_owner(proc)
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
