"""The per-frame pipeline: Frame -> calibration -> stack -> Stokes products -> layers.

One module owns every step a frame goes through after it is read, whoever
asks: ``polcam process`` (:mod:`polcam.process`), ``polcam stokes``,
``polcam demo`` and the live view of ``polcam capture``
(:mod:`polcam.acquisition.live`).

- :func:`calibrate` applies a calibration to the raw mosaic (dark, flat,
  defective pixels, the per-super-pixel polarimetric correction).
- :func:`to_stack` demosaics a frame into the stack of four angle images
  (:func:`polcam.demosaic`), at full or polarizer-cell resolution.
- :func:`products` computes the Stokes products of a stack (``s0`` is
  S0 = (I0 + I45 + I90 + I135) / 2; DoLP in [0, 1]; AoLP in [0, pi)).
- :func:`separate_layers` runs a separation method on the stack clipped to
  [0, 1] (diffuse and specular on the scale of one polarization image).
- :func:`run_frame` chains them and times each step.  The Stokes maps are
  computed once per frame: a separation method that takes a precomputed
  sinusoid fit (its ``fit`` option, e.g. ``wen21``) gets the one made in the
  same pass over the stack as the products.
- :func:`live_maps` is the live view's cheaper route to the same quantities
  at the polarizer-cell resolution (a few fused OpenCV passes over the four
  angle planes, no float stack): S0/2, DoLP, AoLP and the ``imin`` layers.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from polcam import polarimetry as st
from polcam.calibration import apply_calibration
from polcam.demosaicing import default_method
from polcam.demosaicing import demosaic as _demosaic  # the one demosaic import of the pipeline
from polcam.errors import LayoutError
from polcam.frame import Frame
from polcam.mosaic import Layout
from polcam.separation import ResolvedSeparation, input_form, resolve_separation, separate

if TYPE_CHECKING:
    from polcam.calibration.store import Calibration
    from polcam.demosaicing import ResolvedDemosaic
    from polcam.separation import ResolvedSeparation, Separation

__all__ = [
    "PRODUCTS",
    "FrameResult",
    "LiveMaps",
    "calibrate",
    "default_demosaic",
    "live_maps",
    "products",
    "require_layout",
    "run_frame",
    "separate_layers",
    "to_stack",
]

#: Every Stokes product :func:`products` computes, and what it is.
PRODUCTS: dict[str, str] = {
    "i000": "the 0-degree image", "i045": "the 45-degree image",
    "i090": "the 90-degree image", "i135": "the 135-degree image",
    "s0": "S0 = (I0 + I45 + I90 + I135) / 2", "s1": "S1 = I0 - I90", "s2": "S2 = I45 - I135",
    "dolp": "degree of linear polarization, [0, 1]",
    "aolp": "angle of linear polarization, radians in [0, pi) from the image x axis",
    "residual": "fit residual (I0 + I90) - (I45 + I135)",
}


# ---------------------------------------------------------------------------
# the full route
# ---------------------------------------------------------------------------

def require_layout(frame: Frame, path: str | None = None) -> Frame:
    """``frame`` if it has a layout, else the :class:`LayoutError` every command gives (naming the file)."""
    if frame.layout is None:
        where = path if path is not None else frame.metadata.get("path")
        raise LayoutError("no layout: the file has no sidecar saying it; give --layout "
                          "(imx250mzr, imx250myr, mono:A,B,C,D or color:A,B,C,D:BAYER)", path=where)
    return frame


def calibrate(frame: Frame, calibration: Calibration | None) -> Frame:
    """``frame`` corrected by ``calibration`` (dark, flat, defects, polarimetric on the mosaic), or itself.

    Raises
    ------
    CalibrationError
        The frame does not fit the calibration (size, layout, camera, ROI,
        mirroring; exposure, gain or bit depth of a dark).
    """
    if calibration is None:
        return frame
    return apply_calibration(frame, calibration, polarimetric="mosaic")


def default_demosaic(layout: str | Layout) -> str:
    """The demosaicing method for ``layout`` where none is named: the demosaicing registry's
    default (:func:`polcam.demosaicing.default_method`), the same for process, stokes, capture
    and the demo."""
    return default_method(layout)


def to_stack(frame: Frame, *, layout: str | Layout | None = None, demosaic: str | ResolvedDemosaic | None = None,
             resolution: str = "full") -> np.ndarray:
    """Demosaic ``frame`` into a float32 stack (4, H, W) mono or (4, H, W, 3) RGB (halved at ``cell``).

    ``demosaic``: the demosaicing method, a name, a :class:`~polcam.demosaicing.ResolvedDemosaic`
    or ``None`` (:func:`default_demosaic` of the frame's layout).  Linear values on the scale of
    the normalised frame (not clipped).
    """
    kwargs: dict[str, Any] = {"resolution": resolution, "method": demosaic}
    if layout is not None:
        kwargs["layout"] = layout
    return _demosaic(frame, **kwargs)


def products(stack: np.ndarray, names: Iterable[str] = tuple(PRODUCTS)) -> dict[str, np.ndarray]:
    """The Stokes products ``names`` (keys of :data:`PRODUCTS`) of a (4, ...) stack, each of its trailing shape."""
    names = tuple(names)
    unknown = [n for n in names if n not in PRODUCTS]
    if unknown:
        raise ValueError(f"unknown products {unknown}: expected names among {', '.join(PRODUCTS)}")
    m = st.maps(stack, [n for n in names if not n.startswith("i")])
    views = ("i000", "i045", "i090", "i135")
    return {name: stack[views.index(name)] if name.startswith("i") else m[name] for name in names}


def separate_layers(stack: np.ndarray, *, method: str | ResolvedSeparation | None = None,
                    options: Mapping[str, Any] | None = None) -> Separation:
    """Diffuse and specular layers of a stack by ``method`` (a name, a
    :class:`~polcam.separation.ResolvedSeparation`, or None: the registry's default).

    :func:`polcam.separate` clips the stack to [0, 1] (recorded in ``info``).
    """
    return separate(stack, method=method, **dict(options or {}))


def _products_and_fit(stack: np.ndarray, names: tuple[str, ...]) -> tuple[dict[str, np.ndarray], st.Sinusoid]:
    """:func:`products` and the float64 fit (Ic, Isv) of the stack clipped to [0, 1], in one pass:
    the fit a method would compute from what :func:`separate_layers` hands it."""
    m, f = st.maps_together(stack, {"names": [n for n in names if not n.startswith("i")]},
                            {"names": ("ic", "isv"), "dtype": np.float64, "clip": (0.0, 1.0)})
    views = ("i000", "i045", "i090", "i135")
    out = {name: stack[views.index(name)] if name.startswith("i") else m[name] for name in names}
    return out, st.Sinusoid(f["ic"], f["isv"], None)  # type: ignore[arg-type]  # phi: not needed


@dataclass
class FrameResult:
    """What :func:`run_frame` made of one frame.

    Attributes
    ----------
    frame
        The frame the stack was computed from (calibrated when a calibration was given).
    stack
        (4, H, W) or (4, H, W, 3) float32.
    products
        The Stokes products asked for, then ``diffuse`` and ``specular`` when
        a separation ran ((H, W) or (H, W, 3) float32).
    separation
        The separation's result (its ``info``), or ``None``.
    timings
        Seconds of each step: ``calibrate``, ``demosaic``, ``stokes``, ``separate``.
    """

    frame: Frame
    stack: np.ndarray
    products: dict[str, np.ndarray]
    separation: Separation | None = None
    timings: dict[str, float] = field(default_factory=dict)


def run_frame(frame: Frame, *, calibration: Calibration | None = None, layout: str | Layout | None = None,
              demosaic: str | ResolvedDemosaic | None = None, resolution: str = "full",
              stokes_products: Iterable[str] = ("s0", "dolp", "aolp"), separate: bool = False,
              method: str | ResolvedSeparation | None = None,
              method_options: Mapping[str, Any] | None = None) -> FrameResult:
    """A frame through the whole pipeline: calibration, demosaicing, Stokes products, separation.

    Parameters
    ----------
    frame
        The raw frame (its layout used unless ``layout`` is given).
    calibration
        Applied to the mosaic first, or ``None``.
    layout, demosaic, resolution
        As :func:`to_stack` (``demosaic``: the demosaicing method).
    stokes_products
        Stokes products to compute (keys of :data:`PRODUCTS`).
    separate
        Also run the separation: ``method`` (the separation method: a name, a
        :class:`~polcam.separation.ResolvedSeparation`, or ``None``: the
        registry's default for the stack's form) with ``method_options``.

    Returns
    -------
    FrameResult
    """
    timings: dict[str, float] = {}
    t = time.perf_counter()
    frame = calibrate(frame, calibration)
    timings["calibrate"] = time.perf_counter() - t
    t = time.perf_counter()
    stack = to_stack(frame, layout=layout, demosaic=demosaic, resolution=resolution)
    timings["demosaic"] = time.perf_counter() - t
    t = time.perf_counter()
    sep = _resolved(stack.shape, method, method_options) if separate else None
    if sep is not None and "fit" not in sep.options and sep.takes("fit"):
        # a method that takes a precomputed sinusoid fit gets the one made in the pass that makes the maps
        names = tuple(stokes_products)
        unknown = [n for n in names if n not in PRODUCTS]
        if unknown:
            raise ValueError(f"unknown products {unknown}: expected names among {', '.join(PRODUCTS)}")
        out, fit = _products_and_fit(stack, names)
        sep = sep.with_options(fit=fit)
    else:
        out = products(stack, stokes_products)
    timings["stokes"] = time.perf_counter() - t
    res = None
    if sep is not None:
        t = time.perf_counter()
        res = separate_layers(stack, method=sep)
        timings["separate"] = time.perf_counter() - t
        out["diffuse"], out["specular"] = res.diffuse, res.specular
    return FrameResult(frame=frame, stack=stack, products=out, separation=res, timings=timings)


def _resolved(shape: tuple[int, ...], method: str | ResolvedSeparation | None,
              options: Mapping[str, Any] | None) -> ResolvedSeparation:
    """The separation of a stack of ``shape``: ``method`` as resolved (``options`` added), or resolved
    here for the stack's form."""
    form = input_form(shape)
    if isinstance(method, ResolvedSeparation):
        sep = method if method.form == form else method.for_form(form)
        return sep.with_options(**options) if options else sep
    return resolve_separation(method, form, options)


# ---------------------------------------------------------------------------
# the live route: polarizer-cell maps in a few fused OpenCV passes
# ---------------------------------------------------------------------------

_BAYER_TO_RGB = {
    "RGGB": cv2.COLOR_BayerRGGB2RGB,
    "BGGR": cv2.COLOR_BayerBGGR2RGB,
    "GRBG": cv2.COLOR_BayerGRBG2RGB,
    "GBRG": cv2.COLOR_BayerGBRG2RGB,
}


@dataclass
class LiveMaps:
    """Polarization maps of one frame at the polarizer-cell resolution (h, w = H/2, W/2).

    ``ic``, ``diffuse`` and ``specular`` are stored as values; multiply by
    :attr:`scale` for linear values normalised by the white level
    (:meth:`normalized`).  Mono sensors: float32 with ``scale == 1``.
    Colour sensors: uint8 display values with ``scale == 1 / 255`` (they come
    out of OpenCV's integer Bayer interpolation; the live view needs 8 bits).

    Attributes
    ----------
    ic
        Ic = S0 / 2, the mean over the four angles, above black: (h, w) mono
        or (h, w, 3) RGB; normalised values in [0, 1] within the levels.
    dolp
        DoLP in [0, 1], float32 (h, w).  Colour: of the luminance-weighted
        Stokes vector (R + 2G + B) / 4.
    aolp
        AoLP in radians, [0, pi), float32 (h, w); colour: as ``dolp``.
    diffuse
        Imin = Ic - Isv clipped at 0 (the ``imin`` separation), like ``ic``.
    specular
        Ic - diffuse, like ``ic``.
    scale
        Factor from stored values to normalised values.
    """

    ic: np.ndarray
    dolp: np.ndarray
    aolp: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    scale: float = 1.0

    def normalized(self, name: str) -> np.ndarray:
        """Map ``name`` (``ic``, ``diffuse``, ``specular``) as float32 normalised values."""
        arr = getattr(self, name)
        if self.scale == 1.0 and arr.dtype == np.float32:
            return arr
        return (arr.astype(np.float32) * np.float32(self.scale)).astype(np.float32)


def _cell_stokes(mosaic: np.ndarray, layout: Layout, black: float, *, blurred: bool = False
                 ) -> tuple[np.ndarray, ...]:
    """(S0 above black, S1, S2) float32 (H/2, W/2) of every polarizer cell of a mosaic, in one pass
    (:func:`polcam._cell_kernels.cell_stokes`); with ``blurred`` also the three under the 3 x 3
    binomial filter (:func:`polcam._cell_kernels.binomial3`), six arrays in all."""
    from polcam import _cell_kernels  # numba: imported on first use

    cell = layout.angle_index(2, 2)
    rows, cols = np.empty(4, dtype=np.int64), np.empty(4, dtype=np.int64)
    for r in range(2):
        for c in range(2):
            rows[int(cell[r, c])], cols[int(cell[r, c])] = r, c
    s = _cell_kernels.cell_stokes(np.ascontiguousarray(mosaic), rows, cols, float(np.float32(-2.0 * black)))
    return (*s, *(_cell_kernels.binomial3(a) for a in s)) if blurred else s


def _scale(a: np.ndarray, factor: float, offset: float = 0.0, dtype: int = cv2.CV_32F) -> np.ndarray:
    """``a * factor + offset`` in one OpenCV pass (saturating for integer ``dtype``)."""
    return cv2.addWeighted(a, float(factor), a, 0.0, float(offset), dtype=dtype)


def _orientation(s0: np.ndarray, s1: np.ndarray, s2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(|(S1, S2)|, DoLP clipped to [0, 1], AoLP in [0, pi)) of single-channel float32 maps: the
    fused kernel of :func:`polcam.polarimetry.maps`, the same as every other route."""
    m = st.maps_from_stokes(st.Stokes(s0, s1, s2), ("isv", "dolp", "aolp"))
    mag = m["isv"]
    mag *= np.float32(2.0)  # |(S1, S2)| = 2 Isv exactly
    return mag, m["dolp"], m["aolp"]


def live_maps(mosaic: np.ndarray, layout: Layout, *, black_level: float = 0.0,
              white_level: float | None = None) -> LiveMaps:
    """Ic, DoLP, AoLP and the Imin layers of a raw mosaic at the polarizer-cell resolution.

    Each 2x2 polarizer cell gives one sample per angle: one compiled pass
    over the mosaic sums them into S0, S1 and S2 (:mod:`polcam._cell_kernels`),
    then a few OpenCV passes and the fused DoLP/AoLP kernel make the maps,
    without building a float stack.

    Mono sensors: exactly ``polcam.polarimetry`` (``stokes``, ``dolp``, ``aolp``,
    ``imin``) of ``polcam.demosaic(..., resolution="cell")`` up to float32
    rounding (DoLP and AoLP by the same fused kernel, :func:`polcam.polarimetry.maps`),
    and the ``imin`` separation of that stack.

    Colour sensors (each angle's cell image is a Bayer mosaic): Ic, Imin and
    the specular part are computed per colour sample, rounded to 8 bits and
    interpolated by OpenCV's bilinear Bayer demosaicing; DoLP and AoLP are
    those of the luminance-weighted Stokes vector, (R + 2G + B) / 4, which
    the 3x3 binomial filter ``[1 2 1]^T [1 2 1] / 16`` gives at every Bayer
    phase.  Where colour is locally uniform these equal the per-channel
    values of the full method (to 8 bits); at colour edges they are the live
    view's approximation (the saved frames are exact).

    Parameters
    ----------
    mosaic
        (H, W) raw counts, H and W even: uint8 or uint16 as the camera sent
        them, or float32 / float64 (a corrected mosaic, e.g.
        :func:`polcam.calibration.apply_calibration`'s: counts above the dark,
        possibly negative by noise; float64 is converted to float32).
    layout
        Layout of the mosaic.
    black_level, white_level
        Counts of black and saturation (white default: the integer dtype's
        maximum; a float mosaic needs it).

    Returns
    -------
    LiveMaps
        Maps of (H/2, W/2) pixels.

    Raises
    ------
    LayoutError
        A mosaic that is not 2-D uint8/uint16/float with even sizes of at
        least two layout periods, a float mosaic without ``white_level``, or
        levels with white <= black.
    """
    if mosaic.ndim != 2 or mosaic.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise LayoutError(f"mosaic of shape {mosaic.shape} and dtype {mosaic.dtype}: "
                          "expected 2-D uint8/uint16 counts (or float32 corrected counts)")
    h, w = mosaic.shape
    if h % 2 or w % 2 or h < 2 * layout.period or w < 2 * layout.period:
        raise LayoutError(f"mosaic of {w}x{h} pixels: expected even sizes of at least {2 * layout.period}")
    if mosaic.dtype.kind == "f":
        if white_level is None:
            raise LayoutError(f"{mosaic.dtype} mosaic without a white level: expected white_level in counts")
        mosaic = np.asarray(mosaic, dtype=np.float32)
    white = float(np.iinfo(mosaic.dtype).max) if white_level is None else float(white_level)
    black = float(black_level)
    span = white - black
    if span <= 0:
        raise LayoutError(f"white level {white} is not above black level {black}")
    # S0 above black, S1, S2 (counts); colour: also their luminance-weighted values (R + 2G + B) / 4
    s0c, s1, s2, *lum = _cell_stokes(mosaic, layout, black, blurred=layout.is_color)
    if not layout.is_color:
        mag, dolp, aolp = _orientation(s0c, s1, s2)
        ic = _scale(s0c, 0.5 / span)
        diffuse = cv2.max(_scale(cv2.subtract(s0c, mag), 0.5 / span), 0.0)  # (S0 - |S12|) / 2
        specular = cv2.subtract(ic, diffuse)
        return LiveMaps(ic=ic, dolp=dolp, aolp=aolp, diffuse=diffuse, specular=specular)
    # colour: per-sample Ic and Imin in 8 bits, then Bayer interpolation
    code = _BAYER_TO_RGB[layout.bayer]  # type: ignore[index]
    to8 = 0.5 * 255.0 / span
    diffuse_c = cv2.max(cv2.subtract(s0c, cv2.magnitude(s1, s2)), 0.0)  # 2 Imin, counts
    ic = cv2.cvtColor(_scale(s0c, to8, 0.0, cv2.CV_8U), code)
    diffuse = cv2.cvtColor(_scale(diffuse_c, to8, 0.0, cv2.CV_8U), code)
    specular = cv2.subtract(ic, diffuse)
    _, dolp, aolp = _orientation(*lum)
    return LiveMaps(ic=ic, dolp=dolp, aolp=aolp, diffuse=diffuse, specular=specular, scale=1.0 / 255.0)
