"""The capture run: a started camera's frames to the saver and the live view, until a stop condition.

Threads of a capture::

    camera acquisition thread --(bounded frame queue)--> capture loop (main thread)
        capture loop --(bounded save queue)--> saver threads: every good frame, lossless, atomic
        capture loop --(one-slot mailbox, newest wins)--> live thread: the per-frame
            pipeline's live route at cell resolution (S0, DoLP, AoLP, Imin), Rerun logging
        live thread --(one-slot mailbox)--> separation thread: the chosen method on the
            newest frame whenever the previous separation is done

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

import json
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from polcam._hashing import sha256_file
from polcam.acquisition.live import Counters, LiveProcessor
from polcam.acquisition.saving import (
    SAVE_FORMATS,
    FrameSaver,
    check_writable,
    clean_stale,
    existing_frames,
    os_reason,
)
from polcam.camera.base import Camera, CameraDisconnectedError, FrameTimeout
from polcam.errors import LayoutError, MethodError, PolcamError
from polcam.frame import Frame

if TYPE_CHECKING:
    from polcam.calibration.store import Calibration

__all__ = ["ON_WRITE_ERROR", "StopRequest", "run_capture", "write_summary"]

#: What a capture does when a frame cannot be written: stop, or go on with the live view only.
ON_WRITE_ERROR: tuple[str, ...] = ("stop", "continue-live")

def _check_calibration(calibration: Calibration, camera: Camera) -> tuple[str | None, str | None]:
    """Refuse a calibration of another layout than the camera sends; (file, SHA-256) to record.

    The per-cell correction matrices are built here, once, so the live view
    does not wait for them on its first frame.
    """
    from polcam.calibration import CalibrationError, apply_calibration

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
    hold_illuminant: bool = True,
    on_write_error: str = "stop",
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
        Separation method for the live layers, ``"default"`` (the registry's
        default for the camera's layout, :func:`polcam.separation.default_method`)
        or ``None``.
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
    hold_illuminant
        Estimate the illuminant on the first separated frame and keep it for the later ones, for
        a method that estimates it and was given none
        (:class:`polcam.acquisition.live.LiveProcessor`); recorded as
        ``separation_illuminant_held``.  ``False``: estimate on every frame.
    on_write_error
        ``"stop"``: a failed frame write stops the capture at once (stop
        reason ``write failed: FOLDER: REASON``); ``"continue-live"``: saving
        stops (later frames counted ``frames_unsaved``) and the capture and
        its live view go on.  Either way ``write_error`` records the first
        failure and ``progress`` gets a message naming the folder and reason.

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
    from polcam.errors import FrameWriteError

    if save_format not in SAVE_FORMATS:
        raise FrameWriteError(f"save format {save_format!r}: expected one of {', '.join(SAVE_FORMATS)}")
    if on_write_error not in ON_WRITE_ERROR:
        raise FrameWriteError(f"on_write_error {on_write_error!r}: expected one of {', '.join(ON_WRITE_ERROR)}")
    stop = stop or threading.Event()
    abort = abort or threading.Event()
    layout = camera.layout
    if separate == "default" and layout is None and rerun is None:
        # frames of an unknown layout are still saved as sent (process can be given --layout);
        # only an explicit --separate METHOD or --rerun needs the layout now
        separate = None
        if progress is not None:
            progress({"message": f"camera {camera.camera_id}: polarizer layout unknown, so no live layers "
                                 "(give --layout for them); the frames are saved as sent"})
    live_wanted = rerun is not None or separate is not None
    if live_wanted and layout is None:
        raise LayoutError(
            f"camera {camera.camera_id} sends frames without a known polarizer layout: give --layout "
            "(imx250mzr, imx250myr, mono:A,B,C,D, color:A,B,C,D:BAYER), or --separate none without --rerun"
        )
    if separate_options and separate is None:
        raise MethodError(f"separation options {sorted(separate_options)} given without a separation method")
    separation = None
    if separate is not None and layout is not None:  # resolved once for the sensor ("default": the registry's)
        from polcam.separation import layout_form, resolve_separation

        if separate == "imin" and separate_options:  # computed from the live maps, not by separate()
            raise MethodError(f"the live imin layers take no options; got {sorted(separate_options)}")
        separation = resolve_separation(None if separate == "default" else separate, layout_form(layout),
                                        separate_options, got=f"a camera of the mono layout {layout}")
        separate = separation.method
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
        check_writable(out)  # before the camera starts: a folder that cannot take frames is refused now
        stale = clean_stale(out)
        existing = existing_frames(out)
        if existing and not append:
            raise FrameWriteError(
                f"output folder already holds {len(existing)} captured frame(s); choose another --out "
                "or pass --append to continue the numbering", path=out,
            )
        first_index = existing[-1] + 1 if existing else 0

    counters = Counters()
    sink = None
    new_rrd = None  # a recording file this capture creates (removed again if the calibration refuses)
    if rerun is not None and str(rerun) not in ("spawn", "serve") and not Path(rerun).exists():
        new_rrd = Path(rerun)
    if rerun is not None:  # RERUN SINK created; before any thread starts: a viewer that cannot start is a plain error
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
        live = LiveProcessor(layout, sink=sink, separate=separation, separate_options=None,
                             counters=counters, workers=live_workers,
                             calibration=calibration, hold_illuminant=hold_illuminant)

    received = 0
    refused: PolcamError | None = None
    reason = "running"
    error: str | None = None
    arrivals: deque[float] = deque()
    t_start = time.monotonic()
    last_progress = last_stats = t_start
    reads = None
    loop_done = False
    save_failed_seen = False
    try:
        camera.start()
        t_start = last_progress = last_stats = time.monotonic()
        reads = camera.poll_frames(poll=0.1, idle_timeout=idle_timeout, software_trigger=software_trigger)
        while True:
            now = time.monotonic()
            if saver is not None and saver.failed_event.is_set() and not save_failed_seen:
                save_failed_seen = True
                werr = saver.write_error or {}
                what = f"writing frames to {out} failed: {werr.get('reason', 'unknown reason')}"
                if on_write_error == "stop":
                    reason = f"write failed: {out}: {werr.get('reason', 'unknown reason')}"
                    error = f"{what} (frame {werr.get('file')}); capture stopped"
                    if progress is not None:
                        progress({"message": f"{what}; stopping the capture"})
                    break
                error = f"{what} (frame {werr.get('file')}); saving stopped, live view went on"
                if progress is not None:
                    progress({"message": f"{what}; frames are no longer saved, the live view goes on"})
            if stop.is_set():
                reason = getattr(stop, "reason", "stop requested")
                break
            if frames is not None and received >= frames:
                reason = "frames"
                break
            if duration is not None and now - t_start >= duration:
                reason = "duration"
                break
            try:
                frame = next(reads)
            except StopIteration:
                reason = "end of stream"
                break
            except FrameTimeout as exc:
                reason = "timeout"
                error = str(exc)
                break
            except CameraDisconnectedError as exc:
                reason = f"camera disconnected: {camera.lost or exc}"
                error = str(exc)
                if progress is not None:
                    progress({"message": f"{exc}; stopping the capture"})
                break
            now = time.monotonic()
            if frame is not None:
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
            if now - last_stats >= 0.5:  # the live view's statistics plots
                st = camera.stats()
                with counters.lock:
                    counters.fps = float(len(arrivals))
                    counters.dropped = st.dropped
                    counters.incomplete = st.incomplete
                last_stats = now
            if progress is not None and now - last_progress >= 1.0:
                while arrivals and now - arrivals[0] > 1.0:
                    arrivals.popleft()
                st = camera.stats()
                progress({"received": received, "fps": float(len(arrivals)), "dropped": st.dropped,
                          "incomplete": st.incomplete,
                          "saved": len(saver.saved) if saver else 0,
                          "processed": live.processed if live else 0})
                last_progress = now
        loop_done = True
    finally:
        t_end = time.monotonic()
        if reads is not None:
            reads.close()
        camera.stop()
        if loop_done:  # frames delivered before acquisition stopped, not yet read
            left = camera.take_queued()
            if left and refused is None and reason != "frames" and not abort.is_set():
                for frame in left:
                    index = first_index + received
                    received += 1
                    if saver is not None:
                        saver.put(index, frame, abort=abort)
            else:
                camera.unread(len(left))
        if live is not None:  # the newest frame finished on a planned end; on a stop or a fault, not waited for
            live.close(finish=not stop.is_set() and reason in ("frames", "duration", "end of stream"))
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
        "frames_left_at_stop": st.left_at_stop,
        "frames_processed": live.processed if live else 0,
        "frames_skipped": live.skipped if live else 0,
        "separation": separate,
        "separation_options": dict(separate_options or {}),
        "separation_illuminant_held": live.held_illuminant if live else None,
        "separations": live.separations if live else 0,
        "separations_skipped": live.separations_skipped if live else 0,
        "separation_seconds_mean": (float(np.mean(live.separation_seconds))
                                    if live and live.separation_seconds else None),
        "separation_errors": list(live.separation_errors) if live else [],
        "separation_abandoned": live.separation_abandoned if live else False,
        "duration_s": elapsed,
        "fps": received / elapsed,
        "fps_processed": (live.processed / elapsed) if live else 0.0,
        # the two live rates over the capture: maps computed (and logged), frames separated
        "maps_frames": live.processed if live else 0,
        "maps_fps": (live.processed / elapsed) if live else 0.0,
        "layers_frames": live.separations if live else 0,
        "layers_fps": (live.separations / elapsed) if live else 0.0,
        "live_seconds_per_frame": (live.seconds / live.processed) if live and live.processed else None,
        "save_seconds_per_frame": (saver.seconds / len(saver.saved)) if saver and saver.saved else None,
        "by_status": st.by_status,
        "queue_overflow": st.queue_overflow,
        "on_write_error": on_write_error,
        "write_error": saver.write_error if saver else None,
        # seconds from the first failed write to the end of acquisition
        "write_error_to_stop_s": (max(0.0, t_end - saver.failed_at)
                                  if saver is not None and saver.failed_at is not None else None),
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
        "summary_file": None,
        "summary_error": None,
    }
    if out is not None:
        write_summary(summary, out)
    return summary


def _summary_target(out: Path) -> Path:
    """``out/summary.json``, or ``out/summary-N.json`` (N = 2, 3, ...) when earlier captures left theirs."""
    first = out / "summary.json"
    if not first.exists():
        return first
    n = 2
    while (out / f"summary-{n}.json").exists():
        n += 1
    return out / f"summary-{n}.json"


def write_summary(summary: dict[str, Any], out: Path) -> Path | None:
    """Write a capture's summary where it can go; record where in ``summary_file``.

    Tried in order: the output folder (``summary.json``, or ``summary-N.json``
    beside an earlier capture's), the temporary folder (``$TMPDIR``), the
    current folder (``polcam-capture-summary-<time>-<pid>.json``).  The reason
    the output folder refused it goes to ``summary_error``.

    Returns
    -------
    pathlib.Path or None
        The file written, or ``None`` when no place took it (the caller
        prints the counts).
    """
    import os
    import tempfile

    from polcam.io.atomic import atomic_write

    stamp = f"polcam-capture-summary-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.json"
    targets = [_summary_target(Path(out)), Path(tempfile.gettempdir()) / stamp, Path.cwd() / stamp]
    for target in targets:
        summary["summary_file"] = str(target)
        try:
            with atomic_write(target, "w") as fh:
                json.dump(summary, fh, indent=2, default=str)
                fh.write("\n")
        except (PolcamError, OSError) as exc:
            if summary.get("summary_error") is None:
                summary["summary_error"] = f"cannot write {target}: {os_reason(exc)}"
            continue
        return target
    summary["summary_file"] = None
    return None
