"""Cameras: one protocol, a registry of backends.

- :class:`~polcam.camera.base.Camera`: the protocol (context manager; open,
  configure with :class:`~polcam.camera.base.CameraSettings`, start/stop,
  read frames with timeouts, statistics).
- :class:`~polcam.camera.aravis.AravisCamera`: GenICam cameras (GigE Vision,
  USB3 Vision, Aravis' Fake camera) through Aravis 0.8 and PyGObject.
- :class:`~polcam.camera.replay.ReplayCamera`: ``replay:DIR``, a folder of
  raw frames played back as a camera (tests, demos, re-running a session).

:func:`open_camera` picks the backend from a ``--device`` string through the
backend registry (:mod:`polcam.camera.registry`: device-id prefixes, e.g.
``replay:``, and Aravis as the default); :meth:`Camera.poll_frames` is the one
read loop (capture and calibration use it).  Everything
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
    CameraDisconnectedError,
    CameraNotFoundError,
    CameraSettingError,
    CameraSettings,
    CapturedFrame,
    FrameTimeout,
    StreamStats,
)
from polcam.camera.registry import backends, open_camera, register_backend
from polcam.camera.replay import ReplayCamera, as_recorded

__all__ = [
    "AravisCamera",
    "Camera",
    "CameraBusyError",
    "CameraDisconnectedError",
    "CameraNotFoundError",
    "CameraSettingError",
    "CameraSettings",
    "CapturedFrame",
    "DeviceInfo",
    "FrameTimeout",
    "ReplayCamera",
    "StreamStats",
    "TRIGGER_MODES",
    "aravis_available",
    "as_recorded",
    "list_devices",
    "load_aravis",
    "backends",
    "open_camera",
    "register_backend",
]
