"""Applying a calibration: mosaic corrections, then the polarimetric correction.

Where each correction runs (docs/architecture.md draws the stages):

1. On the raw mosaic, before demosaicing (:func:`apply_calibration`): the dark
   map is subtracted (the frame's black level when there is none), the
   result divided by the flat, and defective pixels (hot, dead, polarizer-fit
   outliers) replaced by the mean of their nearest good neighbours of the same
   angle and colour (:func:`fill_defects`).
2. The polarimetric correction needs the four angles at one location.  Two
   places are offered:

   ``"mosaic"`` (default of :func:`apply_calibration`)
       per 2x2 super-pixel, on the mosaic: the four pixels of each cell, with
       their own g, D and theta, give the least-squares Stokes vector of the
       cell (its analysis matrix), and the four pixels are replaced by what
       ideal polarizers at the nominal angles would read for it, plus the
       unexplained part on the (I0 + I90) - (I45 + I135) axis
       (:func:`polcam.calibration.model.correction_matrices`).  At cell
       resolution (``demosaic(..., resolution="cell")``) the Stokes vector of
       each cell is then exactly its analysis-matrix estimate; at full
       resolution any demosaicing method follows unchanged.  For colour
       layouts each 2x2 polarizer cell sits under one colour filter, so the
       same per-cell correction applies.
   ``"stack"`` (:func:`correct_stack`, after demosaicing)
       per output pixel: the three coefficient maps ``g/2``,
       ``g D cos 2theta / 2``, ``g D sin 2theta / 2`` are demosaiced bilinearly
       like the image, which gives each interpolated angle value the model of
       the pixels it was interpolated from (exact for bilinear demosaicing of a
       locally uniform scene), and each pixel's 4x3 matrix is inverted.

docs/guide/calibration.md compares the two (docs/benchmarks.md has the figures).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam.calibration.model import (
    cell_view,
    correction_matrices,
    from_cells,
    measurement_rows,
)
from polcam.calibration.store import Calibration, CalibrationError
from polcam.demosaicing import demosaic
from polcam.errors import PolcamError
from polcam.frame import Frame
from polcam.mosaic import ANGLES, Layout

__all__ = ["POLARIMETRIC", "apply_calibration", "correct_stack", "effective_model", "fill_defects"]

#: Where :func:`apply_calibration` may run the polarimetric correction.
POLARIMETRIC: tuple[str, ...] = ("mosaic", "none")

_STRIP_VALUES = 1 << 17  # pixel-channels per strip in correct_stack


def fill_defects(values: np.ndarray, defects: np.ndarray, layout: Layout, *, passes: int = 4) -> np.ndarray:
    """Replace defective pixels by the mean of their good same-class neighbours.

    The neighbours are the 8 pixels of the same angle and colour one pattern
    period away (2 pixels for mono, 4 for colour; mirrored at the borders).
    Clusters are filled from the outside in (``passes`` rounds); what is left
    gets the median of the good pixels of its class.

    Parameters
    ----------
    values
        (H, W) mosaic (any real dtype).
    defects
        (H, W) bool, True where ``values`` is not to be trusted.
    layout
        Layout of the mosaic.

    Returns
    -------
    numpy.ndarray
        (H, W) float64 copy with the defects filled.
    """
    out = np.asarray(values, dtype=np.float64).copy()
    bad = np.asarray(defects, dtype=bool).copy()
    if not bad.any():
        return out
    h, w = out.shape
    p = layout.period
    offsets = [(dy, dx) for dy in (-p, 0, p) for dx in (-p, 0, p) if (dy, dx) != (0, 0)]
    for _ in range(passes):
        if not bad.any():
            break
        good = ~bad
        pv = np.pad(np.where(good, out, 0.0), p, mode="reflect")
        pg = np.pad(good.astype(np.float64), p, mode="reflect")
        total = np.zeros_like(out)
        count = np.zeros_like(out)
        for dy, dx in offsets:
            total += pv[p + dy:p + dy + h, p + dx:p + dx + w]
            count += pg[p + dy:p + dy + h, p + dx:p + dx + w]
        fill = bad & (count > 0)
        out[fill] = total[fill] / count[fill]
        bad &= ~fill
    if bad.any():
        classes = layout.angle_index(h, w) + 4 * layout.channel_index(h, w)
        for k in np.unique(classes[bad]):
            ref = ~bad & (classes == k) & ~np.asarray(defects, dtype=bool)
            out[bad & (classes == k)] = float(np.median(out[ref])) if ref.any() else 0.0
    return out


def effective_model(calibration: Calibration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The polarizer model used for correction: defective pixels get their class's median model.

    Returns
    -------
    gain, diattenuation, orientation_deg
        (H, W) float64 maps.

    Raises
    ------
    CalibrationError
        The calibration has no polarizer stage.
    """
    cached = calibration._cache.get("model")
    if cached is not None:
        return cached
    if not calibration.has("polarizer"):
        raise CalibrationError("no polarizer calibration in this file (run polcam calibrate polarizer)",
                               path=calibration.source)
    h, w = calibration.shape
    lay = calibration.layout
    gain = calibration.maps["gain"].astype(np.float64)
    dia = calibration.maps["diattenuation"].astype(np.float64)
    theta = calibration.maps["orientation_deg"].astype(np.float64)
    bad = calibration.defects() | ~(gain > 0)
    if bad.any():
        classes = lay.angle_index(h, w) + 4 * lay.channel_index(h, w)
        gain, dia, theta = gain.copy(), dia.copy(), theta.copy()
        for k in np.unique(classes[bad]):
            ref = (classes == k) & ~bad
            sel = (classes == k) & bad
            nominal = float(ANGLES[int(k) % 4])
            if ref.any():
                gain[sel] = float(np.median(gain[ref]))
                dia[sel] = float(np.median(dia[ref]))
                d = np.deg2rad(2.0 * (theta[ref] - nominal))
                mean = np.rad2deg(np.arctan2(np.sin(d).mean(), np.cos(d).mean())) / 2.0
                theta[sel] = np.mod(nominal + mean, 180.0)
            else:
                gain[sel], dia[sel], theta[sel] = 1.0, 1.0, nominal
    calibration._cache["model"] = (gain, dia, theta)
    return gain, dia, theta


def _cell_matrices(calibration: Calibration) -> np.ndarray:
    cached = calibration._cache.get("cell_matrices")
    if cached is not None:
        return cached
    gain, dia, theta = effective_model(calibration)
    h, w = calibration.shape
    angles = np.asarray(calibration.layout.angles, dtype=np.float64)
    mats = np.empty((h // 2, w // 2, 4, 4), dtype=np.float32)
    step = max(2, 2 * (_STRIP_VALUES // max(w, 1)))  # mosaic rows per strip (even)
    for r0 in range(0, h, step):
        r1 = min(h, r0 + step)
        rows = cell_view(measurement_rows(gain[r0:r1], dia[r0:r1], theta[r0:r1]))   # (cells, Wc, 4, 3)
        mats[r0 // 2:r1 // 2] = correction_matrices(rows, angles)
    calibration._cache["cell_matrices"] = mats
    return mats


def apply_calibration(frame: Frame | np.ndarray, calibration: Calibration, *, polarimetric: str = "mosaic",
                      check_settings: bool = True) -> Frame:
    """Correct a raw frame: dark, flat, defective pixels and (by default) the polarizer model.

    Parameters
    ----------
    frame
        The raw frame (a bare (H, W) array of counts is taken to have the
        calibration's layout, bit depth and levels).  A frame without a
        layout gets the calibration's.
    calibration
        A calibration of this camera at this geometry (and, for its dark, at
        this exposure and gain).
    polarimetric
        ``"mosaic"``: the per-super-pixel polarimetric correction on the
        mosaic (module docstring); ``"none"``: mosaic corrections only (for
        :func:`correct_stack` after demosaicing).  Ignored without a
        polarizer stage.
    check_settings
        Refuse a frame whose exposure, gain or bit depth differ from the
        dark's.

    Returns
    -------
    Frame
        ``mosaic`` float32 (H, W): corrected counts above the dark (not
        clipped, so noise may dip below 0); ``black_level`` 0 and
        ``white_level`` the frame's ``white_level - black_level``, so
        ``normalized()`` and :func:`polcam.demosaicing.demosaic` give linear
        values on the same [0, 1] scale as the uncalibrated frame; the same
        layout, and ``metadata["calibration"]`` saying what was applied.

    Raises
    ------
    CalibrationError
        A frame of another size, layout, camera, ROI, or (with a dark and
        ``check_settings``) exposure, gain or bit depth; an unknown
        ``polarimetric``.
    """
    if polarimetric not in POLARIMETRIC:
        raise CalibrationError(f"polarimetric {polarimetric!r}: expected one of {', '.join(POLARIMETRIC)}")
    if not isinstance(frame, Frame):
        arr = np.asarray(frame)
        if arr.ndim != 2:
            raise CalibrationError(f"raw mosaic of shape {arr.shape}: expected a 2-D (H, W) array of counts")
        frame = Frame(arr, layout=calibration.layout, bit_depth=calibration.bit_depth,
                      black_level=calibration.black_level or 0.0, white_level=calibration.white_level)
    lay = calibration.check_frame(frame, check_settings=check_settings)
    x = np.asarray(frame.mosaic, dtype=np.float64)
    if calibration.has("dark"):
        x = x - calibration.maps["dark"]
    else:
        x = x - float(frame.black_level)
    if calibration.has("flat"):
        x = x / calibration.maps["flat"]
    defects = calibration.defects()
    if defects.any():
        x = fill_defects(x, defects, lay)
    done = list(calibration.applied_stages)
    where = None
    if calibration.has("polarizer") and polarimetric == "mosaic":
        mats = _cell_matrices(calibration)
        cells = cell_view(x.astype(np.float32))
        x = from_cells(np.einsum("...ij,...j->...i", mats, cells))
        where = "mosaic (per 2x2 super-pixel)"
    elif calibration.has("polarizer"):
        done.remove("polarizer")
    # the frame's own scale, so calibrated and uncalibrated results share one [0, 1] scale
    span = float(frame.white_level) - float(frame.black_level)
    if not span > 0:
        raise CalibrationError(f"white level {frame.white_level} is not above black level {frame.black_level}",
                               path=calibration.source)
    meta: dict[str, Any] = dict(frame.metadata)
    meta["calibration"] = {
        "file": calibration.source, "stages": done, "polarimetric": where,
        "defects_filled": int(defects.sum()), "created": calibration.created,
    }
    return Frame(np.ascontiguousarray(x, dtype=np.float32), layout=lay, bit_depth=frame.bit_depth,
                 black_level=0.0, white_level=span, metadata=meta)


def _stack_model(calibration: Calibration, resolution: str) -> np.ndarray:
    """Per-pixel (and channel) 4x3 measurement matrices of a demosaiced stack, float32.

    Shape (h, w, 4, 3) for mono, (h, w, 3, 4, 3) for colour.
    """
    key = f"stack_model_{resolution}"
    cached = calibration._cache.get(key)
    if cached is not None:
        return cached

    gain, dia, theta = effective_model(calibration)
    rows = measurement_rows(gain, dia, theta).astype(np.float32)    # (H, W, 3)
    coef = [demosaic(np.ascontiguousarray(rows[..., j]), layout=calibration.layout, method="bilinear",
                     resolution=resolution) for j in range(3)]       # each (4, h, w[, 3])
    w = np.stack(coef, axis=-1)                                       # (4, h, w[, 3], 3)
    w = np.moveaxis(w, 0, -2)                                         # (h, w[, 3], 4, 3)
    w = np.ascontiguousarray(w, dtype=np.float32)
    calibration._cache[key] = w
    return w


def correct_stack(stack: np.ndarray, calibration: Calibration, *, resolution: str = "full") -> np.ndarray:
    """Polarimetric correction of a demosaiced stack, pixel by pixel.

    Use after ``apply_calibration(frame, cal, polarimetric="none")`` and
    :func:`polcam.demosaicing.demosaic`.  Each pixel's four angle values are
    inverted through the 4x3 matrix of the coefficient maps demosaiced
    bilinearly at the same ``resolution`` (module docstring), and replaced by
    the ideal-polarizer values of the estimated Stokes vector plus the
    unexplained part on the residual axis.  For a mono stack at cell
    resolution this equals the per-super-pixel correction exactly.

    Parameters
    ----------
    stack
        (4, h, w) mono or (4, h, w, 3) RGB stack, angles 0, 45, 90, 135,
        linear (any scale); (h, w) is the calibration's size
        (``resolution="full"``) or half of it (``"cell"``).
    calibration
        A calibration with a polarizer stage.
    resolution
        ``"full"`` or ``"cell"``, as passed to ``demosaic``.

    Returns
    -------
    numpy.ndarray
        float32 stack of the input's shape.

    Raises
    ------
    CalibrationError
        No polarizer stage, or a stack whose shape does not fit the
        calibration's size, layout and ``resolution``.
    """
    if resolution not in ("full", "cell"):
        raise CalibrationError(f"resolution {resolution!r}: expected 'full' or 'cell'")
    arr = np.asarray(stack)
    lay = calibration.layout
    h, w = calibration.shape
    if resolution == "cell":
        h, w = h // 2, w // 2
    want = (4, h, w, 3) if lay.is_color else (4, h, w)
    if arr.shape != want:
        raise CalibrationError(
            f"stack of shape {arr.shape}: expected {want} for layout {lay} at {resolution} resolution "
            f"of a {calibration.width}x{calibration.height} calibration", path=calibration.source)
    if not np.issubdtype(arr.dtype, np.floating) and not np.issubdtype(arr.dtype, np.integer):
        raise CalibrationError(f"stack of dtype {arr.dtype}: expected numbers")
    try:
        model = _stack_model(calibration, resolution)
    except PolcamError as exc:  # pragma: no cover - demosaic refuses only sizes checked above
        raise CalibrationError(str(exc), path=calibration.source) from exc
    x = np.moveaxis(arr, 0, -1)                                       # (h, w[, 3], 4)
    out = np.empty(x.shape, dtype=np.float32)
    angles = np.asarray(ANGLES, dtype=np.float64)
    per_row = int(np.prod(x.shape[1:-1]))
    step = max(1, _STRIP_VALUES // max(per_row, 1))
    for r0 in range(0, h, step):
        r1 = min(h, r0 + step)
        mats = correction_matrices(model[r0:r1].astype(np.float64), angles)
        out[r0:r1] = np.einsum("...ij,...j->...i", mats, x[r0:r1].astype(np.float64))
    return np.ascontiguousarray(np.moveaxis(out, -1, 0))
