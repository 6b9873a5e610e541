"""Cameras: one protocol, two backends.

- :class:`~polcam.camera.base.Camera`: the protocol (context manager; open,
  configure, start/stop, read frames with timeouts, statistics).
- :class:`~polcam.camera.aravis.AravisCamera`: GenICam cameras (GigE Vision,
  USB3 Vision, Aravis' Fake camera) through Aravis 0.8 and PyGObject.
- :class:`~polcam.camera.replay.ReplayCamera`: ``replay:DIR``, a folder of
  raw frames played back as a camera (tests, demos, re-running a session).

:func:`open_camera` picks the backend from a ``--device`` string.  Everything
else in polcam works without Aravis; the Aravis functions raise
:class:`~polcam.errors.CameraUnavailableError` with install instructions when
it is missing.
"""

from __future__ import annotations

from polcam.camera.aravis import AravisCamera, DeviceInfo, aravis_available, list_devices, load_aravis
from polcam.camera.base import (
    TRIGGER_MODES,
    Camera,
    CameraBusyError,
    CameraNotFoundError,
    CameraSettingError,
    CapturedFrame,
    StreamStats,
    open_camera,
)
from polcam.camera.replay import ReplayCamera, as_recorded

__all__ = [
    "AravisCamera",
    "Camera",
    "CameraBusyError",
    "CameraNotFoundError",
    "CameraSettingError",
    "CapturedFrame",
    "DeviceInfo",
    "ReplayCamera",
    "StreamStats",
    "TRIGGER_MODES",
    "aravis_available",
    "as_recorded",
    "list_devices",
    "load_aravis",
    "open_camera",
]
