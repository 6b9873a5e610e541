"""The registry of demosaicing methods and the :func:`demosaic` dispatcher.

A method module registers ``fn(mosaic (H, W) float32, layout) -> stack`` with
:func:`register`; :func:`demosaic` checks the input once (layout, size, dtype,
values) and calls it.  :func:`to_float` (raw counts to linear floats) and
:func:`mosaic_stack` (the forward model: what a sensor of a layout records of a
full stack) live here too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from polcam._names import lookup, ordered
from polcam.demosaicing._lattice import bilinear_cells
from polcam.errors import FrameReadError, LayoutError, MethodError
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout

__all__ = ["DemosaicFn", "MethodSpec", "RESOLUTIONS", "default_method", "demosaic", "method_spec",
           "methods", "mosaic_stack", "register", "to_float"]

#: ``fn(mosaic (H, W) float32, layout) -> stack`` (full or cell resolution).
DemosaicFn = Callable[[np.ndarray, Layout], np.ndarray]

#: Output resolutions :func:`demosaic` accepts.
RESOLUTIONS: tuple[str, ...] = ("full", "cell")


@dataclass(frozen=True)
class MethodSpec:
    """A registered demosaicing method.

    Attributes
    ----------
    name
        Registry name.
    fn
        Full resolution: ``fn(mosaic (H, W) float32, layout) -> (4, H, W)`` for a
        mono layout, ``(4, H, W, 3)`` for a colour one, float32.
    cell
        The method's own ``resolution="cell"`` path (same signature, H and W
        halved); ``None``: bilinear interpolation between cells.
    mono, color
        Whether the method accepts mono / colour layouts.
    reference
        Citation of the published method it follows (docs/methods/demosaic-<name>.md has the
        details and the departures).
    """

    name: str
    fn: DemosaicFn
    cell: DemosaicFn | None = None
    mono: bool = True
    color: bool = True
    reference: str = ""


_METHODS: dict[str, MethodSpec] = {}

# The order methods() lists methods in (registered methods not listed here follow, sorted).
_ORDER = ("bilinear", "eari", "lmmse")

#: The method :func:`demosaic` runs when none is named, per kind of layout: the best
#: polcam has (docs/decisions/default-demosaicing.md says why; docs/benchmarks.md has the figures); process,
#: capture and the demo use the same.  Colour: ``lmmse``, the best method on the real
#: stacks on every metric and within the 1 s budget per 2448 x 2048 frame (the
#: validation set ranks the slower ``lmmse-eari`` blend first).
_DEFAULTS = {"color": "lmmse", "mono": "eari"}


def register(name: str, *, cell: DemosaicFn | None = None, mono: bool = True, color: bool = True,
             reference: str = "") -> Callable[[DemosaicFn], DemosaicFn]:
    """Decorator registering a full-resolution demosaicing function under ``name``.

    ``cell`` optionally gives the method's own ``resolution="cell"`` path; without it
    the cells are interpolated bilinearly.
    """

    def deco(fn: DemosaicFn) -> DemosaicFn:
        _METHODS[name] = MethodSpec(name, fn, cell, mono, color, reference)
        return fn

    return deco


def methods() -> tuple[str, ...]:
    """Registered method names, in polcam's canonical order."""
    return ordered(_METHODS, _ORDER)


def method_spec(name: str) -> MethodSpec:
    """The :class:`MethodSpec` of ``name``; :class:`MethodError` if unknown."""
    return lookup(_METHODS, name, what="demosaicing method", order=_ORDER)


def default_method(layout: str | Layout) -> str:
    """The method :func:`demosaic` runs for ``layout`` when none is named."""
    return _DEFAULTS["color" if parse_layout(layout).is_color else "mono"]


def to_float(raw: np.ndarray | Frame, *, black_level: float = 0.0,
             white_level: float | None = None) -> np.ndarray:
    """A mosaic as linear float32 ``(raw - black) / (white - black)``.

    Integer input without ``white_level`` is scaled by its dtype's full range
    (a 16-bit container is full-range 16-bit); float input is taken as already
    normalised unless levels are given.

    Raises
    ------
    FrameReadError
        Not a 2-D array, NaN or infinite values, a dtype that is neither
        integer nor float, or a white level not above the black level.
    """
    if isinstance(raw, Frame):
        black = float(raw.black_level)
        span = float(raw.white_level) - black  # type: ignore[arg-type]
        if span <= 0:
            return raw.normalized()  # its error names the levels
        out = np.asarray(raw.mosaic).astype(np.float32)  # Frame.normalized's arithmetic, in place
        out -= np.float32(black)
        out /= np.float32(span)
        return out
    arr = np.asarray(raw)
    if arr.ndim != 2:
        raise FrameReadError(f"raw mosaic of shape {arr.shape}: expected a 2-D (H, W) array")
    if np.issubdtype(arr.dtype, np.integer):
        white = float(np.iinfo(arr.dtype).max) if white_level is None else float(white_level)
    elif np.issubdtype(arr.dtype, np.floating):
        if not np.all(np.isfinite(arr)):
            raise FrameReadError("raw mosaic contains NaN or infinite values")
        white = 1.0 if white_level is None else float(white_level)
    else:
        raise FrameReadError(f"raw mosaic of dtype {arr.dtype}: expected integers or floats")
    span = white - float(black_level)
    if span <= 0:
        raise FrameReadError(f"white level {white} is not above black level {black_level}")
    if arr.dtype == np.float32 and black_level == 0 and span == 1.0:
        return np.ascontiguousarray(arr)
    out = arr.astype(np.float32)  # in place from here: one full-size array
    if black_level != 0:
        out -= np.float32(black_level)
    out /= np.float32(span)
    return out


def demosaic(
    raw: np.ndarray | Frame,
    *,
    layout: str | Layout | None = None,
    method: str | None = None,
    resolution: str = "full",
) -> np.ndarray:
    """Demosaic a polarization mosaic into a stack of four angle images.

    Parameters
    ----------
    raw
        (H, W) mosaic: integers (scaled by the dtype's range), floats already
        in [0, 1], or a :class:`~polcam.frame.Frame` (scaled by its black and
        white levels, its layout used when ``layout`` is not given).
    layout
        Sensor layout name or :class:`~polcam.mosaic.Layout`.
    method
        A registered method name (:func:`methods`); ``None``: the best method for
        the layout, :func:`default_method`.
    resolution
        ``"full"``: one output pixel per input pixel; ``"cell"``: one per 2x2
        polarizer cell (H and W halved).

    Returns
    -------
    numpy.ndarray
        float32 stack, (4, H, W) for mono or (4, H, W, 3) RGB for colour
        (H, W halved with ``resolution="cell"``), angles 0, 45, 90, 135; linear,
        on the scale of the normalised input, not clipped: the interpolation
        overshoots [0, 1] near edges (eari reaches -0.11 and 1.12 on the
        synthetic fixture frame), and the Stokes maps are computed from the
        values as they are.  :func:`polcam.separate` takes it as it is and
        clips to [0, 1] itself (docs/decisions/input-range.md).

    Raises
    ------
    LayoutError
        No layout, an unknown one, or a mosaic whose size does not fit it (odd,
        or smaller than two periods of the pattern).
    MethodError
        Unknown ``method`` or ``resolution``, or a method that does not take
        this kind of layout (mono/colour).
    FrameReadError
        A raw array that is not a finite 2-D integer or float array.

    Examples
    --------
    Uniform light on an 8 x 8 ``imx250mzr`` mosaic (cell ``90 45 / 135 0``):

    >>> import numpy as np
    >>> import polcam
    >>> raw = np.tile([[0.1, 0.3], [0.5, 0.7]], (4, 4))
    >>> stack = polcam.demosaic(raw, layout="imx250mzr")
    >>> stack.shape, stack.dtype
    ((4, 8, 8), dtype('float32'))
    >>> stack[:, 4, 4]  # I0, I45, I90, I135 of one pixel
    array([0.7, 0.3, 0.1, 0.5], dtype=float32)
    >>> polcam.demosaic(raw, layout="imx250mzr", resolution="cell").shape
    (4, 4, 4)
    """
    if layout is None:
        if isinstance(raw, Frame) and raw.layout is not None:
            layout = raw.layout
        else:
            raise LayoutError("no layout given: pass layout= (e.g. 'imx250mzr' or 'imx250myr')")
    lay = parse_layout(layout)
    spec = method_spec(default_method(lay) if method is None else method)
    if not (spec.color if lay.is_color else spec.mono):
        kind = "colour" if lay.is_color else "mono"
        takes = [m for m in methods() if (_METHODS[m].color if lay.is_color else _METHODS[m].mono)]
        raise MethodError(f"demosaicing method {spec.name!r} does not take {kind} layouts such as {lay}; "
                          f"{kind} methods: {', '.join(takes)}")
    if resolution not in RESOLUTIONS:
        raise MethodError(f"resolution {resolution!r}: expected 'full' or 'cell'")
    img = to_float(raw)
    h, w = img.shape
    p = lay.period
    if h < 2 * p or w < 2 * p or h % 2 or w % 2:
        raise LayoutError(
            f"mosaic of {w}x{h} pixels: expected even dimensions of at least {2 * p} "
            f"for layout {lay}"
        )
    if resolution == "cell":
        return (spec.cell or bilinear_cells)(img, lay)
    return spec.fn(img, lay)


def mosaic_stack(stack: np.ndarray, *, layout: str | Layout) -> np.ndarray:
    """Sample a full-resolution stack the way a sensor of ``layout`` does.

    Parameters
    ----------
    stack
        (4, H, W) for a mono layout or (4, H, W, 3) RGB for a colour layout,
        angle order 0, 45, 90, 135.
    layout
        Sensor layout name or :class:`~polcam.mosaic.Layout`.

    Returns
    -------
    numpy.ndarray
        (H, W) mosaic of the stack's dtype: pixel (y, x) holds the stack's value at
        the angle (and colour) the layout puts there.

    Raises
    ------
    MethodError
        A stack whose shape does not match the layout (mono/colour).
    """
    lay = parse_layout(layout)
    arr = np.asarray(stack)
    want = 4 if lay.is_color else 3
    if arr.ndim != want or arr.shape[0] != 4 or (lay.is_color and arr.shape[-1] != 3):
        kind = "(4, H, W, 3) RGB" if lay.is_color else "(4, H, W)"
        raise MethodError(f"stack of shape {arr.shape}: expected {kind} for layout {lay}")
    h, w = arr.shape[1:3]
    ai = lay.angle_index(h, w)
    yy, xx = np.indices((h, w))
    if lay.is_color:
        return arr[ai, yy, xx, lay.channel_index(h, w)]
    return arr[ai, yy, xx]
