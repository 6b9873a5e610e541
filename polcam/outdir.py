"""The output folder of a batch run: its lock, the up-front write check, and ``summary.json``.

``polcam process`` holds :class:`OutputLock` on its output folder for the
whole run: a second run on the same folder would take the first one's
temporary files for a crash's leftovers and overwrite its summary.  The lock
is the file ``OUT/.polcam-process.lock``, held with ``flock`` (the kernel
releases it when the holder dies, however it dies) and holding the holder's
PID, host, start time and command line, which a refused run names.  A lock
file left by a process that is gone is taken over (and said so).

Before any frame is computed, :func:`check_output` makes sure the folder can
be written (a small file is written, synced and removed) and has room for one
frame's outputs, and reserves room for ``summary.json``
(:class:`SummaryReserve`), released just before the summary is written, so a
disk that fills during the run still gets its summary.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from polcam._jsonable import jsonable
from polcam._version import __version__
from polcam.errors import FrameWriteError, PolcamError
from polcam.io.atomic import atomic_write, os_reason, probe_folder

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: the PID in the lock file decides
    fcntl = None  # type: ignore[assignment]

__all__ = ["LOCK_NAME", "OutputLock", "OutputLocked", "SummaryReserve", "check_output", "summarize",
           "write_summary"]

LOCK_NAME = ".polcam-process.lock"
_RESERVE_NAME = ".polcam-summary.reserve"


class OutputLocked(PolcamError):
    """The output folder is in use by another run (its PID, host and start time in the message)."""


def _proc_start(pid: int) -> int | None:
    """Start time of process ``pid`` in clock ticks since boot (Linux), else None."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return int(fh.read().rsplit(b")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def _running(info: dict[str, Any]) -> bool:
    """The process a lock file names is still running on this host."""
    if info.get("host") != socket.gethostname() or not isinstance(info.get("pid"), int):
        return False
    pid = info["pid"]
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    start = _proc_start(pid)
    return start is None or info.get("proc_start") in (None, start)


def _describe(info: dict[str, Any]) -> str:
    if not info:
        return "a process whose lock file could not be read"
    return (f"PID {info.get('pid')} on {info.get('host')}, started {info.get('started')}"
            f" ({info.get('command', '?')})")


class OutputLock:
    """Exclusive use of an output folder by one run (context manager).

    Parameters
    ----------
    folder
        The output folder (must exist).

    Attributes
    ----------
    taken_over : dict or None
        What a stale lock file said (a run that died without releasing it), if there was one.
    """

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.taken_over: dict[str, Any] | None = None
        self._fd: int | None = None

    @staticmethod
    def _read(fd: int) -> dict[str, Any]:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            data = json.loads(os.read(fd, 65536).decode() or "{}")
        except (OSError, ValueError, UnicodeDecodeError):
            return {}
        return data if isinstance(data, dict) else {}

    def acquire(self) -> OutputLock:
        """Take the lock.

        Raises
        ------
        OutputLocked
            Another run holds it; the message names it.
        FrameWriteError
            The lock file cannot be created (the message names the folder and the reason).
        """
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise FrameWriteError(f"cannot create the lock file: {exc.strerror or exc}",
                                      path=self.path) from exc
            try:
                if fcntl is not None:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                info = self._read(fd)
                os.close(fd)
                raise OutputLocked(f"output folder in use by another polcam process run: {_describe(info)}; "
                                   "wait for it to finish, or stop it", path=self.folder) from None
            except OSError:  # no flock on this file system: the PID in the file decides
                pass
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if not same:  # released and removed between our open and flock: try again
                os.close(fd)
                continue
            prev = self._read(fd)
            if prev and prev.get("pid") != os.getpid() and _running(prev):
                os.close(fd)
                raise OutputLocked(f"output folder in use by another polcam process run: {_describe(prev)}; "
                                   "wait for it to finish, or stop it", path=self.folder)
            self.taken_over = prev or None
            info = {"pid": os.getpid(), "host": socket.gethostname(), "proc_start": _proc_start(os.getpid()),
                    "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "command": " ".join(sys.argv)[:300]}
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, json.dumps(info).encode())
            os.fsync(fd)
            self._fd = fd
            return self

    def release(self) -> None:
        """Remove the lock file and release the lock (idempotent)."""
        if self._fd is None:
            return
        try:
            os.unlink(self.path)
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc: Any) -> None:
        self.release()


def check_output(folder: str | os.PathLike[str], *, frame_bytes: int = 0) -> None:
    """Make sure ``folder`` exists, can be written and has room for ``frame_bytes``, before any work.

    Raises
    ------
    FrameWriteError
        The folder cannot be created or written (read-only, permission,
        full), or has less free space than ``frame_bytes``; the message names
        the folder and the reason.
    """
    folder = Path(folder)
    free = probe_folder(folder)
    if free is None:  # pragma: no cover - no statvfs: the writes will say
        return
    if frame_bytes > free:
        raise FrameWriteError(
            f"no room for one frame: its outputs take about {frame_bytes / 1e6:.1f} MB and "
            f"{free / 1e6:.1f} MB are free (No space left on device)", path=folder)


class SummaryReserve:
    """Room for ``summary.json`` set aside at the start of a run and released just before it is written.

    Parameters
    ----------
    folder
        The output folder.
    frames
        Frames in the run (the summary grows with them).
    """

    def __init__(self, folder: str | os.PathLike[str], frames: int) -> None:
        self.path = Path(folder) / _RESERVE_NAME
        size = 65536 + 1024 * int(frames)
        try:
            with open(self.path, "wb") as fh:
                fh.write(b"\0" * size)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as exc:
            self.release()
            raise FrameWriteError(f"no room for the run's summary ({size} bytes): {os_reason(exc)}",
                                  path=Path(folder)) from exc

    def release(self) -> None:
        """Free the reserved room (idempotent)."""
        try:
            self.path.unlink()
        except OSError:
            pass


def summarize(results: Iterable[dict[str, Any]], problems: Sequence[dict[str, str]], *,
              opts: Any, seconds: float, interrupted: bool,
              planned: Sequence[Any] | None = None) -> dict[str, Any]:
    """The run's summary.json content.

    Every planned frame appears once: ``done``, ``skipped`` (up to date),
    ``failed`` (with its error), ``cancelled`` (in progress when the run was
    stopped) or ``not_started`` (the run was stopped first).  ``planned``:
    the run's jobs (:class:`polcam.process.FrameJob`), for ``not_started``.
    ``peak_rss_mb``: the largest of the done frames' peak memory (None when
    no frame was computed).
    """
    results = sorted(results, key=lambda r: r["name"])
    seen = {r["name"] for r in results}
    not_started = [j.input for j in planned or () if j.name not in seen]
    failed = [{"input": r["input"], "error": r["error"]} for r in results if r["status"] == "failed"]
    return {
        "polcam_version": __version__,
        "options": jsonable(asdict(opts)),
        "frames": len(results) + len(problems) + len(not_started),
        "done": sum(r["status"] == "done" for r in results),
        "skipped": sum(r["status"] == "skipped" for r in results),
        "failed": failed + list(problems),
        "cancelled": [{"input": r["input"], "reason": r["error"]} for r in results if r["status"] == "cancelled"],
        "not_started": not_started,
        "interrupted": interrupted,
        "seconds": seconds,
        "peak_rss_mb": max((r["peak_rss_mb"] for r in results if "peak_rss_mb" in r), default=None),
        "results": [{k: v for k, v in r.items() if k != "error"} for r in results],
    }


def write_summary(out_dir: Path, summary: dict[str, Any]) -> Path:
    """Write OUT_DIR/summary.json atomically."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(out_dir / "summary.json", "w") as fh:
        json.dump(summary, fh, indent=2)
    return out_dir / "summary.json"
