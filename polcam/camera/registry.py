"""Camera backends by device-id prefix: ``open_camera("replay:DIR")``, ``open_camera("Fake_1")``.

Each backend module registers itself when imported (``polcam.camera``
imports them all): :func:`register_backend` maps a device-id prefix to a
constructor and declares the backend's own command-line flags
(:class:`CameraFlag`) and the camera settings it takes when opened rather than
configured; the backend registered with ``default=True`` takes every id no
prefix claims.  Registered today: ``replay:`` (:mod:`polcam.camera.replay`,
a folder of raw frames played as a camera) and the default, Aravis
(:mod:`polcam.camera.aravis`: GenICam device ids as ``polcam devices`` lists
them; Aravis' GigE Vision emulator, :mod:`polcam.camera.emulator`, shows up
there too).  The commands add every backend's flags
(:func:`polcam.commands._args.add_camera_arguments`) and hand the chosen
backend the values of its own (:func:`backend_for`).

A new backend is one module that subclasses :class:`polcam.camera.base.Camera`
and calls :func:`register_backend`, plus its import in ``polcam/camera/__init__.py``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from polcam.camera.base import CameraNotFoundError

if TYPE_CHECKING:
    from polcam.camera.base import Camera

__all__ = ["Backend", "CameraFlag", "backend_for", "backends", "camera_flags", "open_camera", "register_backend",
           "unregister_backend"]


@dataclass(frozen=True)
class CameraFlag:
    """A command-line flag of a backend, and the constructor keyword it fills.

    Attributes
    ----------
    flag
        The flag (``"--packet-size"``); its value is read from the parsed arguments under
        argparse's name for it (``packet_size``).
    keyword
        The keyword of the backend's constructor it fills (``"packet_size"``).
    help
        Its help text.
    argparse
        Further keywords of ``ArgumentParser.add_argument`` (``type``, ``default``, ``metavar``,
        ``action``).
    convert
        Turns the parsed value into the keyword's value (raising
        :class:`~polcam.camera.base.CameraSettingError` for a bad one); None: as parsed.
    skip_none
        Leave the keyword out when the value is None (the constructor's default applies).
    """

    flag: str
    keyword: str
    help: str
    argparse: Mapping[str, Any] = field(default_factory=dict)
    convert: Callable[[Any], Any] | None = None
    skip_none: bool = False

    @property
    def dest(self) -> str:
        """argparse's attribute name for the flag."""
        return self.flag.lstrip("-").replace("-", "_")


@dataclass(frozen=True)
class Backend:
    """A registered camera backend.

    Attributes
    ----------
    name
        Its name (``"replay"``, ``"aravis"``).
    prefix
        The device-id prefix that selects it (stripped off before ``factory`` sees the id);
        None: the default backend only.
    factory
        ``factory(rest_of_the_id, **options)`` -> a :class:`~polcam.camera.base.Camera`.
    flags
        Its own command-line flags.
    open_settings
        Camera settings (names of ``Camera.configure``'s keywords) it takes as constructor
        keywords instead (replay: ``frame_rate``, its playback rate).
    """

    name: str
    prefix: str | None
    factory: Callable[..., Camera]
    flags: tuple[CameraFlag, ...] = ()
    open_settings: tuple[str, ...] = ()

    def options(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """Constructor keywords from parsed flag values (by argparse name; missing ones are None)."""
        out: dict[str, Any] = {}
        for f in self.flags:
            value = values.get(f.dest)
            if value is None and f.skip_none:
                continue
            out[f.keyword] = f.convert(value) if f.convert is not None and value is not None else value
        for name in self.open_settings:
            out[name] = values.get(name)
        return out


_BACKENDS: dict[str, Backend] = {}
_DEFAULT: list[Backend] = []


def register_backend(prefix: str | None, factory: Callable[..., Camera], *, default: bool = False,
                     name: str | None = None, flags: Sequence[CameraFlag] = (),
                     open_settings: Sequence[str] = ()) -> Backend:
    """Open device ids starting with ``prefix`` (stripped off) with ``factory(rest, **options)``.

    Parameters
    ----------
    prefix
        Device-id prefix, e.g. ``"replay:"`` (``None`` with ``default`` only).
    factory
        Callable taking the id without the prefix and the backend's keyword options.
    default
        Also (or only) the backend for ids no prefix claims.
    name
        The backend's name (default: the prefix without its colon, or the factory's name).
    flags
        The backend's own command-line flags (:class:`CameraFlag`).
    open_settings
        Camera settings it takes as constructor keywords rather than through ``configure``.
    """
    backend = Backend(name or (prefix.rstrip(":") if prefix else getattr(factory, "__name__", "default")),
                      prefix, factory, tuple(flags), tuple(open_settings))
    if prefix:
        _BACKENDS[prefix] = backend
    if default:
        _DEFAULT[:] = [backend]
    return backend


def unregister_backend(prefix: str) -> None:
    """Remove the backend registered for ``prefix``."""
    del _BACKENDS[prefix]


def backends() -> tuple[str, ...]:
    """The registered device-id prefixes (``"*"`` stands for the default backend)."""
    return tuple(_BACKENDS) + (("*",) if _DEFAULT else ())


def camera_flags() -> tuple[CameraFlag, ...]:
    """Every backend's own flags, each flag once: the prefixed backends' first, then the default's."""
    seen: dict[str, CameraFlag] = {}
    for backend in (*_BACKENDS.values(), *_DEFAULT):
        for f in backend.flags:
            seen.setdefault(f.flag, f)
    return tuple(seen.values())


def backend_for(device: str) -> tuple[Backend, str]:
    """The backend a ``--device`` string selects, and the id it is given (the prefix stripped off).

    Raises
    ------
    CameraNotFoundError
        An empty id, or no backend for it.
    """
    dev = str(device).strip()
    if not dev:
        raise CameraNotFoundError(
            "no camera id given; list the cameras with `polcam devices` "
            "(or use replay:DIR to play a folder of raw frames)"
        )
    for prefix, backend in _BACKENDS.items():
        if dev.startswith(prefix):
            return backend, dev[len(prefix):]
    if not _DEFAULT:
        raise CameraNotFoundError(f"no camera backend for device {dev!r}: expected one of the prefixes "
                                  f"{', '.join(_BACKENDS)} (no default backend is registered)")
    return _DEFAULT[0], dev


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
    backend, rest = backend_for(device)
    return backend.factory(rest, **options)
