"""Acquisition: recording a camera losslessly while watching it live.

- :mod:`polcam.acquisition.saving`: frames and sidecars written atomically on
  writer threads (:class:`FrameSaver`, :func:`write_captured_frame`);
- :mod:`polcam.acquisition.live`: the newest frame through the per-frame
  pipeline's live route, and the chosen separation, to the Rerun sink
  (:class:`LiveProcessor`);
- :mod:`polcam.acquisition.run`: the capture run (:class:`Capture`:
  prepare, loop, summary; :func:`run_capture`), from a started camera to
  ``summary.json``, with its options (:class:`CaptureOptions`).

``polcam capture`` (:mod:`polcam.commands.capture`) is the command line on top.
"""

from __future__ import annotations

from polcam.acquisition.live import Counters, LiveProcessor
from polcam.acquisition.options import CaptureOptions, StopRequest
from polcam.acquisition.run import Capture, run_capture
from polcam.acquisition.saving import SAVE_FORMATS, FrameSaver, frame_name, write_captured_frame

__all__ = [
    "SAVE_FORMATS",
    "Capture",
    "CaptureOptions",
    "Counters",
    "FrameSaver",
    "LiveProcessor",
    "StopRequest",
    "frame_name",
    "run_capture",
    "write_captured_frame",
]
