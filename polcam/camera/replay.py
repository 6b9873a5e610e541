"""``replay:DIR``: a folder of raw frames played back as a camera.

The test and demo camera, and a way to re-run a capture session: it plays
every raw frame of a folder (any format :func:`polcam.io.read_frame` reads,
with its sidecar) in file-name order through the same protocol as a real
camera, from its own acquisition thread.

Two modes:

* no frame rate (the default): as fast as the consumer takes the frames,
  and losslessly: the acquisition thread waits for room in the frame queue,
  so every file arrives exactly once (per loop).
* ``frame_rate`` frames per second: paced like a free-running camera; a frame
  that finds the consumer's queue full is dropped and counted, as a real
  camera's would be.

Frames carry the metadata of their files (layout, pixel format, vendor,
exposure, gain, ROI, mirroring, levels) plus the camera's own: ``camera_id``
is ``replay:DIR``, ``frame_id`` counts the frames played (0, 1, ...) and
``timestamp_ns`` is the time of playback (``time.time_ns()``); the file's own
values are kept as ``source``, ``source_frame_id``, ``source_timestamp_ns`` and
``source_camera_id``.  A file that cannot be read counts as an incomplete
frame (status ``unreadable``) and playback goes on.

With ``loop``, the frames read in the first pass are kept in memory, up to
:data:`LOOP_CACHE_BYTES` of them, and played again from there: a camera
hands over frames without decoding files, and reading a 5 MP frame and its
sidecar again on every pass took about 7 ms of CPU per frame, a fifth of a
core at 30 fps.  Kept frames are read-only; a folder larger than the budget
reads the rest from disk on every pass.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path
from typing import Any

from polcam.camera.base import Camera, CameraNotFoundError, CameraSettingError, CameraSettings, CapturedFrame
from polcam.camera.registry import CameraFlag, register_backend
from polcam.errors import PixelFormatError, PolcamError
from polcam.frame import Frame
from polcam.io import RAW_EXTENSIONS, read_frame
from polcam.io.listing import raw_files_in
from polcam.mosaic import Layout, parse_layout

__all__ = ["LOOP_CACHE_BYTES", "ReplayCamera", "as_recorded"]

#: Bytes of decoded frames (mosaic and raw payload) a looping replay keeps in memory.
LOOP_CACHE_BYTES = 256 * 1024 * 1024


def as_recorded(frame: Frame) -> Frame:
    """A frame with the camera id of the recording it was replayed from.

    A replayed frame carries the replay's ``camera_id`` (``replay:DIR``) and
    keeps its file's own as ``source_camera_id``.  What a calibration is
    checked against (and records) is the camera that exposed the frame, so
    this returns a frame sharing the mosaic (and payload) whose
    ``camera_id`` is the file's, or absent when the file had none.  Frames
    that were not replayed are returned as they are.

    Parameters
    ----------
    frame
        Any frame (a :class:`~polcam.camera.base.CapturedFrame` keeps its type).

    Returns
    -------
    Frame
        ``frame`` itself, or a shallow copy with the metadata changed.
    """
    meta = frame.metadata
    cam = meta.get("camera_id")
    if not (isinstance(cam, str) and cam.startswith("replay:") and "source" in meta):
        return frame
    new = dict(meta)
    if new.get("source_camera_id") is not None:
        new["camera_id"] = new["source_camera_id"]
    else:
        new.pop("camera_id", None)
    return dataclasses.replace(frame, metadata=new)


class ReplayCamera(Camera):
    """Play a folder of raw frames as a camera.

    Parameters
    ----------
    folder
        Folder of raw frames (``.raw``/``.npy``/``.png``/``.tif``/... with
        sidecars); hidden files and sidecars are skipped.
    frame_rate
        Frames per second, or ``None`` to deliver as fast as the consumer
        reads, without loss.
    loop
        Start over after the last file (until stopped).
    queue_frames
        Capacity of the frame queue.
    """

    def __init__(self, folder: str | Path, *, frame_rate: float | None = None, loop: bool = False,
                 queue_frames: int = 8) -> None:
        super().__init__(f"replay:{folder}", queue_frames=queue_frames)
        self.folder = Path(folder)
        if frame_rate is not None and not frame_rate > 0:
            raise CameraSettingError(f"frame rate {frame_rate!r}: expected a positive number")
        self.frame_rate = frame_rate
        self.loop = bool(loop)
        self.files: list[Path] = []
        self._layout_override: Layout | None = None
        self._layout: Layout | None = None
        self._roi: tuple[int, int, int, int] | None = None
        self._first: Any = None
        self._trigger = "free"
        self._triggers = threading.Semaphore(0)
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self._kept: dict[Path, tuple[Frame, bytes | None]] = {}  # path -> (frame, payload) when looping
        self._kept_bytes = 0

    # ------------------------------------------------------------------ open
    def open(self) -> ReplayCamera:
        """List the folder's raw frames and read the first one.

        Raises
        ------
        CameraNotFoundError
            Missing folder, or no raw frame in it.
        FrameReadError, PixelFormatError
            The first frame cannot be read.
        """
        if not self.folder.is_dir():
            raise CameraNotFoundError(
                f"replay folder {str(self.folder)!r} does not exist (replay:DIR plays a folder of raw frames)"
            )
        self.files = raw_files_in(self.folder)
        if not self.files:
            raise CameraNotFoundError(
                f"replay folder {str(self.folder)!r} holds no raw frames "
                f"(expected files ending in {', '.join(RAW_EXTENSIONS[:9])}, ...)"
            )
        self._first = read_frame(self.files[0])
        self._layout = self._first.layout
        self._opened = True
        return self

    def close(self) -> None:
        """Stop playback."""
        if self._running:
            self.stop()
        self._opened = False

    @property
    def layout(self) -> Layout | None:
        return self._layout

    @property
    def info(self) -> dict[str, Any]:
        first = self._first
        meta = {} if first is None else first.metadata
        return {
            "id": self.camera_id,
            "vendor": "polcam",
            "model": "replay",
            "protocol": "file",
            "folder": str(self.folder),
            "files": len(self.files),
            "frame_rate": self.frame_rate,
            "pixel_format": meta.get("pixel_format"),
            "layout": None if self._layout is None else self._layout.short_name,
        }

    @property
    def waits_for_reader(self) -> bool:
        """True without a frame rate: every file waits in the queue until it is read."""
        return self.frame_rate is None

    # ------------------------------------------------------------- configure
    def _configure(self, settings: CameraSettings) -> dict[str, Any]:
        """Apply what a file source can: layout, ROI (a crop), frame rate, trigger.

        Exposure, gain and mirroring are recorded in the files and cannot be
        changed: they are listed in ``ignored``.  A ``pixel_format`` must be
        the one the files carry.

        Raises
        ------
        PixelFormatError
            A pixel format other than the files' (the message names it).
        CameraSettingError
            A bad ROI, frame rate or trigger.
        """
        s = settings
        if not self._opened:
            raise CameraSettingError(f"camera {self.camera_id} is not open: call open() first")
        if self._running:
            raise CameraSettingError(f"camera {self.camera_id}: stop playback before configuring")
        first = self._first
        have = first.metadata.get("pixel_format")
        if s.pixel_format is not None and s.pixel_format != have:
            raise PixelFormatError(
                f"replay folder {str(self.folder)!r} holds frames in pixel format {have or 'unknown (plain 8/16-bit)'}; "
                f"supported: {have or 'the files as they are (omit --pixel-format)'}, not {s.pixel_format!r}"
            )
        ignored = [name for name, v in (("exposure_us", s.exposure_us), ("gain_db", s.gain_db),
                                        ("reverse_x", s.reverse_x), ("reverse_y", s.reverse_y)) if v is not None]
        if s.layout is not None:
            self._layout_override = parse_layout(s.layout)
        base = self._layout_override or first.layout
        if s.frame_rate is not None:
            if not s.frame_rate > 0:
                raise CameraSettingError(f"frame rate {s.frame_rate!r}: expected a positive number")
            self.frame_rate = float(s.frame_rate)
        if s.trigger is not None:
            if s.trigger not in ("free", "software"):
                raise CameraSettingError(
                    f"trigger {s.trigger!r}: the replay camera has 'free' and 'software' triggers only"
                )
            self._trigger = s.trigger
        if s.roi is not None:
            self._roi = self._aligned_roi(s.roi, base, first.shape)
        self._layout = base
        if base is not None and self._roi is not None:
            self._layout = base.shifted(self._roi[0], self._roi[1])
        return {
            "pixel_format": have,
            "layout": None if self._layout is None else self._layout.short_name,
            "roi": None if self._roi is None else list(self._roi),
            "frame_rate": self.frame_rate,
            "trigger": self._trigger,
            "ignored": ignored,
        }

    @staticmethod
    def _aligned_roi(roi: tuple[int, int, int, int], layout: Layout | None,
                     shape: tuple[int, int]) -> tuple[int, int, int, int]:
        try:
            x, y, w, h = (int(v) for v in roi)
        except (TypeError, ValueError):
            raise CameraSettingError(f"ROI {roi!r}: expected four integers x, y, width, height") from None
        period = 2 if layout is None else layout.period
        x, y = x - x % period, y - y % period
        w, h = w - w % period, h - h % period
        height, width = shape
        if x < 0 or y < 0 or w < 2 * period or h < 2 * period or x + w > width or y + h > height:
            raise CameraSettingError(
                f"ROI {roi!r} (aligned to whole cells: {x}, {y}, {w}, {h}) does not fit the "
                f"{width}x{height} frames of the replay folder"
            )
        return x, y, w, h

    def trigger(self) -> None:
        """Release one frame (``trigger="software"``)."""
        if self._trigger != "software":
            raise CameraSettingError("the replay camera is free-running: configure(trigger='software') first")
        self._triggers.release()

    # -------------------------------------------------------------- playback
    def _start(self) -> None:
        if not self._opened:
            raise CameraSettingError(f"camera {self.camera_id} is not open: call open() first")
        self._stop_event.clear()
        self._kept.clear()  # settings (layout, ROI) may have changed since the last start
        self._kept_bytes = 0
        self._triggers = threading.Semaphore(0)
        self._thread = threading.Thread(target=self._play, name="replay", daemon=True)
        self._thread.start()

    def _stop(self) -> None:
        self._stop_event.set()
        self._triggers.release()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        self._finished.set()

    def _read(self, path: Path) -> tuple[Frame, bytes | None]:
        """The file's frame and, for a raw file played without ROI, its bytes; kept when looping."""
        kept = self._kept.get(path)
        if kept is not None:
            return kept
        fr = read_frame(path, layout=self._layout_override)
        payload = path.read_bytes() if path.suffix.lower() in (".raw", ".bin") and self._roi is None else None
        size = fr.mosaic.nbytes + (len(payload) if payload is not None else 0)
        if self.loop and self._kept_bytes + size <= LOOP_CACHE_BYTES:
            fr.mosaic.setflags(write=False)  # delivered again on every pass
            self._kept[path] = (fr, payload)
            self._kept_bytes += size
        return fr, payload

    def _frame(self, path: Path, seq: int) -> CapturedFrame:
        fr, payload = self._read(path)
        meta = dict(fr.metadata)
        mosaic = fr.mosaic
        layout = fr.layout
        if self._roi is not None:
            x, y, w, h = self._roi
            height, width = mosaic.shape
            if x + w > width or y + h > height:
                raise CameraSettingError(f"ROI {self._roi} does not fit this {width}x{height} frame")
            mosaic = mosaic[y:y + h, x:x + w]
            if layout is not None:
                layout = layout.shifted(x, y)
            ox, oy, ow, oh = meta.get("roi") or (0, 0, width, height)
            sx = ox + (ow - x - w if meta.get("reverse_x") else x)
            sy = oy + (oh - y - h if meta.get("reverse_y") else y)
            meta["roi"] = [sx, sy, w, h]
        for key in ("frame_id", "timestamp_ns", "camera_id"):
            if key in meta:
                meta[f"source_{key}"] = meta[key]
        meta.pop("path", None)
        meta.update({"source": str(path), "camera_id": self.camera_id, "frame_id": seq,
                     "timestamp_ns": time.time_ns()})
        return CapturedFrame(mosaic=mosaic, layout=layout, bit_depth=fr.bit_depth,
                             black_level=fr.black_level, white_level=fr.white_level,
                             metadata=meta, payload=payload)

    def _play(self) -> None:
        seq = 0
        t0 = time.monotonic()
        stop = self._stop_event
        while not stop.is_set():
            for path in self.files:
                if stop.is_set():
                    break
                if self._trigger == "software":
                    self._triggers.acquire()
                    if stop.is_set():
                        break
                elif self.frame_rate:
                    delay = t0 + seq / self.frame_rate - time.monotonic()
                    if delay > 0 and stop.wait(delay):
                        break
                try:
                    frame = self._frame(path, seq)
                except (PolcamError, OSError):
                    self._count("unreadable", incomplete=True)
                    seq += 1
                    continue
                seq += 1
                self._deliver(frame, block=not self.frame_rate, stop=stop)
            if not self.loop:
                break
        self._finished.set()


#: ``replay:DIR``; ``--loop`` is its own flag, and ``--frame-rate`` its playback rate (a constructor keyword).
register_backend("replay:", ReplayCamera, name="replay", open_settings=("frame_rate",), flags=(
    CameraFlag("--loop", "loop", "replay: start over after the last file", {"action": "store_true"}),
))
