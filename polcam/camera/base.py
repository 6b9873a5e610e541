"""The camera protocol every polcam camera backend follows.

A camera is used as a context manager::

    with open_camera("Fake_1") as cam:            # open() ... close()
        cam.configure(pixel_format="Mono8", layout="imx250mzr", exposure_us=5000)
        # or cam.configure(CameraSettings(...)): the same fields
        cam.start()
        for frame in cam.frames(timeout=1.0):     # good frames only
            ...
        cam.stop()
        print(cam.stats())

Two backends implement it: :class:`polcam.camera.aravis.AravisCamera`
(GenICam cameras through Aravis 0.8) and
:class:`polcam.camera.replay.ReplayCamera` (``replay:DIR``, a folder of raw
frames played back as a camera).  Both deliver :class:`CapturedFrame` objects
(a :class:`polcam.frame.Frame` with the bytes the camera sent) carrying the
sidecar metadata (:data:`polcam.frame.SIDECAR_KEYS`), and both count what did not arrive
in a :class:`StreamStats`: frames whose buffer came back incomplete (missing
packets, size mismatch, timeout ...) are counted and never handed on as good
frames; frames the camera produced that polcam never saw (gaps in the frame
ids, a full frame queue) are counted as dropped.

Acquisition runs in the backend's own thread, which never waits for the
consumer: frames go into a bounded queue and a frame that finds the queue
full is dropped (and counted), so a slow consumer costs frames, never a
stalled camera.
"""

from __future__ import annotations

import abc
import queue
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, fields, replace
from typing import Any

from polcam.errors import CameraUnavailableError, PolcamError
from polcam.frame import Frame
from polcam.mosaic import Layout

__all__ = [
    "Camera",
    "CameraSettings",
    "CameraBusyError",
    "CameraDisconnectedError",
    "CameraNotFoundError",
    "CameraSettingError",
    "CapturedFrame",
    "FrameTimeout",
    "FrameIdTracker",
    "StreamStats",
    "TRIGGER_MODES",
]

#: Trigger modes besides a hardware line name (``Line0``, ``Line1``, ...).
TRIGGER_MODES: tuple[str, ...] = ("free", "software")


class CameraNotFoundError(CameraUnavailableError):
    """No camera with the requested id (the message says how to list them)."""


class CameraBusyError(CameraUnavailableError):
    """The camera exists but another program controls it."""


class CameraDisconnectedError(CameraUnavailableError):
    """A started camera stopped answering (cable out, power lost, emulator killed).

    Raised by :meth:`Camera.poll_frames` once the frames the camera delivered
    before it went away have all been read.
    """


class CameraSettingError(PolcamError):
    """A setting the camera refuses or does not have (names the setting and the value)."""


class FrameTimeout(TimeoutError):
    """No frame arrived from a started camera within the idle timeout."""


@dataclass
class CapturedFrame(Frame):
    """A frame as a camera delivered it.

    Attributes
    ----------
    payload
        The image bytes exactly as the camera sent them (in the pixel
        format's packing), or ``None`` when the frame did not come as a
        byte buffer (the replay camera reading a PNG).  A raw dump of a
        captured frame is these bytes.
    """

    payload: bytes | None = None


@dataclass(frozen=True)
class CameraSettings:
    """What :meth:`Camera.configure` sets; ``None`` leaves a setting as it is.

    Attributes
    ----------
    pixel_format
        GenICam PixelFormat name; must be one the camera offers and polcam
        reads.
    layout
        Sensor layout for cameras whose format does not say where the
        polarizers are (plain Mono/Bayer formats).
    exposure_us
        Exposure time, microseconds.
    gain_db
        Gain (dB on SFNC cameras; raw units where the camera only has GainRaw).
    roi
        ``(x, y, width, height)`` on the sensor.  Offsets and sizes are
        rounded down to multiples of the layout's period (2 mono, 4
        colour) and of the camera's increments, so the delivered image
        starts on a whole polarizer (and colour) cell.
    frame_rate
        Frames per second.
    trigger
        ``"free"`` (free-running), ``"software"`` (:meth:`Camera.trigger`
        releases each frame) or a hardware line name (``Line0`` ...).
    reverse_x, reverse_y
        GenICam ReverseX / ReverseY, where the camera has them.
    """

    pixel_format: str | None = None
    layout: str | Layout | None = None
    exposure_us: float | None = None
    gain_db: float | None = None
    roi: tuple[int, int, int, int] | None = None
    frame_rate: float | None = None
    trigger: str | None = None
    reverse_x: bool | None = None
    reverse_y: bool | None = None

    @classmethod
    def of(cls, settings: CameraSettings | None = None, /, **changes: Any) -> CameraSettings:
        """``settings`` (default: all ``None``) with ``changes`` applied.

        Raises
        ------
        TypeError
            A name in ``changes`` that is not a field (the message lists the fields).
        """
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(changes) - set(names))
        if unknown:
            raise TypeError(f"unknown camera settings {unknown}; expected some of {', '.join(names)}")
        return replace(settings or cls(), **changes)

    def given(self) -> dict[str, Any]:
        """The settings that are not ``None``, by name."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass
class StreamStats:
    """Counters of one acquisition.

    Attributes
    ----------
    good
        Complete frames the camera delivered (handed on, or dropped because
        the frame queue was full).
    incomplete
        Frames whose buffer came back with an error status (missing packets,
        size mismatch, timeout, wrong packet id, ...); never handed on.
    dropped
        Frames the camera produced that never reached the consumer: gaps in
        the frame ids plus frames that found the frame queue full.
    queue_overflow
        The part of ``dropped`` lost to a full frame queue (the consumer was
        too slow).
    left_at_stop
        The part of ``dropped`` a live camera delivered that the consumer left
        unread when it stopped (:meth:`Camera.unread`: ``--frames N`` reached,
        an abort).
    by_status
        Buffers per status name (``success``, ``missing-packets``, ...,
        including ``aborted`` buffers cancelled when acquisition stops, which
        are not counted as incomplete).
    stream
        The backend's own counters (Aravis stream statistics: received and
        missing packets, resends, underruns, ...).
    """

    good: int = 0
    incomplete: int = 0
    dropped: int = 0
    queue_overflow: int = 0
    left_at_stop: int = 0
    by_status: dict[str, int] = field(default_factory=dict)
    stream: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return {
            "good": self.good,
            "incomplete": self.incomplete,
            "dropped": self.dropped,
            "queue_overflow": self.queue_overflow,
            "left_at_stop": self.left_at_stop,
            "by_status": dict(self.by_status),
            "stream": dict(self.stream),
        }


class FrameIdTracker:
    """Count frames missing from a sequence of camera frame ids.

    GigE Vision block ids are 16-bit and skip 0 (65535 is followed by 1);
    other cameras count up without wrapping.  A step back that is not such a
    wrap is taken as a counter reset (a restarted acquisition), not as loss.
    """

    def __init__(self) -> None:
        self.last: int | None = None
        self.missing = 0

    def see(self, frame_id: int) -> int:
        """Record ``frame_id``; return how many ids were skipped before it."""
        fid = int(frame_id)
        gap = 0
        if self.last is not None:
            step = fid - self.last
            if step > 0:
                gap = step - 1
            elif self.last >= 0xF000 and fid < 0x1000 and self.last <= 0xFFFF:
                # 16-bit wrap (GigE Vision block id 0 is never used)
                gap = (0xFFFF - self.last) + (fid - 1)
        self.last = fid
        self.missing += gap
        return gap


class Camera(abc.ABC):
    """A source of raw polarization frames.

    Subclasses implement :meth:`open`, :meth:`close`, :meth:`configure`,
    :meth:`_start`, :meth:`_stop` and fill the frame queue from their own
    acquisition thread with :meth:`_deliver`.

    Parameters
    ----------
    camera_id
        The id the camera was asked for (``Fake_1``, a serial, ``replay:DIR``).
    queue_frames
        Capacity of the frame queue between the acquisition thread and the
        consumer; a frame that finds it full is dropped and counted.
    """

    def __init__(self, camera_id: str, *, queue_frames: int = 8) -> None:
        if int(queue_frames) < 1:
            raise CameraSettingError(f"queue_frames {queue_frames!r}: expected a positive integer")
        self.camera_id = str(camera_id)
        self._queue: queue.Queue[CapturedFrame] = queue.Queue(maxsize=int(queue_frames))
        self._stats = StreamStats()
        self._stats_lock = threading.Lock()
        self._running = False
        self._finished = threading.Event()  # a finite source has delivered everything
        self._opened = False
        self._lost: str | None = None  # why the camera stopped answering, once it has

    # ---------------------------------------------------------------- context
    def __enter__(self) -> Camera:
        if not self._opened:
            self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            if self._running:
                self.stop()
        finally:
            self.close()

    # ------------------------------------------------------------ to implement
    @abc.abstractmethod
    def open(self) -> Camera:
        """Connect to the camera; returns ``self``."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the camera (stops acquisition first)."""

    def configure(self, settings: CameraSettings | None = None, /, **changes: Any) -> dict[str, Any]:
        """Apply settings; a setting left ``None`` stays as it is.

        Parameters
        ----------
        settings
            The settings (:class:`CameraSettings`), or ``None``.
        **changes
            Fields of :class:`CameraSettings` (``pixel_format``, ``layout``,
            ``exposure_us``, ``gain_db``, ``roi``, ``frame_rate``,
            ``trigger``, ``reverse_x``, ``reverse_y``) set on top of ``settings``.

        Returns
        -------
        dict
            The settings as the camera reports them afterwards (what frames
            will carry), including ``layout`` (the delivered image's layout)
            and ``ignored`` (settings this camera cannot apply).

        Raises
        ------
        TypeError
            A keyword that is not a field of :class:`CameraSettings`.
        CameraSettingError, PixelFormatError, LayoutError
            A setting the camera refuses (the backend's :meth:`_configure`).
        """
        return self._configure(CameraSettings.of(settings, **changes))

    @abc.abstractmethod
    def _configure(self, settings: CameraSettings) -> dict[str, Any]:
        """Apply ``settings`` (the backend's part of :meth:`configure`); returns what :meth:`configure` does."""

    @abc.abstractmethod
    def _start(self) -> None:
        """Start the acquisition thread."""

    @abc.abstractmethod
    def _stop(self) -> None:
        """Stop and join the acquisition thread."""

    def trigger(self) -> None:
        """Release one frame (``trigger="software"``)."""
        raise CameraSettingError(f"camera {self.camera_id} has no software trigger")

    @property
    @abc.abstractmethod
    def layout(self) -> Layout | None:
        """Layout of the delivered images (after ROI and mirroring)."""

    @property
    def info(self) -> dict[str, Any]:
        """Vendor, model, serial, protocol ... (for the capture summary)."""
        return {"id": self.camera_id}

    @property
    def waits_for_reader(self) -> bool:
        """True when the source holds every frame until it is read (a recording played
        losslessly: the replay camera without a frame rate).

        Such a source never lets frames go stale while the reader pauses, and
        stopping and starting it plays the recording again from the start.  A
        live camera (``False``) keeps exposing while nobody reads: a reader
        that needs frames taken after some moment (``polcam calibrate
        polarizer`` after each turn of the polarizer) stops acquisition
        meanwhile and starts it again.
        """
        return False

    # ---------------------------------------------------------------- running
    def start(self) -> None:
        """Start acquisition (frames begin to fill the queue)."""
        if self._running:
            return
        if self._lost is not None:
            raise CameraDisconnectedError(f"camera {self.camera_id} disconnected: {self._lost}")
        with self._stats_lock:
            self._stats = StreamStats()
        self._finished.clear()
        self._drain_queue()
        self._start()
        self._running = True

    def stop(self) -> None:
        """Stop acquisition.  Frames already queued can still be read."""
        if not self._running:
            return
        self._running = False
        self._stop()

    @property
    def running(self) -> bool:
        """True between :meth:`start` and :meth:`stop`."""
        return self._running

    @property
    def lost(self) -> str | None:
        """Why the camera stopped answering (``None`` while it answers)."""
        return self._lost

    def _connection_lost(self, reason: str) -> None:
        """Record (from any thread) that the camera went away; the first reason is kept."""
        if self._lost is None:
            self._lost = str(reason)

    def take_queued(self) -> list[CapturedFrame]:
        """The frames still in the queue after :meth:`stop` (delivered, never read), removed from it."""
        out = []
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out

    def unread(self, n: int) -> None:
        """Count ``n`` delivered frames that the consumer leaves unread at the end.

        A source that holds every frame until it is read
        (:attr:`waits_for_reader`) still has them: they are taken back from
        ``good``.  A live camera's frames are lost: they count as dropped
        (and ``left_at_stop``).
        """
        if n <= 0:
            return
        with self._stats_lock:
            if self.waits_for_reader:
                self._stats.good -= n
                self._stats.by_status["success"] = self._stats.by_status.get("success", 0) - n
            else:
                self._stats.dropped += n
                self._stats.left_at_stop += n

    @property
    def exhausted(self) -> bool:
        """True when no frame will come any more: a finite source played out
        (or acquisition stopped) and the queue is empty."""
        return (self._finished.is_set() or not self._running) and self._queue.empty()

    def read(self, timeout: float = 1.0) -> CapturedFrame | None:
        """The next good frame, or ``None`` when none arrives within ``timeout`` seconds
        (at once when a finite source has delivered everything)."""
        deadline = time.monotonic() + max(0.0, float(timeout))
        while True:
            remaining = deadline - time.monotonic()
            try:
                return self._queue.get(timeout=min(0.05, max(0.0, remaining)))
            except queue.Empty:
                if remaining <= 0 or (self._finished.is_set() and self._queue.empty()):
                    return None

    def poll_frames(self, *, poll: float = 0.1, idle_timeout: float | None = None,
                    software_trigger: bool = False) -> Iterator[CapturedFrame | None]:
        """The read loop every polcam consumer uses (capture, calibration, :meth:`frames`).

        Yields each good frame as it arrives, and ``None`` after every empty
        wait of ``poll`` seconds, so the caller can check its own stop
        conditions in between.  Returns when the source is exhausted (a
        replay folder played out).  The camera must be started.

        Parameters
        ----------
        poll
            Seconds of each wait for a frame.
        idle_timeout
            Raise :class:`FrameTimeout` when no frame came for this many
            seconds (``None``: wait for ever).
        software_trigger
            Fire :meth:`trigger` for each frame, one at a time (again after
            a second without the frame).

        Raises
        ------
        FrameTimeout
            No frame for ``idle_timeout`` seconds.
        CameraDisconnectedError
            The camera stopped answering (:attr:`lost`); raised once every
            frame it delivered before has been yielded.
        """
        last = time.monotonic()
        outstanding = False
        fired = 0.0
        while True:
            now = time.monotonic()
            if software_trigger and (not outstanding or now - fired > 1.0):
                self.trigger()
                outstanding, fired = True, now
            frame = self.read(poll)
            if frame is not None:
                outstanding = False
                last = time.monotonic()
                yield frame
                continue
            if self._lost is not None and self._queue.empty():
                raise CameraDisconnectedError(f"camera {self.camera_id} disconnected: {self._lost}")
            if self.exhausted:
                return
            if idle_timeout is not None and time.monotonic() - last > idle_timeout:
                raise FrameTimeout(
                    f"camera {self.camera_id}: no frame for {idle_timeout:g} s "
                    f"(trigger not firing? stream statistics: {self.stats().as_dict()})"
                )
            yield None

    def frames(self, *, timeout: float = 1.0, idle_timeout: float | None = None) -> Iterator[CapturedFrame]:
        """Good frames until the source is exhausted or acquisition stops (:meth:`poll_frames` without the empty polls).

        Parameters
        ----------
        timeout
            Seconds of each wait (the loop checks for the end in between).
        idle_timeout
            Raise :class:`FrameTimeout` (a :class:`TimeoutError`) when no
            frame came for this many seconds (``None``: wait for ever).
        """
        for frame in self.poll_frames(poll=timeout, idle_timeout=idle_timeout):
            if frame is not None:
                yield frame

    def stats(self) -> StreamStats:
        """A snapshot of the acquisition counters."""
        with self._stats_lock:
            s = self._stats
            snap = StreamStats(s.good, s.incomplete, s.dropped, s.queue_overflow, s.left_at_stop,
                               dict(s.by_status), dict(s.stream))
        snap.stream.update(self._backend_stats())
        return snap

    def _backend_stats(self) -> dict[str, Any]:
        return {}

    # --------------------------------------------------------- for backends
    def _count(self, status: str, *, incomplete: bool = False, dropped: int = 0) -> None:
        with self._stats_lock:
            self._stats.by_status[status] = self._stats.by_status.get(status, 0) + 1
            if incomplete:
                self._stats.incomplete += 1
            self._stats.dropped += dropped

    def _count_dropped(self, n: int) -> None:
        if n:
            with self._stats_lock:
                self._stats.dropped += n

    def _deliver(self, frame: CapturedFrame, *, block: bool = False,
                 stop: threading.Event | None = None) -> bool:
        """Queue a good frame from the acquisition thread.

        With ``block=False`` (a live camera) a full queue drops the frame and
        counts it; with ``block=True`` (a lossless file source) it waits for
        room until ``stop`` is set (then a source that :attr:`waits_for_reader`
        takes the frame back from ``good``; any other counts it dropped).
        Returns True when the frame was queued.
        """
        with self._stats_lock:
            self._stats.good += 1
            self._stats.by_status["success"] = self._stats.by_status.get("success", 0) + 1
        if not block:
            try:
                self._queue.put_nowait(frame)
                return True
            except queue.Full:
                with self._stats_lock:
                    self._stats.dropped += 1
                    self._stats.queue_overflow += 1
                return False
        while True:
            try:
                self._queue.put(frame, timeout=0.05)
                return True
            except queue.Full:
                if stop is not None and stop.is_set():
                    with self._stats_lock:
                        if self.waits_for_reader:  # the recording still holds it: not delivered, not lost
                            self._stats.good -= 1
                            self._stats.by_status["success"] -= 1
                        else:
                            self._stats.dropped += 1
                            self._stats.queue_overflow += 1
                    return False

    def _drain_queue(self) -> None:
        while True:
            try:
                self._queue.get_nowait()
            except queue.Empty:
                return
