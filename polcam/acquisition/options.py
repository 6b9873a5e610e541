"""What a capture does: :class:`CaptureOptions`, and how it is stopped (:class:`StopRequest`)."""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["ON_WRITE_ERROR", "CaptureOptions", "StopRequest"]

#: What a capture does when a frame cannot be written: stop, or go on with the live view only.
ON_WRITE_ERROR: tuple[str, ...] = ("stop", "continue-live")


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


@dataclass(frozen=True)
class CaptureOptions:
    """What a capture does with a started camera's frames (:class:`Capture`, :func:`run_capture`).

    Attributes
    ----------
    out
        Folder for the frames and ``summary.json`` (created); ``None``:
        nothing is saved (live view only).
    frames, duration
        Stop after this many good frames / seconds (``None``: until the source
        ends or ``stop`` is set).
    save_format
        One of :data:`polcam.acquisition.saving.SAVE_FORMATS`.
    separate
        Separation method for the live layers, ``"default"`` (the registry's
        default for the camera's layout, :func:`polcam.separation.default_method`)
        or ``None``.
    separate_options
        Keyword options of that method, checked against it before the camera
        starts (e.g. ``{"device": "cuda"}``); recorded in the summary.
    rerun
        ``"spawn"``, ``"serve"``, a ``.rrd`` path, or ``None`` (no Rerun view).
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
    """

    out: Path | None = None
    frames: int | None = None
    duration: float | None = None
    save_format: str = "raw"
    separate: str | None = "imin"
    separate_options: Mapping[str, Any] = field(default_factory=dict)
    rerun: str | Path | None = None
    idle_timeout: float | None = 10.0
    software_trigger: bool = False
    append: bool = False
    save_workers: int = 4
    save_queue: int = 16
    raw_every: int = 10
    view_scale: float = 0.5
    live_workers: int = 2
    rerun_bind: str = "127.0.0.1"
    rerun_port: int = 9090
    hold_illuminant: bool = True
    on_write_error: str = "stop"
