"""Checks of a ``polcam process`` run before any work: the method and options against the frames' forms.

Kept apart from :mod:`polcam.process` (which re-exports :func:`check_run` and
:func:`layout_hint`) so the batch module stays about running frames.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from polcam.errors import PolcamError

if TYPE_CHECKING:
    from polcam.process import FrameJob, ProcessOptions

__all__ = ["check_run", "layout_hint"]


def _takes(method: str, option: str) -> bool:
    from polcam.errors import MethodError
    from polcam.separation._registry import check_options

    try:
        check_options(method, {option: None}, types=False)
    except MethodError:
        return False
    return True


def layout_hint(path: str | os.PathLike[str]) -> Any:
    """The layout a frame's sidecar declares (its ``layout``, else its pixel format's), or ``None``.

    Reads the sidecar only, not the pixels; a sidecar that cannot be read gives ``None`` (the
    frame's own read reports it).
    """
    from polcam.io import read_sidecar
    from polcam.mosaic import layout_for_format, parse_layout, pixel_format

    try:
        side = read_sidecar(path) or {}
        if side.get("layout"):
            return parse_layout(side["layout"])
        if side.get("pixel_format"):
            return layout_for_format(pixel_format(side["pixel_format"], side.get("vendor")))
    except (PolcamError, OSError):
        return None
    return None


def check_run(opts: ProcessOptions, jobs: Sequence[FrameJob]) -> dict[str, str]:
    """Check the method and options against the frames before any work; the method per input form.

    Without ``opts.method`` each frame runs the registry's default for its form (colour stack
    or mono stack); the forms are known from ``opts.layout``, else from the frames' sidecars
    (both forms are assumed where no sidecar says).

    Returns
    -------
    dict
        Input form (``"stack"``, ``"mono-stack"``) -> method of the frames of that form.

    Raises
    ------
    MethodError
        An unknown method; an option the named method does not take, or (no method named)
        that no method of the run takes; an option value not of the option's type; a
        colour-only method with a mono ``--layout``.
    LayoutError
        An unknown ``opts.layout``.
    """
    from polcam.errors import MethodError
    from polcam.mosaic import parse_layout
    from polcam.separation import default_method, method_spec, methods
    from polcam.separation._registry import check_options

    if opts.layout is not None:
        lay = parse_layout(opts.layout)
        forms = {"stack" if lay.is_color else "mono-stack"}
    else:
        hints = [layout_hint(j.input) for j in jobs]
        forms = {"stack" if h.is_color else "mono-stack" for h in hints if h is not None}
        if not forms or any(h is None for h in hints):
            forms |= {"stack", "mono-stack"}
    if opts.method is not None:
        spec = method_spec(opts.method)
        check_options(opts.method, dict(opts.method_options))
        if opts.layout is not None and forms == {"mono-stack"} and not spec.mono:
            mono = ", ".join(m for m in methods() if method_spec(m).mono)
            raise MethodError(f"--method {opts.method}: it needs colour frames and --layout {opts.layout} is "
                              f"a mono layout; for mono frames use one of {mono}")
        return {f: opts.method for f in sorted(forms)}
    chosen = {f: default_method(f) for f in sorted(forms)}
    for key in opts.method_options:
        if not any(_takes(m, key) for m in chosen.values()):
            reasons = []
            for m in sorted(set(chosen.values())):
                try:
                    check_options(m, {key: None}, types=False)
                except MethodError as exc:
                    reasons.append(str(exc))
            used = ", ".join(f"{m} for {'colour' if f == 'stack' else 'mono'} frames" for f, m in chosen.items())
            raise MethodError(f"--option {key}: no method of this run ({used}) takes it: {'; '.join(reasons)}")
        for m in sorted(set(chosen.values())):
            if _takes(m, key):
                check_options(m, {key: opts.method_options[key]})
    return chosen
