"""Errors raised by polcam.

Every error about bad input derives from :class:`PolcamError`, itself a
:class:`ValueError`, and its message names the file (when there is one), the
offending value and what was expected.
"""

from __future__ import annotations

from os import PathLike

__all__ = [
    "PolcamError",
    "LayoutError",
    "PixelFormatError",
    "FrameReadError",
    "FrameWriteError",
    "MethodError",
    "CameraUnavailableError",
]


class PolcamError(ValueError):
    """Base class of polcam's input errors.

    Parameters
    ----------
    message
        What was wrong and what was expected.
    path
        The file concerned, if any; it is prefixed to the message.
    """

    def __init__(self, message: str, *, path: str | PathLike[str] | None = None) -> None:
        self.path = None if path is None else str(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class LayoutError(PolcamError):
    """A sensor layout name or geometry that polcam cannot use."""


class PixelFormatError(PolcamError):
    """An unknown or unsupported GenICam pixel format."""


class FrameReadError(PolcamError):
    """A raw frame that cannot be read (truncated, empty, wrong size, ...)."""


class FrameWriteError(PolcamError):
    """An output that cannot be written (bad array, unwritable folder, full disk)."""


class MethodError(PolcamError):
    """An unknown method name or an input shape the method does not accept."""


class CameraUnavailableError(RuntimeError):
    """The camera stack (Aravis) or the requested camera is not available."""
