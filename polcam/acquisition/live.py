"""Live processing of a capture: the newest frame whenever the previous one is done.

The live thread computes the polarizer-cell maps through the per-frame
pipeline's fast route (:func:`polcam.pipeline.live_maps`: S0/2, DoLP, AoLP,
the ``imin`` layers) from the (calibrated) mosaic; other separation methods
run on their own thread through the pipeline's full route
(:func:`polcam.pipeline.to_stack` at cell resolution, then
:func:`polcam.pipeline.separate_layers`) on the newest frame whenever the
previous run is done.  Results go to a sink (:class:`polcam.sinks.base.Sink`,
e.g. :class:`polcam.sinks.rerun.RerunSink`) as :class:`polcam.sinks.base.Record`
objects: per processed frame one with the raw ``frame`` and the ``s0``,
``dolp``, ``aolp`` products (the ``imin`` layers too), one per separation with
``diffuse`` and ``specular``, and ``stats`` records for the live plots.
"""

from __future__ import annotations

import signal
import threading
import time
from collections import deque
from typing import TYPE_CHECKING, Any

from polcam import parallel
from polcam.camera.replay import as_recorded
from polcam.demosaicing import resolve_demosaic
from polcam.frame import Frame
from polcam.mosaic import Layout
from polcam.pipeline import calibrate, live_maps, separate_layers, to_stack
from polcam.separation import ResolvedSeparation, estimated_illuminant, layout_form, resolve_separation
from polcam.sinks.base import Record, Sink

if TYPE_CHECKING:
    from polcam.calibration.store import Calibration

__all__ = ["MAPS_FPS_WITH_LAYERS", "Counters", "LiveProcessor"]

#: Niceness added to the separation thread (and the threads it starts) on Linux: the maps of every
#: frame come first, the layers take the CPU left over.  With wen21 beside the maps of 5 MP colour
#: frames on a loaded 2-core machine the maps ran at 7-8 fps without it, 10-18 fps with it
#: (docs/benchmarks.md, "Live rates").
SEPARATION_NICENESS = 10

#: With a separation on its own thread (any method but ``imin``), the maps start at most this many
#: frames a second.  The maps of a 5 MP colour frame and their logging take about 35 ms of CPU
#: (``live_maps`` and the sink), so a camera or a replay faster than this would otherwise keep
#: the cores of a 2-core machine on the maps and leave the lower-priority separation little;
#: 25 keeps the maps above their 20 fps target (docs/benchmarks.md, "Live rates").
MAPS_FPS_WITH_LAYERS = 25.0

#: Seconds over which the live rates plotted at ``/stats/maps_fps`` and ``/stats/layers_fps`` are counted.
RATE_WINDOW_S = 5.0


class _Rate:
    """Events per second over the last ``window`` seconds (fewer at the start of the capture)."""

    def __init__(self, window: float = RATE_WINDOW_S) -> None:
        self.window = float(window)
        self.start = time.monotonic()
        self._times: deque[float] = deque()

    def tick(self) -> float:
        """Record one event now; return the rate."""
        now = time.monotonic()
        self._times.append(now)
        return self.rate(now)

    def rate(self, now: float | None = None) -> float:
        """Events per second over the last ``window`` seconds, as of ``now``."""
        now = time.monotonic() if now is None else now
        while self._times and now - self._times[0] > self.window:
            self._times.popleft()
        span = min(self.window, now - self.start)
        return len(self._times) / span if span > 0 else 0.0


class Counters:
    """Numbers the capture loop shares with the live thread (for the statistics plots)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.fps = 0.0
        self.dropped = 0
        self.incomplete = 0


def _start_workers_deaf_to_ctrl_c(separation: ResolvedSeparation) -> int | None:
    """Start the fork server of a method that runs worker processes, with SIGINT ignored.

    A terminal's Ctrl-C reaches the whole process group.  The capture turns it
    into a clean stop; the method's worker processes must not die of it mid-frame
    with a traceback.  An ignored signal stays ignored across ``exec``, and the
    fork server hands that on to every worker it forks.  Only the main thread
    can change a signal's handler: from another thread the workers start as
    they would anyway.  Returns the fork server's process id when it was started here.
    """
    if "workers" not in (separation.spec.options or ()) or parallel.start_method() != "forkserver":
        return None
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        parallel.start_workers()
    finally:
        signal.signal(signal.SIGINT, previous)
    from multiprocessing import forkserver

    return getattr(forkserver._forkserver, "_forkserver_pid", None)


def _stop_fork_server(pid: int) -> int:
    """SIGTERM a fork server and its children, its workers (Linux ``/proc``); returns how many.

    The server goes first, so no new worker is forked meanwhile; the next pool starts a new one.
    """
    import os

    try:
        with open(f"/proc/{pid}/task/{pid}/children", encoding="ascii") as fh:
            children = [int(c) for c in fh.read().split()]
    except (OSError, ValueError):
        children = []
    n = 0
    for target in (pid, *children):
        try:
            os.kill(target, signal.SIGTERM)
            n += 1
        except OSError:
            pass
    return n


def _lower_priority(niceness: int) -> None:
    """Add ``niceness`` to the calling thread's (Linux: each thread has its own; threads it starts
    inherit it).  Elsewhere ``setpriority`` would take the thread id for a process id: nothing is done."""
    import os
    import sys

    if not sys.platform.startswith("linux") or niceness <= 0:
        return
    tid = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + int(niceness)))
    except OSError:
        pass  # not permitted here: the separation runs at the capture's priority


class LiveProcessor:
    """Process the newest frame whenever the previous one is done.

    Parameters
    ----------
    layout
        Layout of the frames (the camera's delivered layout).
    sink
        Where the live results go (:class:`polcam.sinks.base.Sink`, e.g. a
        :class:`polcam.sinks.rerun.RerunSink`), or ``None``.  It is logged
        to from the live and separation threads; the caller closes it.
    separate
        Separation method for the diffuse/specular layers (a name, or a
        :class:`~polcam.separation.ResolvedSeparation` for the layout's form as
        :func:`~polcam.acquisition.run_capture` resolves it), or ``None``.
        ``imin`` is computed on the live thread from the live maps (every
        processed frame); other methods run on their own thread on the
        polarizer-cell stack of the newest frame (``polcam.demosaic``
        bilinear, clipped to [0, 1]) whenever the previous run is done, at
        a lower priority (Linux: :data:`SEPARATION_NICENESS`), so the maps
        keep their rate; the maps then start at most
        :data:`MAPS_FPS_WITH_LAYERS` frames a second, so the layers get CPU too.
    separate_options
        Keyword options of that method (e.g. ``{"device": "cuda"}`` for the
        tensor method on a GPU).
    hold_illuminant
        For a method that estimates the illuminant (``polarized-residual``, ``tensor``: it takes an
        ``illuminant`` option and reports its estimate) and was not given one: estimate it on the
        first separated frame and pass that estimate to every later one (:attr:`held_illuminant`).
        A scene's light does not change from frame to frame, but its estimate does with the noise:
        re-estimated each frame it flipped between two decisions on one of six noisy frames of a
        static synthetic scene, and the whole diffuse layer with it (docs/methods/polarized-residual.md,
        "Stability").  ``False``: estimate on every frame.
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

    def __init__(self, layout: Layout, *, sink: Sink | None = None, separate: str | ResolvedSeparation | None = None,
                 separate_options: dict[str, Any] | None = None,
                 counters: Counters | None = None, workers: int = 2,
                 calibration: Calibration | None = None, hold_illuminant: bool = True) -> None:
        self.layout = layout
        self._bilinear = resolve_demosaic("bilinear", layout)  # the separation's cell stack
        self.sink = sink
        self.calibration = calibration
        if isinstance(separate, str):
            separate = resolve_separation(separate, layout_form(layout), separate_options)
        elif separate is not None and separate_options:
            separate = separate.with_options(**separate_options)
        #: The separation the layers run, resolved once (options as passed to the method), or None.
        self.separation: ResolvedSeparation | None = separate
        self.method = None if separate is None else separate.method
        self.method_options = {} if separate is None else dict(separate.options)
        #: The illuminant estimated on the first separated frame and passed to the later ones (RGB), or None.
        self.held_illuminant: list[float] | None = None
        self._hold = hold_illuminant and separate is not None and "illuminant" not in separate.options \
            and separate.takes("illuminant")
        self.counters = counters or Counters()
        #: Frames whose maps were computed (and logged, with a sink).
        self.processed = 0
        self.skipped = 0
        #: Frames separated into layers (``imin``: every processed frame).
        self.separations = 0
        self.separations_skipped = 0
        self.separation_errors: list[str] = []
        self.seconds = 0.0
        self.separation_seconds: list[float] = []
        self._lock = threading.Lock()
        self._maps_rate = _Rate()
        self._layers_rate = _Rate()
        self._wake = threading.Condition(self._lock)
        self._pending: tuple[int, Frame] | None = None
        self._closing = False
        self._sep_lock = threading.Lock()
        self._sep_wake = threading.Condition(self._sep_lock)
        self._sep_pending: tuple[int, Frame] | None = None
        # the earliest start of the next frame's maps (see MAPS_FPS_WITH_LAYERS)
        self._maps_interval = 1.0 / MAPS_FPS_WITH_LAYERS if self.method not in (None, "imin") else 0.0
        self._next_maps = 0.0
        self.error: BaseException | None = None
        self._threads = [threading.Thread(target=self._run, name=f"live-{i}", daemon=True)
                         for i in range(max(1, int(workers)))]
        for t in self._threads:
            t.start()
        self._sep_thread: threading.Thread | None = None
        #: True when a stop did not wait for the separation in progress (:meth:`close`).
        self.separation_abandoned = False
        self._fork_server: int | None = None
        if separate is not None and separate.method != "imin":
            self._fork_server = _start_workers_deaf_to_ctrl_c(separate)
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
                while True:
                    while self._pending is None and not self._closing:
                        self._wake.wait()
                    if self._pending is None:
                        return
                    early = self._next_maps - time.monotonic()
                    if early <= 0 or self._closing:
                        break
                    self._wake.wait(early)  # a newer frame may replace the pending one meanwhile
                index, frame = self._pending
                self._pending = None
                self._next_maps = time.monotonic() + self._maps_interval
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
                maps_fps = self._maps_rate.tick()
                layers_fps = self._layers_rate.rate()
            self._stats(index, frame.metadata.get("timestamp_ns"), maps_fps, layers_fps)

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

        return calibrate(as_recorded(frame), self.calibration)

    def _process(self, index: int, frame: Frame) -> None:
        ts = frame.metadata.get("timestamp_ns")
        view = self.corrected(frame)
        maps = live_maps(view.mosaic, self.layout, black_level=view.black_level,
                         white_level=view.white_level)
        if self.sink is not None:  # the raw frame as sent; S0 = 2 Ic
            products = {"s0": maps.ic, "dolp": maps.dolp, "aolp": maps.aolp}
            scale = {"s0": 2 * maps.scale}
            if self.method == "imin":
                products.update(diffuse=maps.diffuse, specular=maps.specular)
                scale.update(diffuse=maps.scale, specular=maps.scale)
            self.sink.log(index, Record(frame=frame, products=products, scale=scale, timestamp_ns=ts))
        if self.method == "imin":
            with self._lock:
                self.separations += 1
                self._layers_rate.tick()
        elif self.method is not None:
            with self._sep_lock:
                if self._sep_pending is not None:  # replaced by a newer frame before it started
                    self.separations_skipped += 1
                self._sep_pending = (index, view)
                self._sep_wake.notify()

    def _stats(self, index: int, ts: int | None, maps_fps: float, layers_fps: float) -> None:
        if self.sink is None:
            return
        c = self.counters
        with c.lock:
            fps, dropped, incomplete = c.fps, c.dropped, c.incomplete
        self.sink.log(index, Record(stats={"fps": fps, "dropped": dropped, "incomplete": incomplete,
                                           "maps_fps": maps_fps, "layers_fps": layers_fps}, timestamp_ns=ts))

    def _run_separation(self) -> None:
        _lower_priority(SEPARATION_NICENESS)
        while True:
            with self._sep_lock:
                while self._sep_pending is None and not self._closing:
                    self._sep_wake.wait()
                if self._sep_pending is None:
                    return
                index, frame = self._sep_pending
                self._sep_pending = None
            try:
                stack = to_stack(frame, demosaic=self._bilinear, resolution="cell")
                t0 = time.perf_counter()
                res = separate_layers(stack, method=self.separation)
                if self.separation_abandoned:  # the capture stopped without it
                    return
                dt = time.perf_counter() - t0
                self.separation_seconds.append(dt)
                if self._hold and self.held_illuminant is None:
                    self._hold_from(res.info)
                ts = frame.metadata.get("timestamp_ns")
                if self.sink is not None:
                    self.sink.log(index, Record(products={"diffuse": res.diffuse, "specular": res.specular},
                                                timestamp_ns=ts))
                with self._lock:
                    self.separations += 1
                    layers_fps = self._layers_rate.tick()
                if self.sink is not None:
                    self.sink.log(index, Record(stats={"separation_seconds": dt, "layers_fps": layers_fps},
                                                timestamp_ns=ts))
            except Exception as exc:  # noqa: BLE001 - reported, live view goes on
                if self.separation_abandoned:  # its workers were stopped with the capture
                    return
                self.separation_errors.append(f"frame {index}: {exc}")
            except KeyboardInterrupt:  # a worker interrupted all the same: the capture is stopping
                self.separations_skipped += 1
                return

    def _hold_from(self, info: dict[str, Any]) -> None:
        """Keep the illuminant a separation estimated, for the separations that follow."""
        est = estimated_illuminant(info)
        if est is not None and self.separation is not None:
            self.held_illuminant = est
            self.separation = self.separation.with_options(illuminant=est)
            self.method_options["illuminant"] = est

    def close(self, *, finish: bool = True, abandon_after: float = 1.0) -> None:
        """Stop the live threads.

        With ``finish`` the newest frame still waiting (and its separation)
        is processed first, and a separation in progress is waited for.
        Without it (a stop on request) the waiting frame is counted as
        skipped, and a separation still running ``abandon_after`` seconds
        later is abandoned (:attr:`separation_abandoned`, counted in
        ``separations_skipped``): a tensor separation of a full frame takes
        tens of seconds, and a stop must not wait for it.  A fork server this
        processor started, and its workers, are then sent SIGTERM, so the
        process can exit (the next pool starts a new server).
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
            self._sep_thread.join(None if finish else abandon_after)
            if self._sep_thread.is_alive():
                self.separation_abandoned = True
                self.separations_skipped += 1
                if self._fork_server is not None:
                    _stop_fork_server(self._fork_server)
                self._sep_thread.join(5.0)
