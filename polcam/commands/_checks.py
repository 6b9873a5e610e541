"""Checks of a command's options before any work: a bad value is exit 2 with nothing created."""

from __future__ import annotations

from polcam import DEMOSAIC_METHODS
from polcam.errors import LayoutError, MethodError
from polcam.mosaic import parse_layout
from polcam.sinks.files import FORMATS

__all__ = ["check_run_options"]


def check_run_options(*, layout: str | None = None, demosaic: str | None = None,
                      resolution: str | None = None, fmt: str | None = None) -> None:
    """Refuse an unknown ``--layout``, ``--demosaic``, ``--resolution`` or ``--format`` up front.

    Raises
    ------
    LayoutError
        ``--layout`` is not a layout name or spelling.
    MethodError
        An unknown demosaicing method, resolution or output format.
    """
    if layout is not None:
        try:
            parse_layout(layout)
        except (LayoutError, ValueError) as exc:
            raise LayoutError(f"--layout {layout!r}: {exc}") from None
    if demosaic is not None:
        if demosaic not in DEMOSAIC_METHODS:
            raise MethodError(f"--demosaic {demosaic!r}: expected one of {', '.join(DEMOSAIC_METHODS)}")
    if resolution is not None and resolution not in ("full", "cell"):
        raise MethodError(f"--resolution {resolution!r}: expected full or cell")
    if fmt is not None:
        if fmt not in FORMATS:
            raise MethodError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
