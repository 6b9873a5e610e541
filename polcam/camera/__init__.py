"""Cameras: GenICam devices through Aravis.

Only device discovery lives here so far (``polcam devices``); the camera protocol,
the Aravis backend and the file-backed replay camera come with live capture.
Everything else in polcam works without Aravis; the functions here raise
:class:`~polcam.errors.CameraUnavailableError` with install instructions when it
is missing.
"""

from __future__ import annotations

from polcam.camera.aravis import DeviceInfo, aravis_available, list_devices, load_aravis

__all__ = ["DeviceInfo", "aravis_available", "list_devices", "load_aravis"]
