"""Saving captured frames: losslessly, atomically, on writer threads.

Files: ``OUT/frame_NNNNNN.<ext>`` with its JSON sidecar ``frame_NNNNNN.json``
(layout, pixel format, levels, exposure, gain, timestamps, camera, ROI,
mirroring: :data:`polcam.frame.SIDECAR_KEYS`), both written atomically
(temporary file, ``fsync``, rename; the sidecar first, so every frame file on
disk has its sidecar).  Formats (:data:`SAVE_FORMATS`): ``raw`` (the bytes
exactly as the camera sent them, in the pixel format's packing), ``tiff``
(uncompressed), ``npy``, ``png`` (lossless but ~90 ms a 5 MP frame: too slow
for camera rate).
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import Any

from polcam.errors import PolcamError
from polcam.frame import Frame

__all__ = ["SAVE_FORMATS", "FrameSaver", "clean_stale", "existing_frames", "frame_name", "write_captured_frame"]

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
    from polcam.io import read_sidecar, write_frame
    from polcam.io.atomic import atomic_write
    from polcam.io.sidecar import write_sidecar

    path = Path(path)
    payload = getattr(frame, "payload", None)
    if path.suffix == ".raw" and payload is not None:
        write_sidecar(path, {**frame.sidecar(), **(extra or {})})  # first: a frame file never lacks its sidecar
        with atomic_write(path, "wb") as fh:
            fh.write(payload)
        return path
    write_frame(path, frame)
    if extra:
        write_sidecar(path, {**(read_sidecar(path) or {}), **extra})
    return path


class FrameSaver:
    """Write frames on worker threads, losslessly and atomically.

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
    """

    def __init__(self, out: Path, ext: str, *, workers: int = 2, queue_frames: int = 16) -> None:
        self.out = Path(out)
        self.ext = ext
        self._q: queue.Queue[tuple[int, Frame] | None] = queue.Queue(maxsize=max(1, int(queue_frames)))
        self._lock = threading.Lock()
        self.saved: list[str] = []
        self.failed: list[dict[str, str]] = []
        self.unsaved = 0
        self.seconds = 0.0
        self._threads = [threading.Thread(target=self._work, name=f"saver-{i}", daemon=True)
                         for i in range(max(1, int(workers)))]
        for t in self._threads:
            t.start()

    def put(self, index: int, frame: Frame, *, abort: threading.Event | None = None) -> bool:
        """Queue a frame for writing, waiting for room; False if ``abort`` was set meanwhile."""
        while True:
            try:
                self._q.put((index, frame), timeout=0.1)
                return True
            except queue.Full:
                if abort is not None and abort.is_set():
                    with self._lock:
                        self.unsaved += 1
                    return False

    def _work(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            index, frame = item
            path = self.out / f"{frame_name(index)}{self.ext}"
            t0 = time.perf_counter()
            try:
                write_captured_frame(path, frame)
            except (PolcamError, OSError) as exc:
                with self._lock:
                    self.failed.append({"file": path.name, "error": str(exc)})
                continue
            with self._lock:
                self.saved.append(path.name)
                self.seconds += time.perf_counter() - t0

    def pending(self) -> int:
        """Frames waiting to be written."""
        return self._q.qsize()

    def close(self, *, abort: bool = False) -> None:
        """Write what is queued (or, with ``abort``, drop it, counted as unsaved) and stop."""
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
    """Remove hidden temporary files a killed capture left (``.frame_*``); returns how many."""
    n = 0
    for p in out.glob(f".{_FRAME_PREFIX}*"):
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
