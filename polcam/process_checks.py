"""The separation of a ``polcam process`` run, resolved before any work: the method and options
against the frames' forms.

Kept apart from :mod:`polcam.process` (which re-exports :func:`check_run` and
:func:`layout_hint`) so the batch module stays about running frames.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from polcam.errors import MethodError, PolcamError
from polcam.io import read_sidecar
from polcam.mosaic import layout_for_format, parse_layout, pixel_format
from polcam.separation import check_options, layout_form, resolve_separation

if TYPE_CHECKING:
    from polcam.process import FrameJob, ProcessOptions
    from polcam.separation import ResolvedSeparation

__all__ = ["check_run", "layout_hint", "separation_for"]


def layout_hint(path: str | os.PathLike[str]) -> Any:
    """The layout a frame's sidecar declares (its ``layout``, else its pixel format's), or ``None``.

    Reads the sidecar only, not the pixels; a sidecar that cannot be read gives ``None`` (the
    frame's own read reports it).
    """
    try:
        side = read_sidecar(path) or {}
        if side.get("layout"):
            return parse_layout(side["layout"])
        if side.get("pixel_format"):
            return layout_for_format(pixel_format(side["pixel_format"], side.get("vendor")))
    except (PolcamError, OSError):
        return None
    return None


def separation_for(opts: ProcessOptions, form: str, *, got: str | None = None) -> ResolvedSeparation:
    """The separation of a run's frames of ``form`` (``"stack"`` or ``"mono-stack"``).

    ``opts.method`` with all of ``opts.method_options``; without a method, the registry's default
    for the form with the options it takes (:func:`check_run` makes sure some method of the run
    takes each).

    Raises
    ------
    MethodError
        An unknown method; an option it does not take or a value not of the option's type; a
        colour-only method for mono frames (``got`` describes them in the message).
    """
    return resolve_separation(opts.method, form, opts.method_options, only_taken=opts.method is None, got=got)


def check_run(opts: ProcessOptions, jobs: Sequence[FrameJob]) -> dict[str, ResolvedSeparation]:
    """Resolve the separation of a run before any work: the method and options against the frames' forms.

    Without ``opts.method`` each frame runs the registry's default for its form (colour stack
    or mono stack); the forms are known from ``opts.layout``, else from the frames' sidecars
    (both forms are assumed where no sidecar says).

    Returns
    -------
    dict
        Input form (``"stack"``, ``"mono-stack"``) -> the :class:`~polcam.separation.ResolvedSeparation`
        of the frames of that form (:func:`polcam.process.run` takes it as it is).  A form whose
        frames a colour-only ``opts.method`` cannot take (known from sidecars only) is left out:
        those frames fail, each with the reason.

    Raises
    ------
    MethodError
        An unknown method; an option the named method does not take, or (no method named)
        that no method of the run takes; an option value not of the option's type; a
        colour-only method with a mono ``--layout``.
    LayoutError
        An unknown ``opts.layout``.
    """
    if opts.layout is not None:
        forms = {layout_form(opts.layout)}
    else:
        hints = [layout_hint(j.input) for j in jobs]
        forms = {layout_form(h) for h in hints if h is not None}
        if not forms or any(h is None for h in hints):
            forms |= {"stack", "mono-stack"}
    if opts.method is not None:
        # a colour stack takes every method: the name and the options are checked whatever the frames are
        named = separation_for(opts, "stack")
        chosen = {"stack": named} if "stack" in forms else {}
        if "mono-stack" in forms:
            if named.spec.mono or opts.layout is not None:  # a mono --layout: refused now
                chosen["mono-stack"] = named.for_form("mono-stack", got=f"mono frames (--layout {opts.layout})")
        return chosen
    chosen = {f: separation_for(opts, f) for f in sorted(forms)}
    for key in opts.method_options:
        if not any(r.takes(key) for r in chosen.values()):
            reasons = []
            for r in sorted(chosen.values(), key=lambda r: r.method):
                try:
                    check_options(r.spec, {key: None}, types=False)
                except MethodError as exc:
                    if str(exc) not in reasons:
                        reasons.append(str(exc))
            used = ", ".join(f"{r.method} for {'colour' if f == 'stack' else 'mono'} frames" for f, r in chosen.items())
            raise MethodError(f"--option {key}: no method of this run ({used}) takes it: {'; '.join(reasons)}")
    return chosen
