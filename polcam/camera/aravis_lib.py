"""Aravis 0.8 through PyGObject, imported lazily: loading it and listing the cameras it sees.

Aravis is a system library (Debian: ``gir1.2-aravis-0.8``) reached through
GObject introspection (PyGObject, pinned ``<3.50`` on bookworm).  polcam imports
it only when a camera is used; the backend is :mod:`polcam.camera.aravis`.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from types import ModuleType
from typing import Any

from polcam.errors import CameraUnavailableError

__all__ = ["DeviceInfo", "INSTALL_HINT", "aravis_available", "gerror_message", "is_busy", "list_devices", "load_aravis"]

INSTALL_HINT = (
    "install the camera stack with `sudo drivers/install.sh` (Debian packages gir1.2-aravis-0.8, "
    "aravis-tools-cli, aravis-tools and the PyGObject build dependencies) and "
    "`pip install 'polcam[camera]'` (PyGObject<3.50)"
)

_ARAVIS: ModuleType | None = None


def load_aravis() -> ModuleType:
    """The ``gi.repository.Aravis`` module.

    Raises
    ------
    CameraUnavailableError
        When PyGObject or the Aravis 0.8 typelib is missing; the message says
        how to install them.
    """
    global _ARAVIS
    if _ARAVIS is not None:
        return _ARAVIS
    if os.environ.get("POLCAM_NO_ARAVIS"):
        raise CameraUnavailableError(f"Aravis disabled by POLCAM_NO_ARAVIS; {INSTALL_HINT}")
    try:
        import gi
    except ImportError as exc:
        raise CameraUnavailableError(f"PyGObject is not installed ({exc}); {INSTALL_HINT}") from None
    try:
        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise CameraUnavailableError(
            f"the Aravis 0.8 library is not installed ({exc}); {INSTALL_HINT}"
        ) from None
    _ARAVIS = Aravis
    return Aravis


def aravis_available() -> bool:
    """True when Aravis can be imported."""
    try:
        load_aravis()
    except CameraUnavailableError:
        return False
    return True


@dataclass(frozen=True)
class DeviceInfo:
    """A camera Aravis can see."""

    id: str
    vendor: str
    model: str
    serial: str
    protocol: str
    address: str
    physical_id: str

    def as_dict(self) -> dict[str, Any]:
        """The fields as a plain dict (for JSON)."""
        return asdict(self)


def list_devices(*, fake: bool = False) -> list[DeviceInfo]:
    """Cameras on every Aravis interface (GigE Vision, USB3 Vision).

    Parameters
    ----------
    fake
        Also enable Aravis' in-process ``Fake`` interface (camera ``Fake_1``),
        for tests and demos without hardware.
    """
    arv = load_aravis()
    if fake:
        arv.enable_interface("Fake")
    arv.update_device_list()
    out = []
    for i in range(arv.get_n_devices()):
        out.append(DeviceInfo(
            id=arv.get_device_id(i) or "",
            vendor=arv.get_device_vendor(i) or "",
            model=arv.get_device_model(i) or "",
            serial=arv.get_device_serial_nbr(i) or "",
            protocol=arv.get_device_protocol(i) or "",
            address=arv.get_device_address(i) or "",
            physical_id=arv.get_device_physical_id(i) or "",
        ))
    return out


def gerror_message(exc: BaseException) -> str:
    """The message of a GLib error (or of any exception)."""
    return str(getattr(exc, "message", None) or exc)


def is_busy(message: str) -> bool:
    """Whether an Aravis error message says another process holds the camera."""
    m = message.lower()
    return any(w in m for w in ("control access", "busy", "in use", "access denied", "privilege"))
