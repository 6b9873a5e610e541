"""Saving captured frames: losslessly, atomically, on writer threads.

Files: ``OUT/frame_NNNNNN.<ext>`` with its JSON sidecar ``frame_NNNNNN.json``
(layout, pixel format, levels, exposure, gain, timestamps, camera, ROI,
mirroring: :data:`polcam.frame.SIDECAR_KEYS`), both written atomically: the
frame's data and its sidecar's go to hidden temporary files (``fsync``-ed)
before either name appears, then the sidecar is renamed, then the frame.  So
a full disk or an unwritable folder leaves neither file; a frame file on disk
always has its sidecar (a frame without one would be read with the wrong
layout and levels); a sidecar whose frame could not be renamed is removed,
and the next capture into the folder removes the orphan sidecar a crash
between the two renames could leave (:func:`clean_stale`).  Formats
(:data:`SAVE_FORMATS`): ``raw`` (the bytes exactly as the camera sent them,
in the pixel format's packing), ``tiff`` (uncompressed), ``npy``, ``png``
(lossless but ~90 ms a 5 MP frame: too slow for camera rate).

The first failed write stops the saver (:attr:`FrameSaver.write_error`):
frames handed to it afterwards, and those still queued, are counted as
``unsaved`` rather than tried one by one against a full disk.

:class:`FrameSaver` is a capture's file sink (:class:`polcam.sinks.base.Sink`):
``log(index, record)`` queues ``record.frame``.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import time
from pathlib import Path
from typing import Any

from polcam.errors import FrameWriteError, PolcamError
from polcam.frame import Frame
from polcam.io import read_sidecar, sidecar_path, write_frame
from polcam.io.atomic import atomic_write, os_reason, probe_folder
from polcam.io.sidecar import write_sidecar
from polcam.sinks.base import Record, SinkBase

__all__ = ["SAVE_FORMATS", "FrameSaver", "check_writable", "clean_stale", "existing_frames", "frame_name",
           "os_reason", "write_captured_frame"]

#: ``--format`` choices and their file extensions.
SAVE_FORMATS: dict[str, str] = {"raw": ".raw", "tiff": ".tif", "npy": ".npy", "png": ".png"}

_FRAME_PREFIX = "frame_"


def frame_name(index: int) -> str:
    """File stem of the ``index``-th frame of a capture: ``frame_000042``."""
    return f"{_FRAME_PREFIX}{int(index):06d}"


def write_captured_frame(path: Path, frame: Frame, *, extra: dict[str, Any] | None = None) -> Path:
    """Write one frame and its sidecar atomically, raw dumps straight from the camera's bytes.

    Parameters
    ----------
    path
        Target file; its extension picks the container (:func:`polcam.io.write_frame`).
        A ``.raw`` target of a frame that carries the camera's bytes
        (``payload``) gets exactly those bytes.
    frame
        The frame, uint8/uint16 counts as the camera sent them.
    extra
        Sidecar keys to add to the frame's own (e.g. ``polarizer_deg``).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    FrameWriteError
        An unwritable target or a frame that cannot be stored losslessly.
    """
    path = Path(path)
    payload = getattr(frame, "payload", None)
    try:
        if path.suffix == ".raw" and payload is not None:
            meta = {**frame.sidecar(), **(extra or {})}
            with atomic_write(path, "wb") as fh:
                fh.write(payload)
                fh.flush()
                os.fsync(fh.fileno())  # the frame's data are on disk before its sidecar is named
                write_sidecar(path, meta)  # renamed before the frame: a frame file never lacks its sidecar
            return path
        write_frame(path, frame)  # the same order: both written, then sidecar and frame renamed
        if extra:
            write_sidecar(path, {**(read_sidecar(path) or {}), **extra})
    except BaseException:
        if not path.exists():  # no sidecar without its frame
            with contextlib.suppress(OSError):
                sidecar_path(path).unlink()
        raise
    return path


def check_writable(out: Path, *, need_bytes: int = 1 << 20) -> Path:
    """Create ``out`` if needed and make sure frames can be written there, before any frame is taken.

    A hidden probe file (``.frame_probe_*``) of 64 KiB is written, ``fsync``-ed
    and removed, and the file system must have at least ``need_bytes`` free.

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    FrameWriteError
        The folder cannot be created, is not a folder, cannot be written
        (read-only file system, permissions), or the disk is full; the
        message names the folder and the system's reason.
    """
    out = Path(out)
    free = probe_folder(out, cannot="cannot write frames into the output folder")
    if free is not None and free < need_bytes:
        raise FrameWriteError(f"cannot write frames into the output folder: only {free} bytes free on its disk, "
                              f"expected at least {need_bytes}", path=out)
    return out


class FrameSaver(SinkBase):
    """Write frames on worker threads, losslessly and atomically: a capture's file sink.

    Parameters
    ----------
    out
        Output folder (must exist).
    ext
        File extension: ``.raw``, ``.tif``, ``.npy`` or ``.png``.
    workers
        Writer threads (file writes and ``fsync`` release the GIL).
    queue_frames
        Frames waiting to be written before :meth:`put` waits.
    abort
        Once set, :meth:`log` stops waiting for room (the frame is counted
        unsaved) and :meth:`close` drops the frames still queued.
    """

    def __init__(self, out: Path, ext: str, *, workers: int = 2, queue_frames: int = 16,
                 abort: threading.Event | None = None) -> None:
        self.out = Path(out)
        self.ext = ext
        self.abort = abort
        self._q: queue.Queue[tuple[int, Frame] | None] = queue.Queue(maxsize=max(1, int(queue_frames)))
        self._lock = threading.Lock()
        self.saved: list[str] = []
        self.failed: list[dict[str, str]] = []
        self.unsaved = 0
        self.seconds = 0.0
        #: The first failed write, ``{"file", "folder", "reason", "error"}``; the saver writes nothing after it.
        self.write_error: dict[str, str] | None = None
        #: Set at the first failed write (the capture loop watches it).
        self.failed_event = threading.Event()
        #: ``time.monotonic()`` of the first failed write, or ``None``.
        self.failed_at: float | None = None
        self._closed = False
        self._threads = [threading.Thread(target=self._work, name=f"saver-{i}", daemon=True)
                         for i in range(max(1, int(workers)))]
        for t in self._threads:
            t.start()

    def put(self, index: int, frame: Frame, *, abort: threading.Event | None = None) -> bool:
        """Queue a frame for writing, waiting for room; False (counted unsaved) if ``abort`` was set
        meanwhile or a write has failed."""
        while True:
            if self.failed_event.is_set():
                with self._lock:
                    self.unsaved += 1
                return False
            try:
                self._q.put((index, frame), timeout=0.1)
                return True
            except queue.Full:
                if abort is not None and abort.is_set():
                    with self._lock:
                        self.unsaved += 1
                    return False

    def log(self, index: int, record: Record) -> None:
        """Queue ``record.frame`` as frame ``index`` (:meth:`put` with this saver's ``abort``).

        Raises
        ------
        ValueError
            A record without a frame.
        """
        if record.frame is None:
            raise ValueError(f"FrameSaver: record {index} carries no frame to save")
        self.put(index, record.frame, abort=self.abort)

    def _work(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            index, frame = item
            if self.failed_event.is_set():  # nothing more against a disk that refused a write
                with self._lock:
                    self.unsaved += 1
                continue
            path = self.out / f"{frame_name(index)}{self.ext}"
            t0 = time.perf_counter()
            try:
                write_captured_frame(path, frame)
            except (PolcamError, OSError) as exc:
                with self._lock:
                    self.failed.append({"file": path.name, "error": str(exc)})
                    if self.write_error is None:
                        self.failed_at = time.monotonic()
                        self.write_error = {"file": path.name, "folder": str(self.out),
                                            "reason": os_reason(exc), "error": str(exc)}
                self.failed_event.set()
                continue
            with self._lock:
                self.saved.append(path.name)
                self.seconds += time.perf_counter() - t0

    def pending(self) -> int:
        """Frames waiting to be written."""
        return self._q.qsize()

    def close(self, *, abort: bool | None = None) -> None:
        """Write what is queued (or, with ``abort``, drop it, counted as unsaved) and stop.

        ``abort=None``: whether this saver's ``abort`` event is set.  A second call does nothing.
        """
        if abort is None:
            abort = self.abort is not None and self.abort.is_set()
        if self._closed:
            return
        self._closed = True
        if abort:
            while True:
                try:
                    item = self._q.get_nowait()
                except queue.Empty:
                    break
                if item is not None:
                    with self._lock:
                        self.unsaved += 1
        for _ in self._threads:
            self._q.put(None)
        for t in self._threads:
            t.join()


def clean_stale(out: Path) -> int:
    """Remove what a killed capture left: hidden temporary files (``.frame_*``) and
    sidecars without their frame (``frame_NNNNNN.json`` alone); returns how many."""
    n = 0
    frames = {p.stem for p in out.glob(f"{_FRAME_PREFIX}*") if p.suffix != ".json"}
    stale = list(out.glob(f".{_FRAME_PREFIX}*"))
    stale += [p for p in out.glob(f"{_FRAME_PREFIX}*.json") if p.stem not in frames]
    for p in stale:
        if p.is_file():
            try:
                p.unlink()
                n += 1
            except OSError:
                pass
    return n


def existing_frames(out: Path) -> list[int]:
    idx = []
    for p in out.glob(f"{_FRAME_PREFIX}*"):
        stem = p.stem[len(_FRAME_PREFIX):]
        if stem.isdigit() and p.suffix != ".json":
            idx.append(int(stem))
    return sorted(idx)
