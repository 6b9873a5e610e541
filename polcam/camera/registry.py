"""Camera backends by device-id prefix: ``open_camera("replay:DIR")``, ``open_camera("Fake_1")``.

Each backend module registers itself when imported (``polcam.camera``
imports them all): :func:`register_backend` maps a device-id prefix to a
constructor; the backend registered with ``default=True`` takes every id no
prefix claims.  Registered today: ``replay:`` (:mod:`polcam.camera.replay`,
a folder of raw frames played as a camera) and the default, Aravis
(:mod:`polcam.camera.aravis`: GenICam device ids as ``polcam devices`` lists
them; Aravis' GigE Vision emulator shows up there too).

A new backend is one module that subclasses :class:`polcam.camera.base.Camera`
and calls :func:`register_backend`, plus its import in ``polcam/camera/__init__.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from polcam.camera.base import CameraNotFoundError

if TYPE_CHECKING:
    from polcam.camera.base import Camera

__all__ = ["backends", "open_camera", "register_backend"]

_BACKENDS: dict[str, Callable[..., Camera]] = {}
_DEFAULT: list[Callable[..., Camera]] = []


def register_backend(prefix: str | None, factory: Callable[..., Camera], *, default: bool = False) -> None:
    """Open device ids starting with ``prefix`` (stripped off) with ``factory(rest, **options)``.

    Parameters
    ----------
    prefix
        Device-id prefix, e.g. ``"replay:"`` (``None`` with ``default`` only).
    factory
        Callable taking the id without the prefix and the backend's keyword options.
    default
        Also (or only) the backend for ids no prefix claims.
    """
    if prefix:
        _BACKENDS[prefix] = factory
    if default:
        _DEFAULT[:] = [factory]


def backends() -> tuple[str, ...]:
    """The registered device-id prefixes (``"*"`` stands for the default backend)."""
    return tuple(_BACKENDS) + (("*",) if _DEFAULT else ())


def open_camera(device: str, **options: Any) -> Camera:
    """The camera for a ``--device`` string (not yet opened).

    Parameters
    ----------
    device
        ``replay:DIR`` for the file-backed camera; an id no registered prefix
        claims goes to the default backend, Aravis (``polcam devices`` lists
        the ids; ``Fake_1`` is Aravis' simulated camera).
    options
        Passed to the backend's constructor (``frame_rate``/``loop`` for
        replay; ``n_buffers``, ``packet_size``, ``socket_buffer_bytes`` for
        Aravis; ``queue_frames`` for both).

    Returns
    -------
    Camera
        The backend's camera, closed: use it as a context manager (opens and
        closes it), :meth:`~polcam.camera.Camera.start` it and read
        :meth:`~polcam.camera.Camera.frames`.

    Raises
    ------
    CameraNotFoundError
        An empty id, or no backend for it.

    Examples
    --------
    The replay camera plays a folder of raw frames, here three 4 x 4 PNGs:

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from polcam import Frame
    >>> from polcam.camera import open_camera
    >>> from polcam.io import write_frame
    >>> tmp = tempfile.TemporaryDirectory()
    >>> for i in range(3):
    ...     mosaic = np.full((4, 4), 10 * i, dtype=np.uint8)
    ...     _ = write_frame(Path(tmp.name) / f"frame_{i}.png", Frame(mosaic, layout="imx250mzr"))
    >>> with open_camera(f"replay:{tmp.name}") as camera:
    ...     camera.start()
    ...     for frame in camera.frames(timeout=1.0):
    ...         print(frame.metadata["frame_id"], frame.layout, frame.mosaic.max())
    0 imx250mzr 0
    1 imx250mzr 10
    2 imx250mzr 20
    >>> tmp.cleanup()
    """
    dev = str(device).strip()
    if not dev:
        raise CameraNotFoundError(
            "no camera id given; list the cameras with `polcam devices` "
            "(or use replay:DIR to play a folder of raw frames)"
        )
    for prefix, factory in _BACKENDS.items():
        if dev.startswith(prefix):
            return factory(dev[len(prefix):], **options)
    if not _DEFAULT:
        raise CameraNotFoundError(f"no camera backend for device {dev!r}: expected one of the prefixes "
                                  f"{', '.join(_BACKENDS)} (no default backend is registered)")
    return _DEFAULT[0](dev, **options)

