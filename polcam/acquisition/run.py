"""The capture run: a started camera's frames to the saver and the live view, until a stop condition.

Threads of a capture::

    camera acquisition thread --(bounded frame queue)--> capture loop (main thread)
        capture loop --(bounded save queue)--> saver threads: every good frame, lossless, atomic
        capture loop --(one-slot mailbox, newest wins)--> live thread: the per-frame
            pipeline's live route at cell resolution (S0, DoLP, AoLP, Imin), Rerun logging
        live thread --(one-slot mailbox)--> separation thread: the chosen method on the
            newest frame whenever the previous separation is done

Both ends are sinks (:class:`polcam.sinks.base.Sink`): the frame sinks (the
saver, and any passed as ``sinks``) are logged every frame received, on the
capture loop's thread; the live sinks (Rerun, ``Capture(live_sink=...)``) the
live view's maps, layers and statistics, on the live threads.  :class:`Capture`
closes them all once when it ends, however it ends.

Nothing the capture does blocks acquisition: the camera's own thread only
ever drops frames into its queue (a full queue drops the frame and counts
it).  Saving is lossless for every frame the capture loop takes: when the
disk falls behind, the save queue fills, the loop waits, the camera queue
fills and the camera's frames are dropped and counted, so the summary always
says what was lost.  The live view takes the newest frame whenever it is
free; frames it did not get to are counted as skipped (they are still saved).

Calibration (``run_capture(calibration=...)``): the first frame is checked
against it (size, layout, camera, ROI, mirroring, and the exposure, gain and
bit depth of its dark) before anything is saved, and a mismatch stops the
capture with a ``CalibrationError``.  The live view (maps and separation) is
computed from the corrected mosaic; the saved frames, their sidecars and the
``/camera/raw`` view stay exactly as the camera sent them.  The summary
records the calibration file and its SHA-256.

Stopping: ``frames``, ``duration``, the end of a replay folder, or ``stop``
(the command sets it on SIGINT / SIGTERM): acquisition stops, queued frames
are written, the summary is returned and written.  ``abort`` (a second
signal) abandons the frames still waiting to be written (counted as
``unsaved``).  After SIGKILL or a power cut, complete frames are on disk and
nothing else except hidden temporary files (``.frame_*``), which the next
capture into that folder removes.

Faults:

- the output folder is checked before the camera starts
  (:func:`polcam.acquisition.saving.check_writable`): one that cannot be
  created or written, or a full disk, is a ``FrameWriteError`` naming the
  folder and the reason, and nothing is captured;
- a write that fails during the capture stops it at once (``on_write_error=
  "stop"``; stop reason ``write failed: FOLDER: REASON``), or, with
  ``"continue-live"``, stops saving and keeps the live view going; either
  way every frame not written is counted (``frames_save_failed``,
  ``frames_unsaved``);
- a camera that stops answering (:class:`polcam.camera.base.CameraDisconnectedError`)
  ends the capture: the frames it delivered before are saved, the stop
  reason is ``camera disconnected: ...``;
- frames the camera delivered that the loop had not yet read when
  acquisition stopped are saved (a stop on duration, signal, disconnect),
  or, when the ``frames`` count was reached or on ``abort``, left unread and
  counted (:meth:`polcam.camera.base.Camera.unread`).  So for a live camera
  ``frames_good == frames_received + queue_overflow + frames_left_at_stop``,
  and ``frames_received == frames_saved + frames_save_failed + frames_unsaved``;
- the summary goes to ``OUT/summary.json`` (``OUT/summary-N.json`` when an
  earlier capture's summary is there: ``--append`` never overwrites it), or,
  when the folder cannot take it, to the temporary folder or the current
  folder (``summary_file`` says where; ``None`` when nowhere could).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from polcam._hashing import sha256_file
from polcam.acquisition.live import Counters, LiveProcessor
from polcam.acquisition.options import ON_WRITE_ERROR, CaptureOptions, StopRequest
from polcam.acquisition.saving import (
    SAVE_FORMATS,
    FrameSaver,
    check_writable,
    clean_stale,
    existing_frames,
)
from polcam.acquisition.summary import summarize, write_summary
from polcam.calibration import CalibrationError, apply_calibration
from polcam.camera.base import Camera, CameraDisconnectedError, CapturedFrame, FrameTimeout
from polcam.camera.replay import as_recorded
from polcam.errors import FrameWriteError, LayoutError, MethodError, PolcamError
from polcam.frame import Frame
from polcam.separation import layout_form, resolve_separation
from polcam.sinks.base import FanOut, Record, Sink
from polcam.sinks.rerun import RerunSink

if TYPE_CHECKING:
    from polcam.calibration.store import Calibration
    from polcam.separation import ResolvedSeparation

__all__ = ["ON_WRITE_ERROR", "Capture", "CaptureOptions", "StopRequest", "run_capture", "write_summary"]


def _check_calibration(calibration: Calibration, camera: Camera) -> tuple[str | None, str | None]:
    """Refuse a calibration of another layout than the camera sends; (file, SHA-256) to record.

    The per-cell correction matrices are built here, once, so the live view
    does not wait for them on its first frame.
    """
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
    try:
        calibration.check_frame(as_recorded(frame))
    except CalibrationError as exc:
        return CalibrationError(f"capture from camera {camera_id} refused, nothing saved: the first frame "
                                f"does not fit the calibration: {exc}")
    return None


class Capture:
    """One capture run: :meth:`prepare` (checks, sinks), :meth:`loop` (frames), :meth:`summary`.

    :meth:`run` does all three and writes the summary; :func:`run_capture` is
    the same as one call.  The capture owns its sinks: the frame sinks (the
    :class:`polcam.acquisition.saving.FrameSaver` of ``options.out`` and
    ``sinks``) get every frame received, the live sink (a
    :class:`polcam.sinks.rerun.RerunSink` for ``options.rerun``, or ``live_sink``)
    the live view's maps, layers and statistics; all are closed once when
    the capture ends, however it ends.

    Parameters
    ----------
    camera
        Open and configured (not started) camera.
    options
        What to do (:class:`CaptureOptions`).
    stop, abort
        Set ``stop`` to end the capture cleanly (signals do); set ``abort`` as
        well to drop frames still waiting to be written.
    progress
        Called about once a second with the running counters, and with
        ``{"message": ...}`` for notices and errors.
    calibration
        A calibration of this camera (:func:`polcam.calibration.load_calibration`),
        or ``None``.  The first frame is checked against it before anything
        is saved; the live view (maps and separation) is computed from the
        corrected mosaic, while the saved frames stay exactly as the camera
        sent them.
    sinks
        More sinks (:class:`polcam.sinks.base.Sink`) that get every frame
        received, as a :class:`polcam.sinks.base.Record` with ``frame`` and
        ``timestamp_ns``, at its capture index, from the capture's thread.
    live_sink
        A sink for the live view besides (or instead of) ``options.rerun``'s.
    """

    def __init__(self, camera: Camera, options: CaptureOptions, *, stop: threading.Event | None = None,
                 abort: threading.Event | None = None, progress: Callable[[dict[str, Any]], None] | None = None,
                 calibration: Calibration | None = None, sinks: Sequence[Sink] = (),
                 live_sink: Sink | None = None) -> None:
        self.camera = camera
        self.options = options
        self.stop = stop or threading.Event()
        self.abort = abort or threading.Event()
        self.progress = progress
        self.calibration = calibration
        self.separate = options.separate
        self.separate_options = dict(options.separate_options or {})
        #: The live separation, resolved once for the camera's layout (:meth:`_resolve_separation`), or None.
        self.separation: ResolvedSeparation | None = None
        self.out = None if options.out is None else Path(options.out)
        self.frame_sinks = FanOut(sinks)
        self.live_sinks = FanOut([live_sink])
        self.saver: FrameSaver | None = None
        self.live: LiveProcessor | None = None
        self.counters = Counters()
        self.cal_file: str | None = None
        self.cal_sha: str | None = None
        self.first_index = 0
        self.stale = 0
        self.created_out = False
        self.new_rrd: Path | None = None  # a recording this capture creates (removed if the calibration refuses)
        self.received = 0
        self.refused: PolcamError | None = None
        self.reason = "running"
        self.error: str | None = None
        self.t_start = self.t_end = time.monotonic()
        self._arrivals: deque[float] = deque()
        self._save_failed_seen = False
        self._closed = False

    # ------------------------------------------------------------- prepare
    def prepare(self) -> None:
        """Check everything before the camera starts; create the saver, the live view and the sinks.

        Raises
        ------
        CalibrationError, LayoutError, MethodError, FrameWriteError
            As :func:`run_capture`; nothing is captured.
        """
        opts = self.options
        if opts.save_format not in SAVE_FORMATS:
            raise FrameWriteError(f"save format {opts.save_format!r}: expected one of {', '.join(SAVE_FORMATS)}")
        if opts.on_write_error not in ON_WRITE_ERROR:
            raise FrameWriteError(f"on_write_error {opts.on_write_error!r}: expected one of "
                                  f"{', '.join(ON_WRITE_ERROR)}")
        self._resolve_separation()
        if self.calibration is not None:
            self.cal_file, self.cal_sha = _check_calibration(self.calibration, self.camera)
        if self.out is not None:
            self._prepare_out()
        self._open_sinks()

    def _resolve_separation(self) -> None:
        """The live separation method (``"default"`` resolved) and its options, checked."""
        layout = self.camera.layout
        separate, separate_options = self.separate, self.separate_options
        if separate == "default" and layout is None and self.options.rerun is None:
            # frames of an unknown layout are still saved as sent (process can be given --layout);
            # only an explicit --separate METHOD or --rerun needs the layout now
            separate = None
            self._say(f"camera {self.camera.camera_id}: polarizer layout unknown, so no live layers "
                      "(give --layout for them); the frames are saved as sent")
        if self._live_wanted(separate) and layout is None:
            raise LayoutError(
                f"camera {self.camera.camera_id} sends frames without a known polarizer layout: give --layout "
                "(imx250mzr, imx250myr, mono:A,B,C,D, color:A,B,C,D:BAYER), or --separate none without --rerun"
            )
        if separate_options and separate is None:
            raise MethodError(f"separation options {sorted(separate_options)} given without a separation method")
        if separate is not None and layout is not None:  # resolved once for the sensor ("default": the registry's)
            if separate == "imin" and separate_options:  # computed from the live maps, not by separate()
                raise MethodError(f"the live imin layers take no options; got {sorted(separate_options)}")
            self.separation = resolve_separation(None if separate == "default" else separate, layout_form(layout),
                                                 separate_options, got=f"a camera of the mono layout {layout}")
            separate = self.separation.method
        self.separate = separate

    def _live_wanted(self, separate: str | None) -> bool:
        return self.options.rerun is not None or bool(self.live_sinks) or separate is not None

    def _prepare_out(self) -> None:
        """Before the camera starts: a folder that cannot take frames is refused now."""
        out = self.out
        assert out is not None
        self.created_out = not out.exists()
        check_writable(out)
        self.stale = clean_stale(out)
        existing = existing_frames(out)
        if existing and not self.options.append:
            raise FrameWriteError(
                f"output folder already holds {len(existing)} captured frame(s); choose another --out "
                "or pass --append to continue the numbering", path=out,
            )
        self.first_index = existing[-1] + 1 if existing else 0

    def _open_sinks(self) -> None:
        """The Rerun sink (before any thread starts: a viewer that cannot start is a plain error), the
        saver and the live view."""
        opts = self.options
        rerun = opts.rerun
        if rerun is not None:
            if str(rerun) not in ("spawn", "serve") and not Path(rerun).exists():
                self.new_rrd = Path(rerun)
            sink = RerunSink(rerun, raw_every=opts.raw_every, view_scale=opts.view_scale, bind=opts.rerun_bind,
                             port=opts.rerun_port)
            self.live_sinks.sinks.insert(0, sink)
            if sink.server is not None:
                self._say(sink.server.message())
        if self.out is not None:
            self.saver = FrameSaver(self.out, SAVE_FORMATS[opts.save_format], workers=opts.save_workers,
                                    queue_frames=opts.save_queue, abort=self.abort)
            self.frame_sinks.sinks.insert(0, self.saver)
        if self._live_wanted(self.separate):
            layout = self.camera.layout
            assert layout is not None
            self.live = LiveProcessor(layout, sink=self.live_sinks if self.live_sinks else None,
                                      separate=self.separation, separate_options=None,
                                      counters=self.counters, workers=opts.live_workers,
                                      calibration=self.calibration, hold_illuminant=opts.hold_illuminant)

    def _say(self, message: str) -> None:
        if self.progress is not None:
            self.progress({"message": message})

    # ---------------------------------------------------------------- loop
    def loop(self) -> None:
        """Start the camera, hand its frames on until a stop condition, stop it; close the sinks.

        Sets :attr:`reason` (the stop reason), :attr:`error`, :attr:`refused`
        (a calibration refusal) and the counts the summary reports.
        """
        reads = None
        loop_done = False
        try:
            self.camera.start()
            self.t_start = last_progress = last_stats = time.monotonic()
            reads = self.camera.poll_frames(poll=0.1, idle_timeout=self.options.idle_timeout,
                                            software_trigger=self.options.software_trigger)
            while self._stop_reason() is None:
                frame = self._next(reads)
                if self.reason != "running":
                    break
                now = time.monotonic()
                if frame is not None and not self._take(frame, now):
                    break
                if now - last_stats >= 0.5:  # the live view's statistics plots
                    self._count_stats()
                    last_stats = now
                if self.progress is not None and now - last_progress >= 1.0:
                    self._report(now)
                    last_progress = now
            loop_done = True
        finally:
            self.t_end = time.monotonic()
            if reads is not None:
                reads.close()
            self.camera.stop()
            try:
                if loop_done:
                    self._take_leftovers()
            finally:
                self._close()

    def _stop_reason(self) -> str | None:
        """Why the loop stops before the next read (also set as :attr:`reason`), or ``None``."""
        opts = self.options
        if self.reason != "running":
            return self.reason
        if self._write_failed():
            return self.reason
        if self.stop.is_set():
            self.reason = getattr(self.stop, "reason", "stop requested")
        elif opts.frames is not None and self.received >= opts.frames:
            self.reason = "frames"
        elif opts.duration is not None and time.monotonic() - self.t_start >= opts.duration:
            self.reason = "duration"
        return None if self.reason == "running" else self.reason

    def _write_failed(self) -> bool:
        """React once to the saver's first failed write; True when that stops the capture."""
        saver = self.saver
        if saver is None or not saver.failed_event.is_set() or self._save_failed_seen:
            return False
        self._save_failed_seen = True
        werr = saver.write_error or {}
        why = werr.get("reason", "unknown reason")
        what = f"writing frames to {self.out} failed: {why}"
        if self.options.on_write_error == "stop":
            self.reason = f"write failed: {self.out}: {why}"
            self.error = f"{what} (frame {werr.get('file')}); capture stopped"
            self._say(f"{what}; stopping the capture")
            return True
        self.error = f"{what} (frame {werr.get('file')}); saving stopped, live view went on"
        self._say(f"{what}; frames are no longer saved, the live view goes on")
        return False

    def _next(self, reads: Iterator[CapturedFrame | None]) -> CapturedFrame | None:
        """The next frame, or ``None`` after an empty wait; at the end of the stream or a fault
        sets :attr:`reason` (and :attr:`error`)."""
        try:
            return next(reads)
        except StopIteration:
            self.reason = "end of stream"
        except FrameTimeout as exc:
            self.reason = "timeout"
            self.error = str(exc)
        except CameraDisconnectedError as exc:
            self.reason = f"camera disconnected: {self.camera.lost or exc}"
            self.error = str(exc)
            self._say(f"{exc}; stopping the capture")
        return None

    def _take(self, frame: CapturedFrame, now: float) -> bool:
        """Hand a received frame to the frame sinks and the live view; False when the calibration
        refuses the first one (nothing saved or shown yet)."""
        if self.calibration is not None and self.received == 0:
            self.refused = _refusal(self.calibration, frame, self.camera.camera_id)
            if self.refused is not None:
                self.reason = "calibration refused"
                return False
        index = self._log_frame(frame)
        arrivals = self._arrivals
        arrivals.append(now)
        while arrivals and now - arrivals[0] > 1.0:
            arrivals.popleft()
        if self.live is not None:
            self.live.offer(index, frame)
        return True

    def _log_frame(self, frame: CapturedFrame) -> int:
        """Number a received frame and log it to the frame sinks (the saver waits for room; a frame it
        cannot take is counted unsaved); returns its index."""
        index = self.first_index + self.received
        self.received += 1
        if self.frame_sinks:
            self.frame_sinks.log(index, Record(frame=frame, timestamp_ns=frame.metadata.get("timestamp_ns")))
        return index

    def _count_stats(self) -> None:
        st = self.camera.stats()
        with self.counters.lock:
            self.counters.fps = float(len(self._arrivals))
            self.counters.dropped = st.dropped
            self.counters.incomplete = st.incomplete

    def _report(self, now: float) -> None:
        assert self.progress is not None
        arrivals = self._arrivals
        while arrivals and now - arrivals[0] > 1.0:
            arrivals.popleft()
        st = self.camera.stats()
        self.progress({"received": self.received, "fps": float(len(arrivals)), "dropped": st.dropped,
                       "incomplete": st.incomplete, "saved": len(self.saver.saved) if self.saver else 0,
                       "processed": self.live.processed if self.live else 0})

    def _take_leftovers(self) -> None:
        """Frames delivered before acquisition stopped, not yet read: logged, or counted unread
        (the ``frames`` count reached, ``abort``, a calibration refusal)."""
        left = self.camera.take_queued()
        if left and self.refused is None and self.reason != "frames" and not self.abort.is_set():
            for frame in left:
                self._log_frame(frame)
        else:
            self.camera.unread(len(left))

    def _close(self) -> None:
        """Stop the live view, then close the frame sinks and the live sinks (once, each even when
        another fails)."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.live is not None:  # the newest frame finished on a planned end; on a stop or a fault, not waited for
                self.live.close(finish=not self.stop.is_set()
                                and self.reason in ("frames", "duration", "end of stream"))
        finally:
            try:
                self.frame_sinks.close()
            finally:
                self.live_sinks.close()

    # ------------------------------------------------------------- summary
    def summary(self) -> dict[str, Any]:
        """The capture's summary (the keys :func:`run_capture` lists, :func:`polcam.acquisition.summary.summarize`);
        not written anywhere."""
        return summarize(self)

    # ----------------------------------------------------------------- run
    def run(self) -> dict[str, Any]:
        """:meth:`prepare`, :meth:`loop`, :meth:`summary`; the summary written to ``out``.

        Raises
        ------
        CalibrationError
            The first frame does not fit the calibration: nothing was saved,
            no summary is written, and an output folder or ``.rrd`` file this
            capture created is removed again.
        """
        try:
            self.prepare()
            self.loop()
        finally:
            self._close()
        if self.refused is not None:
            for leftover, remove in ((self.out if self.created_out else None, Path.rmdir),
                                     (self.new_rrd, Path.unlink)):
                if leftover is not None:
                    with contextlib.suppress(OSError):
                        remove(leftover)  # the folder is empty, the recording holds no frame
            raise self.refused
        summary = self.summary()
        if self.out is not None:
            write_summary(summary, self.out)
        return summary


def run_capture(camera: Camera, *, out: Path | None, stop: threading.Event | None = None,
                abort: threading.Event | None = None, progress: Callable[[dict[str, Any]], None] | None = None,
                calibration: Calibration | None = None, sinks: Sequence[Sink] = (),
                **options: Any) -> dict[str, Any]:
    """Capture from an open, configured camera until a stop condition; return the summary.

    ``Capture(camera, CaptureOptions(out=out, **options), ...).run()``.

    Parameters
    ----------
    camera
        Open and configured (not started) camera.
    out
        Folder for the frames and ``summary.json`` (created); ``None``:
        nothing is saved (live view only).
    stop, abort, progress, calibration, sinks
        As :class:`Capture`.
    **options
        The other fields of :class:`CaptureOptions` (``frames``, ``duration``,
        ``save_format``, ``separate``, ``separate_options``, ``rerun``,
        ``idle_timeout``, ``software_trigger``, ``append``, ``save_workers``,
        ``save_queue``, ``raw_every``, ``view_scale``, ``live_workers``,
        ``rerun_bind``, ``rerun_port``, ``hold_illuminant``, ``on_write_error``).

    Returns
    -------
    dict
        The summary (also written to ``out/summary.json``): ``frames_good``,
        ``frames_incomplete``, ``frames_dropped``, ``frames_received``,
        ``frames_saved``, ``frames_save_failed``, ``frames_unsaved``,
        ``frames_left_at_stop``, ``frames_processed``, ``frames_skipped``, ``separations``,
        ``separations_skipped``, ``separation_illuminant_held``, ``duration_s``, ``fps``, ``maps_frames``,
        ``maps_fps``, ``layers_frames``, ``layers_fps`` (frames whose maps were computed, frames
        separated, and each per second over ``duration_s``), ``stop_reason``,
        ``files``, ``write_error``, ``summary_file`` (where the summary was
        written; see above), the camera's ``stream`` statistics, and
        ``calibration`` / ``calibration_sha256`` (the calibration file and its
        SHA-256, as ``polcam process`` records them; ``None`` without one).

    Raises
    ------
    TypeError
        A keyword that is not a field of :class:`CaptureOptions`.
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
        ``out`` holds frames of an earlier capture (without ``append``), or
        cannot be created or written (read-only, permissions, a full disk):
        checked before the camera starts, nothing is captured.
    """
    capture = Capture(camera, CaptureOptions(out=out, **options), stop=stop, abort=abort, progress=progress,
                      calibration=calibration, sinks=sinks)
    return capture.run()
