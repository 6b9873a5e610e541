"""``polcam capture``: record a camera losslessly and watch it live.

Threads of a capture::

    camera acquisition thread --(bounded frame queue)--> capture loop (main thread)
        capture loop --(bounded save queue)--> saver threads: every good frame, lossless, atomic
        capture loop --(one-slot mailbox, newest wins)--> live thread: demosaic at cell
            resolution, Stokes, DoLP, AoLP, Imin, Rerun logging
        live thread --(one-slot mailbox)--> separation thread: the chosen method on the
            newest frame whenever the previous separation is done

Nothing the capture does blocks acquisition: the camera's own thread only
ever drops frames into its queue (a full queue drops the frame and counts
it).  Saving is lossless for every frame the capture loop takes: when the
disk falls behind, the save queue fills, the loop waits, the camera queue
fills and the camera's frames are dropped and counted, so the summary always
says what was lost.  The live view takes the newest frame whenever it is
free; frames it did not get to are counted as skipped (they are still saved).

Files: ``OUT/frame_NNNNNN.<ext>`` with the sidecar ``frame_NNNNNN.json`` of
DESIGN.md section 3, both written atomically (temporary file, ``fsync``,
rename; the sidecar first, so every frame file on disk has its sidecar), and
``OUT/summary.json``.  Formats: ``raw`` (default: the bytes exactly as the
camera sent them, in the pixel format's packing), ``tiff`` (uncompressed),
``npy``, ``png`` (lossless but ~90 ms a 5 MP frame: too slow for camera rate).

Calibration (``--calibration FILE``, ``run_capture(calibration=...)``): loaded
once; the first frame is checked against it (size, layout, camera, ROI,
mirroring, and the exposure, gain and bit depth of its dark) before anything is
saved, and a mismatch stops the capture with a ``CalibrationError``.  The live
view (maps and separation) is computed from the corrected mosaic
(``apply_calibration(..., polarimetric="mosaic")``); the saved frames, their
sidecars and the ``/camera/raw`` view stay exactly as the camera sent them.
The summary records the calibration file and its SHA-256.

Stopping: ``--frames N``, ``--duration S``, the end of a replay folder, or
SIGINT / SIGTERM: acquisition stops, queued frames are written, the summary
(frames good, incomplete, dropped, saved, ...) is printed and written.  A
second signal abandons the frames still waiting to be written (they are
counted as ``unsaved``).  After SIGKILL or a power cut, complete frames are
on disk and nothing else except hidden temporary files (``.frame_*``), which
the next capture into that folder removes.
"""

from __future__ import annotations

import argparse
import json
import queue
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from polcam.camera.base import TRIGGER_MODES, Camera, CameraSettingError, open_camera
from polcam.errors import LayoutError, MethodError, PolcamError
from polcam.frame import Frame
from polcam.mosaic import Layout

if TYPE_CHECKING:
    from polcam.calibration.store import Calibration

__all__ = [
    "CAMERA_SETTINGS",
    "SAVE_FORMATS",
    "FrameSaver",
    "StopRequest",
    "LiveMaps",
    "LiveProcessor",
    "add_camera_arguments",
    "add_capture_parser",
    "camera_options",
    "cmd_capture",
    "configure_camera",
    "frame_name",
    "live_maps",
    "main",
    "run_capture",
    "write_captured_frame",
]

#: ``--format`` choices and their file extensions.
SAVE_FORMATS: dict[str, str] = {"raw": ".raw", "tiff": ".tif", "npy": ".npy", "png": ".png"}

_FRAME_PREFIX = "frame_"


def frame_name(index: int) -> str:
    """File stem of the ``index``-th frame of a capture: ``frame_000042``."""
    return f"{_FRAME_PREFIX}{int(index):06d}"


# ---------------------------------------------------------------------------
# live polarization maps (fused OpenCV path)
# ---------------------------------------------------------------------------

_BAYER_TO_RGB = {
    "RGGB": cv2.COLOR_BayerRGGB2RGB,
    "BGGR": cv2.COLOR_BayerBGGR2RGB,
    "GRBG": cv2.COLOR_BayerGRBG2RGB,
    "GBRG": cv2.COLOR_BayerGBRG2RGB,
}
_TWO_PI = float(2.0 * np.pi)


@dataclass
class LiveMaps:
    """Polarization maps of one frame at the polarizer-cell resolution (h, w = H/2, W/2).

    ``ic``, ``diffuse`` and ``specular`` are stored as values; multiply by
    :attr:`scale` for linear values normalised by the white level
    (:meth:`normalized`).  Mono sensors: float32 with ``scale == 1``.
    Colour sensors: uint8 display values with ``scale == 1 / 255`` (they come
    out of OpenCV's integer Bayer interpolation; the live view needs 8 bits).

    Attributes
    ----------
    ic
        Ic = S0 / 2, the mean over the four angles, above black: (h, w) mono
        or (h, w, 3) RGB; normalised values in [0, 1] within the levels.
    dolp
        DoLP in [0, 1], float32 (h, w).  Colour: of the luminance-weighted
        Stokes vector (R + 2G + B) / 4.
    aolp
        AoLP in radians, [0, pi), float32 (h, w); colour: as ``dolp``.
    diffuse
        Imin = Ic - Isv clipped at 0 (the ``imin`` separation), like ``ic``.
    specular
        Ic - diffuse, like ``ic``.
    scale
        Factor from stored values to normalised values.
    """

    ic: np.ndarray
    dolp: np.ndarray
    aolp: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    scale: float = 1.0

    def normalized(self, name: str) -> np.ndarray:
        """Map ``name`` (``ic``, ``diffuse``, ``specular``) as float32 normalised values."""
        arr = getattr(self, name)
        if self.scale == 1.0 and arr.dtype == np.float32:
            return arr
        return (arr.astype(np.float32) * np.float32(self.scale)).astype(np.float32)


def _angle_planes(mosaic: np.ndarray, layout: Layout) -> list[np.ndarray]:
    """The four (H/2, W/2) angle planes of a mosaic, in the order 0, 45, 90, 135."""
    h, w = mosaic.shape
    v = np.ascontiguousarray(mosaic).reshape(h // 2, 2, w // 2, 2)
    cell = layout.angle_index(2, 2)
    planes: list[np.ndarray] = [np.empty(0)] * 4
    for r in range(2):
        left, right = cv2.split(v[:, r])  # rows of the cell: one OpenCV pass splits the columns
        planes[int(cell[r, 0])] = left
        planes[int(cell[r, 1])] = right
    return planes


def _scale(a: np.ndarray, factor: float, offset: float = 0.0, dtype: int = cv2.CV_32F) -> np.ndarray:
    """``a * factor + offset`` in one OpenCV pass (saturating for integer ``dtype``)."""
    return cv2.addWeighted(a, float(factor), a, 0.0, float(offset), dtype=dtype)


def _orientation(s0: np.ndarray, s1: np.ndarray, s2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(|(S1, S2)|, DoLP clipped to [0, 1], AoLP in [0, pi)) of single-channel float32 maps."""
    mag, ang = cv2.cartToPolar(s1, s2)
    dolp = cv2.divide(mag, s0)  # OpenCV gives 0 where S0 is 0
    dolp = cv2.max(cv2.min(dolp, 1.0), 0.0)
    # the angle of (S1, S2) is in [0, 2 pi]; 2 pi is the orientation of 0
    ang = cv2.threshold(ang, _TWO_PI * (1.0 - 1e-7), 0.0, cv2.THRESH_TOZERO_INV)[1]
    return mag, dolp, _scale(ang, 0.5)


def live_maps(mosaic: np.ndarray, layout: Layout, *, black_level: float = 0.0,
              white_level: float | None = None) -> LiveMaps:
    """Ic, DoLP, AoLP and the Imin layers of a raw mosaic at the polarizer-cell resolution.

    Computed in a few OpenCV passes over the four angle planes (each 2x2
    polarizer cell gives one sample per angle), without building a float
    stack.

    Mono sensors: exactly ``polcam.stokes`` (``stokes``, ``dolp``, ``aolp``,
    ``imin``) of ``polcam.demosaic(..., resolution="cell")`` up to float32
    rounding (AoLP through OpenCV's ``cartToPolar``, within 1e-4 rad), and the
    ``imin`` separation of that stack.

    Colour sensors (each angle's cell image is a Bayer mosaic): Ic, Imin and
    the specular part are computed per colour sample, rounded to 8 bits and
    interpolated by OpenCV's bilinear Bayer demosaicing; DoLP and AoLP are
    those of the luminance-weighted Stokes vector, (R + 2G + B) / 4, which
    the 3x3 binomial filter ``[1 2 1]^T [1 2 1] / 16`` gives at every Bayer
    phase.  Where colour is locally uniform these equal the per-channel
    values of the full method (to 8 bits); at colour edges they are the live
    view's approximation (the saved frames are exact).

    Parameters
    ----------
    mosaic
        (H, W) raw counts, H and W even: uint8 or uint16 as the camera sent
        them, or float32 / float64 (a corrected mosaic, e.g.
        :func:`polcam.calibration.apply_calibration`'s: counts above the dark,
        possibly negative by noise; float64 is converted to float32).
    layout
        Layout of the mosaic.
    black_level, white_level
        Counts of black and saturation (white default: the integer dtype's
        maximum; a float mosaic needs it).

    Returns
    -------
    LiveMaps
        Maps of (H/2, W/2) pixels.

    Raises
    ------
    LayoutError
        A mosaic that is not 2-D uint8/uint16/float with even sizes of at
        least two layout periods, a float mosaic without ``white_level``, or
        levels with white <= black.
    """
    if mosaic.ndim != 2 or mosaic.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise LayoutError(f"mosaic of shape {mosaic.shape} and dtype {mosaic.dtype}: "
                          "expected 2-D uint8/uint16 counts (or float32 corrected counts)")
    h, w = mosaic.shape
    if h % 2 or w % 2 or h < 2 * layout.period or w < 2 * layout.period:
        raise LayoutError(f"mosaic of {w}x{h} pixels: expected even sizes of at least {2 * layout.period}")
    if mosaic.dtype.kind == "f":
        if white_level is None:
            raise LayoutError(f"{mosaic.dtype} mosaic without a white level: expected white_level in counts")
        mosaic = np.asarray(mosaic, dtype=np.float32)
    white = float(np.iinfo(mosaic.dtype).max) if white_level is None else float(white_level)
    black = float(black_level)
    span = white - black
    if span <= 0:
        raise LayoutError(f"white level {white} is not above black level {black}")
    i0, i45, i90, i135 = _angle_planes(mosaic, layout)
    f32 = cv2.CV_32F
    total = cv2.add(cv2.add(i0, i90, dtype=f32), cv2.add(i45, i135, dtype=f32))  # 2 S0 in counts
    s1 = cv2.subtract(i0, i90, dtype=f32)
    s2 = cv2.subtract(i45, i135, dtype=f32)
    s0c = _scale(total, 0.5, -2.0 * black)  # S0 above black, counts
    if not layout.is_color:
        mag, dolp, aolp = _orientation(s0c, s1, s2)
        ic = _scale(s0c, 0.5 / span)
        diffuse = cv2.max(_scale(cv2.subtract(s0c, mag), 0.5 / span), 0.0)  # (S0 - |S12|) / 2
        specular = cv2.subtract(ic, diffuse)
        return LiveMaps(ic=ic, dolp=dolp, aolp=aolp, diffuse=diffuse, specular=specular)
    # colour: per-sample Ic and Imin in 8 bits, then Bayer interpolation
    code = _BAYER_TO_RGB[layout.bayer]  # type: ignore[index]
    to8 = 0.5 * 255.0 / span
    diffuse_c = cv2.max(cv2.subtract(s0c, cv2.magnitude(s1, s2)), 0.0)  # 2 Imin, counts
    ic = cv2.cvtColor(_scale(s0c, to8, 0.0, cv2.CV_8U), code)
    diffuse = cv2.cvtColor(_scale(diffuse_c, to8, 0.0, cv2.CV_8U), code)
    specular = cv2.subtract(ic, diffuse)
    lum = [cv2.GaussianBlur(a, (3, 3), 0, borderType=cv2.BORDER_REFLECT_101) for a in (s0c, s1, s2)]
    _, dolp, aolp = _orientation(*lum)
    return LiveMaps(ic=ic, dolp=dolp, aolp=aolp, diffuse=diffuse, specular=specular, scale=1.0 / 255.0)


# ---------------------------------------------------------------------------
# saving
# ---------------------------------------------------------------------------

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


def _clean_stale(out: Path) -> int:
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


def _existing_frames(out: Path) -> list[int]:
    idx = []
    for p in out.glob(f"{_FRAME_PREFIX}*"):
        stem = p.stem[len(_FRAME_PREFIX):]
        if stem.isdigit() and p.suffix != ".json":
            idx.append(int(stem))
    return sorted(idx)


# ---------------------------------------------------------------------------
# live processing
# ---------------------------------------------------------------------------

class _Counters:
    """Numbers the capture loop shares with the live thread (for the statistics plots)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.fps = 0.0
        self.dropped = 0
        self.incomplete = 0


class LiveProcessor:
    """Process the newest frame whenever the previous one is done.

    Parameters
    ----------
    layout
        Layout of the frames (the camera's delivered layout).
    sink
        A :class:`polcam.sinks.rerun.RerunSink`, or ``None``.
    separate
        Separation method for the diffuse/specular layers, or ``None``.
        ``imin`` is computed on the live thread from the live maps (every
        processed frame); other methods run on their own thread on the
        polarizer-cell stack of the newest frame (``polcam.demosaic``
        bilinear, clipped to [0, 1]) whenever the previous run is done.
    separate_options
        Keyword options of that method (e.g. ``{"device": "cuda"}`` for the
        tensor method on a GPU).
    counters
        Shared frame rate / dropped / incomplete numbers to plot.
    workers
        Live threads; each takes the newest frame when it is free, so with
        two a second frame is processed while the first one is still being
        logged (OpenCV and Rerun release the GIL for their heavy parts).
    calibration
        A calibration of this camera, or ``None``.  The maps and the
        separation are computed from the corrected mosaic
        (:func:`polcam.calibration.apply_calibration`: dark, flat, defective
        pixels and the per-super-pixel polarimetric correction); the raw
        mosaic logged to ``/camera/raw`` stays as the camera sent it.
    """

    def __init__(self, layout: Layout, *, sink: Any = None, separate: str | None = None,
                 separate_options: dict[str, Any] | None = None,
                 counters: _Counters | None = None, workers: int = 2,
                 calibration: Calibration | None = None) -> None:
        self.layout = layout
        self.sink = sink
        self.calibration = calibration
        self.method = separate
        self.method_options = dict(separate_options or {})
        self.counters = counters or _Counters()
        self.processed = 0
        self.skipped = 0
        self.separations = 0
        self.separations_skipped = 0
        self.separation_errors: list[str] = []
        self.seconds = 0.0
        self.separation_seconds: list[float] = []
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending: tuple[int, Frame] | None = None
        self._closing = False
        self._sep_lock = threading.Lock()
        self._sep_wake = threading.Condition(self._sep_lock)
        self._sep_pending: tuple[int, Frame] | None = None
        self.error: BaseException | None = None
        self._threads = [threading.Thread(target=self._run, name=f"live-{i}", daemon=True)
                         for i in range(max(1, int(workers)))]
        for t in self._threads:
            t.start()
        self._sep_thread: threading.Thread | None = None
        if separate not in (None, "imin"):
            self._sep_thread = threading.Thread(target=self._run_separation, name="separation", daemon=True)
            self._sep_thread.start()

    def offer(self, index: int, frame: Frame) -> None:
        """Hand over the newest frame (replacing one not yet started, which counts as skipped)."""
        with self._lock:
            if self._pending is not None:
                self.skipped += 1
            self._pending = (index, frame)
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._lock:
                while self._pending is None and not self._closing:
                    self._wake.wait()
                if self._pending is None:
                    return
                index, frame = self._pending
                self._pending = None
            t0 = time.perf_counter()
            try:
                self._process(index, frame)
            except Exception as exc:  # noqa: BLE001 - reported in the summary, capture goes on
                with self._lock:
                    self.error = exc
                    self._closing = True
                    self._pending = None
                return
            with self._lock:
                self.seconds += time.perf_counter() - t0
                self.processed += 1

    def corrected(self, frame: Frame) -> Frame:
        """The frame the live view computes from: ``frame`` itself, or its calibrated mosaic.

        Raises
        ------
        CalibrationError
            The frame does not fit the calibration (size, layout, camera, ROI,
            mirroring; exposure, gain or bit depth of a dark).
        """
        if self.calibration is None:
            return frame
        from polcam.calibration import apply_calibration
        from polcam.camera.replay import as_recorded

        return apply_calibration(as_recorded(frame), self.calibration, polarimetric="mosaic")

    def _process(self, index: int, frame: Frame) -> None:
        ts = frame.metadata.get("timestamp_ns")
        view = self.corrected(frame)
        maps = live_maps(view.mosaic, self.layout, black_level=view.black_level,
                         white_level=view.white_level)
        sink = self.sink
        if sink is not None:
            sink.log_raw(index, ts, frame.mosaic, bit_depth=frame.bit_depth)  # raw is raw
            # S0 = 2 Ic
            sink.log_polarization(index, ts, s0=maps.ic, dolp=maps.dolp, aolp=maps.aolp, scale=2 * maps.scale)
        if self.method == "imin":
            with self._lock:
                self.separations += 1
            if sink is not None:
                sink.log_layers(index, ts, diffuse=maps.diffuse, specular=maps.specular, scale=maps.scale)
        elif self.method is not None:
            with self._sep_lock:
                if self._sep_pending is not None:  # replaced by a newer frame before it started
                    self.separations_skipped += 1
                self._sep_pending = (index, view)
                self._sep_wake.notify()
        self._stats(index, ts)

    def _stats(self, index: int, ts: int | None) -> None:
        if self.sink is None:
            return
        c = self.counters
        with c.lock:
            fps, dropped, incomplete = c.fps, c.dropped, c.incomplete
        self.sink.log_stats(index, ts, fps=fps, dropped=dropped, incomplete=incomplete)

    def _run_separation(self) -> None:
        from polcam.demosaicing import demosaic
        from polcam.separation import separate

        while True:
            with self._sep_lock:
                while self._sep_pending is None and not self._closing:
                    self._sep_wake.wait()
                if self._sep_pending is None:
                    return
                index, frame = self._sep_pending
                self._sep_pending = None
            try:
                stack = np.clip(demosaic(frame, layout=self.layout, method="bilinear", resolution="cell"),
                                0.0, 1.0)
                t0 = time.perf_counter()
                res = separate(stack, method=self.method, **self.method_options)  # type: ignore[arg-type]
                dt = time.perf_counter() - t0
                self.separation_seconds.append(dt)
                self.separations += 1
                if self.sink is not None:
                    ts = frame.metadata.get("timestamp_ns")
                    self.sink.log_layers(index, ts, diffuse=res.diffuse, specular=res.specular)
                    self.sink.log_stats(index, ts, separation_seconds=dt)
            except Exception as exc:  # noqa: BLE001 - reported, live view goes on
                self.separation_errors.append(f"frame {index}: {exc}")

    def close(self, *, finish: bool = True) -> None:
        """Stop the live threads.

        With ``finish`` the newest frame still waiting (and its separation)
        is processed first; without it (a stop on request) it is counted as
        skipped.  Frames being processed are always completed.
        """
        with self._lock:
            if self._pending is not None and not finish:
                self.skipped += 1
                self._pending = None
            self._closing = True
            self._wake.notify_all()
        for t in self._threads:
            t.join()
        if self._sep_thread is not None:
            with self._sep_lock:
                if self._sep_pending is not None and not finish:
                    self.separations_skipped += 1
                    self._sep_pending = None
                self._sep_wake.notify_all()
            self._sep_thread.join()


# ---------------------------------------------------------------------------
# the capture loop
# ---------------------------------------------------------------------------

def _check_calibration(calibration: Calibration, camera: Camera) -> tuple[str | None, str | None]:
    """Refuse a calibration of another layout than the camera sends; (file, SHA-256) to record.

    The per-cell correction matrices are built here, once, so the live view
    does not wait for them on its first frame.
    """
    from polcam.calibration import CalibrationError, apply_calibration
    from polcam.process import sha256_file

    where = f"calibration {calibration.source}" if calibration.source else "the calibration"
    if camera.layout is not None and camera.layout != calibration.layout:
        raise CalibrationError(f"layout mismatch: camera {camera.camera_id} sends layout {camera.layout}, "
                               f"{where} is for {calibration.layout}")
    if calibration.has("polarizer"):
        apply_calibration(np.zeros(calibration.shape, dtype=np.uint16), calibration, check_settings=False)
    if calibration.source is None:
        return None, None
    try:
        digest = sha256_file(calibration.source)
    except OSError as exc:
        raise CalibrationError(f"cannot read the calibration file to hash it: {exc.strerror}",
                               path=calibration.source) from exc
    return str(calibration.source), digest


def _refusal(calibration: Calibration, frame: Frame, camera_id: str) -> PolcamError | None:
    """The error that stops a capture whose first frame does not fit the calibration, or ``None``."""
    from polcam.calibration import CalibrationError
    from polcam.camera.replay import as_recorded

    try:
        calibration.check_frame(as_recorded(frame))
    except CalibrationError as exc:
        return CalibrationError(f"capture from camera {camera_id} refused, nothing saved: the first frame "
                                f"does not fit the calibration: {exc}")
    return None


class StopRequest(threading.Event):
    """An event that also says why the capture should stop (``reason``)."""

    def __init__(self) -> None:
        super().__init__()
        self.reason = "stop requested"

    def request(self, reason: str) -> None:
        """Set the event, keeping the first reason given."""
        if not self.is_set():
            self.reason = reason
        self.set()


def run_capture(
    camera: Camera,
    *,
    out: Path | None,
    frames: int | None = None,
    duration: float | None = None,
    save_format: str = "raw",
    separate: str | None = "imin",
    separate_options: dict[str, Any] | None = None,
    rerun: str | Path | None = None,
    stop: threading.Event | None = None,
    abort: threading.Event | None = None,
    idle_timeout: float | None = 10.0,
    software_trigger: bool = False,
    append: bool = False,
    save_workers: int = 4,
    save_queue: int = 16,
    raw_every: int = 10,
    view_scale: float = 0.5,
    live_workers: int = 2,
    progress: Callable[[dict[str, Any]], None] | None = None,
    calibration: Calibration | None = None,
    rerun_bind: str = "127.0.0.1",
    rerun_port: int = 9090,
) -> dict[str, Any]:
    """Capture from an open, configured camera until a stop condition; return the summary.

    Parameters
    ----------
    camera
        Open and configured (not started) camera.
    out
        Folder for the frames and ``summary.json`` (created); ``None``:
        nothing is saved (live view only).
    frames, duration
        Stop after this many good frames / seconds (``None``: until the source
        ends or ``stop`` is set).
    save_format
        One of :data:`SAVE_FORMATS`.
    separate
        Separation method for the live layers, or ``None``.
    separate_options
        Keyword options of that method, checked against it before the camera
        starts (e.g. ``{"device": "cuda"}``); recorded in the summary.
    rerun
        ``"spawn"``, ``"serve"``, a ``.rrd`` path, or ``None`` (no live view).
    stop, abort
        Set ``stop`` to end the capture cleanly (signals do); set ``abort`` as
        well to drop frames still waiting to be written.
    idle_timeout
        End with an error when no frame arrives for this many seconds.
    software_trigger
        Fire the camera's software trigger for each frame (one at a time).
    append
        Allow an ``out`` folder that already holds frames (numbering continues).
    save_workers, save_queue
        Writer threads and their queue length.
    raw_every
        Log the full-resolution raw mosaic to Rerun every this many processed frames.
    view_scale
        Size factor of the maps logged to Rerun (0.5: half the polarizer-cell resolution).
    live_workers
        Threads of the live view (each processes the newest frame when free).
    progress
        Called about once a second with the running counters.
    calibration
        A calibration of this camera (:func:`polcam.calibration.load_calibration`),
        or ``None``.  The first frame is checked against it before anything
        is saved; the live view (maps and separation) is computed from the
        corrected mosaic, while the saved frames stay exactly as the camera
        sent them.
    rerun_bind, rerun_port
        ``rerun="serve"``: address and port of the web viewer (the data on
        port + 1); see :class:`polcam.sinks.rerun.WebServer`.

    Returns
    -------
    dict
        The summary (also written to ``out/summary.json``): ``frames_good``,
        ``frames_incomplete``, ``frames_dropped``, ``frames_received``,
        ``frames_saved``, ``frames_save_failed``, ``frames_unsaved``,
        ``frames_processed``, ``frames_skipped``, ``separations``,
        ``separations_skipped``, ``duration_s``, ``fps``, ``stop_reason``,
        ``files``, the camera's ``stream`` statistics, and ``calibration``
        / ``calibration_sha256`` (the calibration file and its SHA-256, as
        ``polcam process`` records them; ``None`` without one).

    Raises
    ------
    CalibrationError
        The calibration does not fit the layout the camera sends, or its
        first frame (size, layout, camera id, ROI, mirroring; with a dark,
        exposure, gain or bit depth).  The capture stops before any frame is
        saved and no summary is written (an output folder or ``.rrd`` file
        it created is removed again).
    LayoutError
        Live processing or separation requested but the frames have no layout.
    MethodError
        Unknown separation method, or a colour-only one on a mono camera.
    FrameWriteError
        ``out`` holds frames of an earlier capture (without ``append``).
    """
    from polcam.errors import FrameWriteError

    if save_format not in SAVE_FORMATS:
        raise FrameWriteError(f"save format {save_format!r}: expected one of {', '.join(SAVE_FORMATS)}")
    stop = stop or threading.Event()
    abort = abort or threading.Event()
    layout = camera.layout
    live_wanted = rerun is not None or separate is not None
    if live_wanted and layout is None:
        raise LayoutError(
            f"camera {camera.camera_id} sends frames without a known polarizer layout: give --layout "
            "(imx250mzr, imx250myr, mono:A,B,C,D, color:A,B,C,D:BAYER), or --separate none without --rerun"
        )
    if separate_options and separate is None:
        raise MethodError(f"separation options {sorted(separate_options)} given without a separation method")
    if separate is not None:
        from polcam.separation import method_spec
        from polcam.separation._registry import check_options

        if separate == "imin" and separate_options:  # computed from the live maps, not by separate()
            raise MethodError(f"the live imin layers take no options; got {sorted(separate_options)}")
        spec = method_spec(separate)
        check_options(separate, dict(separate_options or {}))
        if layout is not None and not layout.is_color and not spec.mono:
            from polcam.separation import methods

            raise MethodError(
                f"separation method {separate!r} needs a colour sensor; camera layout is {layout}; "
                f"for mono use one of {', '.join(m for m in methods() if method_spec(m).mono)} or none"
            )
    cal_file: str | None = None
    cal_sha: str | None = None
    if calibration is not None:
        cal_file, cal_sha = _check_calibration(calibration, camera)
    first_index = 0
    stale = 0
    created_out = False
    if out is not None:
        out = Path(out)
        created_out = not out.exists()
        out.mkdir(parents=True, exist_ok=True)
        stale = _clean_stale(out)
        existing = _existing_frames(out)
        if existing and not append:
            raise FrameWriteError(
                f"output folder already holds {len(existing)} captured frame(s); choose another --out "
                "or pass --append to continue the numbering", path=out,
            )
        first_index = existing[-1] + 1 if existing else 0

    counters = _Counters()
    sink = None
    new_rrd = None  # a recording file this capture creates (removed again if the calibration refuses)
    if rerun is not None and str(rerun) not in ("spawn", "serve") and not Path(rerun).exists():
        new_rrd = Path(rerun)
    if rerun is not None:  # before any thread starts: a viewer that cannot start is a plain error
        from polcam.sinks.rerun import RerunSink

        sink = RerunSink(rerun, raw_every=raw_every, view_scale=view_scale, bind=rerun_bind, port=rerun_port)
        if sink.server is not None and progress is not None:
            progress({"message": sink.server.message()})
    saver: FrameSaver | None = None
    if out is not None:
        saver = FrameSaver(out, SAVE_FORMATS[save_format], workers=save_workers, queue_frames=save_queue)
    live: LiveProcessor | None = None
    if live_wanted:
        assert layout is not None
        live = LiveProcessor(layout, sink=sink, separate=separate, separate_options=separate_options,
                             counters=counters, workers=live_workers,
                             calibration=calibration)

    received = 0
    refused: PolcamError | None = None
    reason = "running"
    error: str | None = None
    arrivals: deque[float] = deque()
    t_start = time.monotonic()
    last_frame = t_start
    last_progress = t_start
    outstanding_trigger = False
    trigger_time = 0.0
    try:
        camera.start()
        t_start = last_frame = last_progress = time.monotonic()
        while True:
            now = time.monotonic()
            if stop.is_set():
                reason = getattr(stop, "reason", "stop requested")
                break
            if frames is not None and received >= frames:
                reason = "frames"
                break
            if duration is not None and now - t_start >= duration:
                reason = "duration"
                break
            if software_trigger and (not outstanding_trigger or now - trigger_time > 1.0):
                camera.trigger()
                outstanding_trigger, trigger_time = True, now
            frame = camera.read(timeout=0.1)
            now = time.monotonic()
            if frame is None:
                if camera.exhausted:
                    reason = "end of stream"
                    break
                if idle_timeout is not None and now - last_frame > idle_timeout:
                    reason = "timeout"
                    error = (f"no frame from camera {camera.camera_id} for {idle_timeout:g} s "
                             f"(stream statistics: {camera.stats().as_dict()})")
                    break
            else:
                outstanding_trigger = False
                last_frame = now
                if calibration is not None and received == 0:
                    refused = _refusal(calibration, frame, camera.camera_id)
                    if refused is not None:  # nothing saved or shown yet
                        reason = "calibration refused"
                        break
                index = first_index + received
                received += 1
                arrivals.append(now)
                while arrivals and now - arrivals[0] > 1.0:
                    arrivals.popleft()
                if saver is not None and not saver.put(index, frame, abort=abort):
                    pass  # aborted: counted as unsaved by the saver
                if live is not None:
                    live.offer(index, frame)
            if now - last_progress >= 0.5:
                st = camera.stats()
                with counters.lock:
                    counters.fps = float(len(arrivals))
                    counters.dropped = st.dropped
                    counters.incomplete = st.incomplete
                if progress is not None and now - last_progress >= 1.0:
                    progress({"received": received, "fps": counters.fps, "dropped": st.dropped,
                              "incomplete": st.incomplete,
                              "saved": len(saver.saved) if saver else 0,
                              "processed": live.processed if live else 0})
                last_progress = now
    finally:
        t_end = time.monotonic()
        camera.stop()
        if live is not None:
            live.close(finish=not stop.is_set())
        if saver is not None:
            saver.close(abort=abort.is_set())
        if sink is not None:
            sink.close()

    if refused is not None:
        for leftover, remove in ((out if created_out else None, Path.rmdir), (new_rrd, Path.unlink)):
            if leftover is not None:
                try:
                    remove(leftover)  # the folder is empty, the recording holds no frame
                except OSError:
                    pass
        raise refused
    st = camera.stats()
    elapsed = max(t_end - t_start, 1e-9)
    if live is not None and live.error is not None:
        error = f"live processing failed: {live.error}"
    summary: dict[str, Any] = {
        "camera": camera.info,
        "stop_reason": reason,
        "error": error,
        "frames_good": st.good,
        "frames_incomplete": st.incomplete,
        "frames_dropped": st.dropped,
        "frames_received": received,
        "frames_saved": len(saver.saved) if saver else 0,
        "frames_save_failed": len(saver.failed) if saver else 0,
        "frames_unsaved": saver.unsaved if saver else 0,
        "frames_processed": live.processed if live else 0,
        "frames_skipped": live.skipped if live else 0,
        "separation": separate,
        "separation_options": dict(separate_options or {}),
        "separations": live.separations if live else 0,
        "separations_skipped": live.separations_skipped if live else 0,
        "separation_seconds_mean": (float(np.mean(live.separation_seconds))
                                    if live and live.separation_seconds else None),
        "separation_errors": live.separation_errors if live else [],
        "duration_s": elapsed,
        "fps": received / elapsed,
        "fps_processed": (live.processed / elapsed) if live else 0.0,
        "live_seconds_per_frame": (live.seconds / live.processed) if live and live.processed else None,
        "save_seconds_per_frame": (saver.seconds / len(saver.saved)) if saver and saver.saved else None,
        "by_status": st.by_status,
        "queue_overflow": st.queue_overflow,
        "stream": st.stream,
        "format": save_format if saver else None,
        "out": None if out is None else str(out),
        "rerun": None if rerun is None else str(rerun),
        "stale_temporaries_removed": stale,
        "calibration": cal_file,
        "calibration_sha256": cal_sha,
        "calibration_stages": calibration.applied_stages if calibration is not None else None,
        "save_errors": saver.failed if saver else [],
        "files": sorted(saver.saved) if saver else [],
    }
    if out is not None:
        from polcam.io.atomic import atomic_write

        with atomic_write(Path(out) / "summary.json", "w") as fh:
            json.dump(summary, fh, indent=2, default=str)
            fh.write("\n")
    return summary


# ---------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------

def add_capture_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``capture`` to an ``argparse`` sub-parser set; returns the new parser."""
    c = subparsers.add_parser(
        "capture",
        help="record a camera (or replay:DIR) losslessly with a live Rerun view",
        description="Capture raw frames from a GenICam camera through Aravis (`polcam devices` lists "
                    "them; Fake_1 is Aravis' simulated camera) or from a folder of raw frames "
                    "(--device replay:DIR). Every good frame is saved losslessly with its JSON sidecar, "
                    "atomically; the newest frame is processed live (S0, DoLP, AoLP, Imin at the "
                    "polarizer-cell resolution, and the chosen separation) and shown in Rerun; with "
                    "--calibration the live view is computed from the corrected mosaic while the saved "
                    "frames stay raw. Ctrl-C or SIGTERM stops cleanly and writes OUT/summary.json.",
    )
    c.add_argument("--device", required=True, help="camera id, serial or address, or replay:DIR")
    stop = c.add_mutually_exclusive_group()
    stop.add_argument("--frames", type=int, help="stop after N good frames")
    stop.add_argument("--duration", type=float, help="stop after S seconds")
    c.add_argument("--out", type=Path, help="output folder (default captures/<date-time>)")
    c.add_argument("--no-save", action="store_true", help="live view only: save nothing")
    c.add_argument("--format", default="raw", choices=tuple(SAVE_FORMATS),
                   help="frame files: raw (the camera's bytes, default), tiff (uncompressed), npy, "
                        "png (lossless, slow: ~90 ms a 5 MP frame)")
    c.add_argument("--append", action="store_true", help="allow an --out folder that holds frames already")
    add_camera_arguments(c)
    c.add_argument("--calibration", type=Path, metavar="FILE",
                   help="calibration file (polcam calibrate) of this camera at these settings: the first "
                        "frame is checked against it, the live view (S0, DoLP, AoLP, layers) uses the "
                        "corrected mosaic; saved frames stay raw. summary.json records the file and its SHA-256")
    c.add_argument("--separate", default="imin",
                   help="separation method for the live layers, or none (default imin: every frame; "
                        "slower methods run on the newest frame whenever the last run is done)")
    c.add_argument("--separate-option", action="append", metavar="KEY=VALUE",
                   help="an option of the --separate method, VALUE as JSON (repeatable), e.g. "
                        "--separate-option device=cuda for the tensor method on a GPU")
    c.add_argument("--rerun", help="live view: spawn (a viewer; needs a display), serve (web viewer), "
                                   "or FILE.rrd")
    c.add_argument("--raw-every", type=int, default=10,
                   help="log the full-resolution raw mosaic to Rerun every N processed frames (default 10)")
    c.add_argument("--port", type=int, default=9090,
                   help="--rerun serve: port of the web viewer (its data use port + 1; default 9090)")
    c.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                   help="--rerun serve: address to listen on (default 127.0.0.1, this machine only; "
                        "0.0.0.0: anyone on this machine's networks can watch)")
    c.add_argument("--view-scale", type=float, default=0.5,
                   help="size of the maps in the Rerun view relative to the polarizer-cell resolution "
                        "(default 0.5: 612x512 for a 5 MP sensor; 1 for full cell resolution)")
    c.add_argument("--live-workers", type=int, default=2, help="live processing threads (default 2)")
    c.add_argument("--save-workers", type=int, default=4,
                   help="writer threads (default 4: writes and fsync overlap)")
    c.add_argument("--quiet", action="store_true", help="no progress lines")
    c.set_defaults(func=cmd_capture)
    return c


def add_camera_arguments(parser: Any, *, layout: bool = True) -> None:
    """Add the camera options ``polcam capture`` and ``polcam calibrate --device`` share.

    Settings (``--pixel-format``, ``--layout``, ``--exposure``, ``--gain``,
    ``--roi``, ``--frame-rate``, ``--trigger``, ``--reverse-x``,
    ``--reverse-y``) and the connection (``--timeout``, ``--loop``,
    ``--buffers``, ``--packet-size``, ``--socket-buffer``); read them back
    with :func:`camera_options` and :func:`configure_camera`.

    Parameters
    ----------
    parser
        The command's ``argparse.ArgumentParser``, or an argument group of it.
    layout
        Add ``--layout`` too (a command that has its own leaves it out).
    """
    p = parser
    p.add_argument("--pixel-format", help="GenICam PixelFormat (`polcam formats` lists what polcam reads)")
    if layout:
        p.add_argument("--layout", help="sensor layout for plain Mono/Bayer formats (imx250mzr, imx250myr, "
                                        "mono:A,B,C,D, color:A,B,C,D:BAYER)")
    p.add_argument("--exposure", type=float, metavar="US", help="exposure time, microseconds")
    p.add_argument("--gain", type=float, metavar="DB", help="gain, dB")
    p.add_argument("--roi", type=int, nargs=4, metavar=("X", "Y", "W", "H"),
                   help="region of interest on the sensor (aligned down to whole polarizer cells)")
    p.add_argument("--frame-rate", type=float, metavar="FPS",
                   help="frame rate (replay: playback rate; default as fast as read, lossless)")
    p.add_argument("--trigger", help=f"{' | '.join(TRIGGER_MODES)} | a line (Line0, ...); default: "
                                     "as the camera is")
    p.add_argument("--reverse-x", action="store_true", default=None, help="mirror the image left-right")
    p.add_argument("--reverse-y", action="store_true", default=None, help="mirror the image top-bottom")
    p.add_argument("--timeout", type=float, default=10.0,
                   help="give up when no frame arrives for S seconds (default 10)")
    p.add_argument("--loop", action="store_true", help="replay: start over after the last file")
    p.add_argument("--buffers", type=int, default=16, help="Aravis buffer pool size (default 16)")
    p.add_argument("--packet-size", default="1500",
                   help="GigE packet size in bytes (default 1500; 8192/9000 with jumbo frames end to end; "
                        "'auto': Aravis probes the largest size the path carries)")
    p.add_argument("--socket-buffer", type=int, metavar="BYTES",
                   help="GigE receive socket buffer (default: Aravis' automatic size)")


#: Destinations of the camera settings :func:`add_camera_arguments` adds, with their flags.
CAMERA_SETTINGS: dict[str, str] = {
    "pixel_format": "--pixel-format", "exposure": "--exposure", "gain": "--gain", "roi": "--roi",
    "frame_rate": "--frame-rate", "trigger": "--trigger", "reverse_x": "--reverse-x", "reverse_y": "--reverse-y",
}


def camera_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of :func:`polcam.camera.open_camera` from the parsed camera options.

    Raises
    ------
    CameraSettingError
        A ``--packet-size`` that is neither a number nor ``auto``.
    """
    if str(args.device).startswith("replay:"):
        return {"frame_rate": args.frame_rate, "loop": args.loop}
    opts: dict[str, Any] = {"n_buffers": args.buffers}
    if args.packet_size is not None:
        size = str(args.packet_size).strip().lower()
        if size != "auto" and not size.isdigit():
            raise CameraSettingError(f"--packet-size {args.packet_size!r}: expected a number of bytes or 'auto'")
        opts["packet_size"] = "auto" if size == "auto" else int(size)
    if args.socket_buffer is not None:
        opts["socket_buffer_bytes"] = args.socket_buffer
    return opts


def configure_camera(camera: Camera, args: argparse.Namespace, *, quiet: bool = False) -> dict[str, Any]:
    """Apply the parsed camera settings to an open camera; returns what it reports.

    Settings the camera cannot change are listed in the result's ``ignored``
    and, unless ``quiet``, named in a note on stderr.

    Raises
    ------
    CameraSettingError, PixelFormatError, LayoutError
        A setting the camera refuses (the message names it and the value).
    """
    settings = camera.configure(
        pixel_format=args.pixel_format, layout=args.layout, exposure_us=args.exposure,
        gain_db=args.gain, roi=tuple(args.roi) if args.roi else None,
        frame_rate=args.frame_rate if not str(args.device).startswith("replay:") else None,
        trigger=args.trigger, reverse_x=args.reverse_x, reverse_y=args.reverse_y,
    )
    if settings.get("ignored") and not quiet:
        print(f"note: camera {camera.camera_id} cannot change {', '.join(settings['ignored'])}; ignored",
              file=sys.stderr)
    return settings


def _print_summary(summary: dict[str, Any]) -> None:
    keys = ("frames_good", "frames_incomplete", "frames_dropped", "frames_saved", "frames_processed",
            "frames_skipped", "separations")
    line = ", ".join(f"{k[7:] if k.startswith('frames_') else k} {summary[k]}" for k in keys)
    print(f"capture stopped ({summary['stop_reason']}) after {summary['duration_s']:.1f} s: {line}; "
          f"{summary['fps']:.1f} fps received, {summary['fps_processed']:.1f} fps processed")
    if summary.get("out"):
        print(f"frames and summary.json in {summary['out']}")
    if summary.get("error"):
        print(f"error: {summary['error']}", file=sys.stderr)


def cmd_capture(args: argparse.Namespace) -> int:
    """``polcam capture``: open, configure, capture, summarise.  Returns the exit status."""
    if args.frames is not None and args.frames <= 0:
        raise CameraSettingError(f"--frames {args.frames}: expected a positive number")
    if args.duration is not None and args.duration <= 0:
        raise CameraSettingError(f"--duration {args.duration}: expected a positive number of seconds")
    separate = None if str(args.separate).lower() == "none" else args.separate
    from polcam.cli import parse_option

    separate_options = dict(parse_option(o, flag="--separate-option") for o in args.separate_option or [])
    out: Path | None = None
    if not args.no_save:
        out = args.out or Path("captures") / time.strftime("%Y%m%d-%H%M%S")
    trigger = args.trigger
    stop = StopRequest()
    abort = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        if stop.is_set():
            abort.set()  # a second signal: do not wait for the frames still queued for writing
        stop.request(f"signal {signal.Signals(signum).name}")

    calibration = None
    if args.calibration is not None:  # loaded once, before the camera is touched
        from polcam.calibration import load_calibration

        calibration = load_calibration(args.calibration)
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with open_camera(args.device, **camera_options(args)) as cam:
            settings = configure_camera(cam, args, quiet=args.quiet)
            if not args.quiet:
                print(f"capturing from {cam.camera_id}: {settings.get('pixel_format')} "
                      f"layout {settings.get('layout')} -> {out if out else '(not saved)'}")
                if calibration is not None:
                    print(f"live view calibrated with {args.calibration} "
                          f"({', '.join(calibration.applied_stages) or 'no stages'}); frames saved raw")

            def progress(p: dict[str, Any]) -> None:
                if "message" in p:
                    print(p["message"], file=sys.stderr)
                    return
                print(f"  {p['received']} frames, {p['fps']:.0f} fps, saved {p['saved']}, "
                      f"processed {p['processed']}, dropped {p['dropped']}, incomplete {p['incomplete']}",
                      file=sys.stderr)

            summary = run_capture(
                cam, out=out, frames=args.frames, duration=args.duration, save_format=args.format,
                separate=separate, separate_options=separate_options, rerun=args.rerun, stop=stop,
                abort=abort, idle_timeout=args.timeout,
                software_trigger=trigger == "software", append=args.append,
                save_workers=args.save_workers, raw_every=args.raw_every, view_scale=args.view_scale,
                live_workers=args.live_workers,
                progress=None if args.quiet else progress, calibration=calibration,
                rerun_bind=args.bind, rerun_port=args.port,
            )
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    _print_summary(summary)
    if summary["error"] or summary["frames_save_failed"]:
        return 1
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m polcam.capture ...``: the capture command on its own."""
    parser = argparse.ArgumentParser(prog="polcam")
    sub = parser.add_subparsers(dest="command", required=True)
    add_capture_parser(sub)
    args = parser.parse_args(["capture", *(sys.argv[1:] if argv is None else argv)])
    from polcam.cli import run_command

    return run_command(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
