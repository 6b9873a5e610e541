"""The per-pixel polarizer model from frames of light through a rotated linear polarizer.

Frames of uniform light through a linear polarizer at M >= 8 known angles
``a`` spread over the half circle (largest gap 45 degrees at most).  After
dark subtraction and flat correction each pixel is fitted by linear least
squares with ``I(a) = c0 + c1 cos 2a + c2 sin 2a`` (the normal equations are
accumulated frame by frame, so memory does not grow with the number of
frames); then ``g ~ c0`` (normalised to mean 1 per colour class),
``D = hypot(c1, c2) / (p c0)`` with ``p`` the calibration light's degree of
polarization, and ``theta = atan2(c2, c1) / 2`` (docs/guide/calibration.md; Hagen
et al. 2019 calibrate from a rotated polarizer likewise).  The fit residual (RMS over frames of the misfit, over
``c0``) and a map of outliers (robust outliers of g, D, theta - nominal and
the residual within each angle/colour class) come with it.

The frames are read and checked as for dark and flat (:mod:`polcam.calibration._series`), with an
optional ``base`` calibration whose dark and flat are applied first and whose maps are carried into
the result.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from polcam.calibration._series import (
    MIN_SIGNAL,
    Frames,
    Stats,
    check_saturation,
    class_index,
    class_mean,
    class_name,
    mosaic_correction,
    new_calibration,
    read_frames,
    robust_sigma,
    stage_info,
)
from polcam.calibration.model import model_from_coefficients, nominal_orientation
from polcam.calibration.store import Calibration, CalibrationError
from polcam.mosaic import ANGLES, Layout

__all__ = ["MAX_ANGLE_GAP_DEG", "MAX_CLASS_OFFSET_DEG", "MIN_ANGLES", "calibrate_polarizer", "check_angles"]

#: Fewest distinct polarizer angles :func:`calibrate_polarizer` accepts.
MIN_ANGLES = 8
#: Largest gap (degrees, on the 180-degree circle) between consecutive polarizer angles.
MAX_ANGLE_GAP_DEG = 45.0
#: Largest |median(theta - nominal)| of an angle class before the angles are deemed mislabelled.
MAX_CLASS_OFFSET_DEG = 20.0

# Floors of the robust spread in the polarizer outlier test: deviations smaller than
# outlier_sigma times these are never outliers, whatever the spread of a very uniform
# (or skewed, like D from extinction ratios) class: gain 1 %, D 0.01, orientation
# 0.5 degree; the residual's floor is 10 % of its median.
_FLOOR_GAIN = 0.01
_FLOOR_D = 0.01
_FLOOR_THETA = 0.5
_FLOOR_RESIDUAL = 0.1
#: Least median diattenuation of the fitted pixels: a polarization sensor's micro-polarizers have D near 1
#: (extinction ratios of tens to hundreds); under this the light was barely polarized (no polarizer in the
#: beam, or a wrong source_dolp).
_MIN_MEDIAN_D = 0.5


def check_angles(angles_deg: Sequence[float], *, min_angles: int = MIN_ANGLES,
                 max_gap_deg: float = MAX_ANGLE_GAP_DEG) -> np.ndarray:
    """Check the polarizer angles of a calibration series.

    Parameters
    ----------
    angles_deg
        One angle per frame, degrees (any real numbers; taken modulo 180).
    min_angles
        Fewest distinct angles (modulo 180, to 0.01 degree).
    max_gap_deg
        Largest allowed gap between consecutive distinct angles on the
        180-degree circle.

    Returns
    -------
    numpy.ndarray
        The angles as float64, one per frame.

    Raises
    ------
    CalibrationError
        Non-finite angles, too few distinct angles, or a gap over ``max_gap_deg``.
    """
    a = np.asarray(angles_deg, dtype=np.float64).ravel()
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"polarizer angles {a.tolist()}: expected finite numbers (degrees)")
    distinct = np.unique(np.round(np.mod(a, 180.0), 2) % 180.0)
    shown = ", ".join(f"{v:g}" for v in distinct[:20]) + (" ..." if distinct.size > 20 else "")
    if distinct.size < min_angles:
        raise CalibrationError(
            f"{distinct.size} distinct polarizer angles ({shown}): expected at least {min_angles}, "
            f"spread over 180 degrees (e.g. every {180 / min_angles:g} degrees)")
    gaps = np.diff(np.concatenate([distinct, [distinct[0] + 180.0]]))
    if gaps.max() > max_gap_deg + 1e-9:
        i = int(np.argmax(gaps))
        raise CalibrationError(
            f"polarizer angles ({shown}) leave a gap of {gaps.max():g} degrees after {distinct[i]:g}: "
            f"expected angles spread over the half circle with gaps of at most {max_gap_deg:g} degrees")
    return a


def calibrate_polarizer(frames: Frames, angles_deg: Sequence[float], *, layout: str | Layout | None = None,
                        base: Calibration | None = None, source_dolp: float = 1.0, zero: str = "polarizer",
                        outlier_sigma: float = 6.0, camera_id: str | None = None,
                        check_settings: bool = True) -> Calibration:
    """Per-pixel gain, diattenuation and orientation from light through a rotated linear polarizer.

    Parameters
    ----------
    frames
        Frames of uniform light through a linear polarizer, in any order
        ((N, H, W) counts or Frames).  Per-pixel precision scales as
        ``1 / sqrt(N * electrons)``: about 0.03 degree and 0.001 in D for
        N = 256 frames of 8000 electrons (docs/guide/calibration.md).
    angles_deg
        The polarizer angle of each frame, degrees, in the image convention of
        :mod:`polcam.polarimetry` (from the image x axis towards the layout's
        45-degree polarizer); at least :data:`MIN_ANGLES` distinct values with
        gaps of at most :data:`MAX_ANGLE_GAP_DEG`.
    layout
        Sensor layout when the frames do not carry one.
    base
        Earlier calibration (dark and flat): applied to the frames first and
        carried into the result.  The gains then describe what the flat
        leaves (mainly the transmission of each polarizer angle).
    source_dolp
        Degree of linear polarization of the calibration light in (0, 1]
        (``(ER - 1) / (ER + 1)`` of the reference polarizer); the fitted
        diattenuation is divided by it.
    zero
        ``"polarizer"``: the angles are exact in the image frame.
        ``"sensor"``: the polarizer's zero is not known to the image axis; the
        mean rotation of all pixels from their nominal angles is removed
        (the micro-polarizer array is taken as right on average).
    outlier_sigma
        Robust standard deviations (within each angle/colour class) beyond
        which a pixel's gain, diattenuation, orientation or fit residual
        marks it an outlier.  The spreads have floors (gain 1 %, D 0.01,
        orientation 0.5 degree, residual 10 % of its median), so with the
        default 6 a pixel is an outlier only if it is off its class's median
        by more than 6 %, 0.06, 3 degrees or 60 % of the median residual.
    camera_id
        Camera identifier to record when neither frames nor ``base`` carry one.
    check_settings
        Refuse frames whose exposure or gain differ from ``base``'s dark.

    Returns
    -------
    Calibration
        With maps ``gain`` (mean 1 per colour class), ``diattenuation``,
        ``orientation_deg`` ([0, 180)), ``residual`` and ``outlier``.

    Raises
    ------
    CalibrationError
        Angles that do not match the frames in number, too few or badly
        spread angles, saturated or inconsistent frames, light that is barely
        polarized (median D under 0.5), or orientations more than 20 degrees
        off the layout's nominal angles in some class (angles measured in
        the opposite sense, or the wrong layout).
    """
    angles = _checked_polarizer_input(angles_deg, zero=zero, source_dolp=source_dolp, outlier_sigma=outlier_sigma)
    stats, coef, resid, offset = _fit_sinusoids(frames, angles, layout=layout, base=base,
                                                check_settings=check_settings)
    c0 = coef[0]
    scale, dia, theta = model_from_coefficients(c0, coef[1], coef[2], source_dolp=source_dolp)
    lay, (h, w) = stats.layout, stats.shape
    known_bad = _known_bad(base, c0)
    good = ~known_bad
    _check_polarizer_signal(c0, dia, good, stats.white_level - float(np.median(offset)))
    classes = class_index(lay, h, w)
    theta, delta, common, offsets = _orientation(theta, lay, classes, good, zero)
    gain = scale / class_mean(scale, class_index(lay, h, w, angle=False), good)
    outlier = _polarizer_outliers((gain, dia, delta, resid), classes, good, known_bad, outlier_sigma)
    gain = np.where(np.isfinite(gain), gain, 0.0)
    maps = {"gain": gain.astype(np.float32), "diattenuation": dia.astype(np.float32),
            "orientation_deg": np.where(theta >= 180.0, 0.0, theta).astype(np.float32),
            "residual": resid.astype(np.float32), "outlier": outlier}
    return _polarizer_calibration(
        stats, base, camera_id, angles, maps, source_dolp=source_dolp, zero=zero, common_rotation_deg=common,
        outlier_sigma=outlier_sigma, statistics=_polarizer_statistics(gain, dia, delta, resid, outlier, offsets))


def _polarizer_calibration(stats: Stats, base: Calibration | None, camera_id: str | None, angles: np.ndarray,
                           maps: dict[str, np.ndarray], **stage: Any) -> Calibration:
    """The calibration: ``base``'s maps and the frames' metadata, the polarizer ``maps`` and its stage record."""
    cal = new_calibration(stats, base)
    if cal.camera_id is None:
        cal.camera_id = camera_id
    cal.maps.update(maps)
    distinct = np.unique(np.round(np.mod(angles, 180.0), 2) % 180.0)
    statistics = stage.pop("statistics")
    cal.stages["polarizer"] = stage_info(
        stats, angles_deg=[float(a) for a in distinct], **stage,
        after_dark=bool(base and base.has("dark")), after_flat=bool(base and base.has("flat")),
        statistics=statistics)
    cal.__post_init__()
    return cal


def _checked_polarizer_input(angles_deg: Sequence[float], *, zero: str, source_dolp: float,
                             outlier_sigma: float) -> np.ndarray:
    """The options of :func:`calibrate_polarizer` checked, and its angles as float64 (degrees, one per frame)."""
    if zero not in ("polarizer", "sensor"):
        raise CalibrationError(f"zero {zero!r}: expected 'polarizer' or 'sensor'")
    if not (0 < source_dolp <= 1):
        raise CalibrationError(f"source_dolp {source_dolp!r}: expected a number in (0, 1]")
    if not outlier_sigma > 0:
        raise CalibrationError(f"outlier_sigma {outlier_sigma!r}: expected a positive number")
    angles = np.asarray(angles_deg, dtype=np.float64).ravel()
    if not np.all(np.isfinite(angles)):
        raise CalibrationError(f"polarizer angles {angles.tolist()}: expected finite numbers (degrees)")
    check_angles(angles)
    return angles


def _fit_sinusoids(frames: Frames, angles: np.ndarray, *, layout: str | Layout | None, base: Calibration | None,
                   check_settings: bool) -> tuple[Stats, np.ndarray, np.ndarray, np.ndarray | float]:
    """Per pixel, the least-squares fit ``I(a) = c0 + c1 cos 2a + c2 sin 2a`` to the corrected frames.

    The normal equations are accumulated frame by frame (memory does not grow with the number of
    frames).  Returns the series' statistics, the coefficients (3, H, W), the fit residual (H, W:
    RMS over frames of the misfit, over ``c0``; 0 where ``c0 <= 0``) and the dark offset that was
    subtracted (a map or a number).
    """
    rad = np.deg2rad(angles)
    ata = np.zeros((3, 3))
    aty: np.ndarray | None = None
    yy: np.ndarray | None = None
    offset: np.ndarray | float = 0.0
    flat: np.ndarray | float = 1.0
    stats: Stats | None = None
    for i, counts, _frame, stats in read_frames(frames, layout=layout, base=base, what="polarizer",
                                                 check_settings=check_settings):
        if i >= angles.size:
            raise CalibrationError(f"more frames than polarizer angles ({angles.size} given): "
                                   "expected one angle per frame")
        if aty is None:
            offset, flat = mosaic_correction(base, stats)
            aty = np.zeros((3,) + counts.shape)
            yy = np.zeros(counts.shape)
        y = (counts - offset) / flat
        row = np.array([1.0, math.cos(2 * rad[i]), math.sin(2 * rad[i])])
        ata += np.outer(row, row)
        aty[0] += y
        aty[1] += row[1] * y
        aty[2] += row[2] * y
        yy += y * y  # type: ignore[operator]
    assert stats is not None and aty is not None and yy is not None
    if stats.count != angles.size:
        raise CalibrationError(f"{stats.count} frames but {angles.size} polarizer angles: "
                               "expected one angle per frame")
    check_saturation(stats, "polarizer")
    h, w = stats.shape
    coef = np.linalg.solve(ata, aty.reshape(3, -1)).reshape(3, h, w)
    n = stats.count
    rss = yy - np.einsum("khw,khw->hw", coef, aty)  # sum (y - A c)^2 = y.y - c.A^T y
    rss = np.maximum(rss, 0.0)
    c0 = coef[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        resid = np.where(c0 > 0, np.sqrt(rss / max(n - 3, 1)) / np.where(c0 > 0, c0, 1.0), 0.0)
    return stats, coef, resid, offset


def _check_polarizer_signal(c0: np.ndarray, dia: np.ndarray, good: np.ndarray, span: float) -> None:
    """Refuse polarizer frames too dark for the fit, or light barely polarized (median D of good pixels)."""
    if not float(np.median(c0)) > MIN_SIGNAL * span:
        raise CalibrationError(
            f"polarizer frames too dark: median signal {float(np.median(c0)):.4g} counts, expected at "
            f"least 2% of the range ({MIN_SIGNAL * span:.4g})")
    med_d = float(np.median(dia[good])) if good.any() else 0.0
    if med_d < _MIN_MEDIAN_D:
        raise CalibrationError(
            f"calibration light barely polarized: median diattenuation {med_d:.3f} (expected near 1 for a "
            "polarization sensor): is the polarizer in the beam, and source_dolp right?")


def _orientation(theta: np.ndarray, lay: Layout, classes: np.ndarray, good: np.ndarray,
                 zero: str) -> tuple[np.ndarray, np.ndarray, float, dict[str, float]]:
    """Orientation (degrees), its offset from nominal in [-90, 90), the common rotation removed, class offsets.

    With ``zero="sensor"`` the circular mean of the good pixels' offsets is removed (the
    micro-polarizer array is taken as right on average); otherwise nothing (0).  The median offset
    of each angle/colour class is checked by :func:`_class_offsets`.
    """
    nominal = nominal_orientation(lay, *theta.shape)
    delta = _wrap90(theta - nominal)
    common = 0.0
    if zero == "sensor":
        common = _circular_mean_deg(delta[good])
        theta = np.mod(theta - common, 180.0)
        delta = _wrap90(theta - nominal)
    return theta, delta, common, _class_offsets(delta, classes, good, lay)


def _known_bad(base: Calibration | None, c0: np.ndarray) -> np.ndarray:
    """(H, W) bool: hot or dead in ``base``, or no signal (``c0 <= 0``)."""
    known_bad = np.zeros(c0.shape, dtype=bool)
    if base is not None:
        for key in ("hot", "dead"):
            if key in base.maps:
                known_bad |= base.maps[key]
    known_bad |= ~(c0 > 0)
    return known_bad


def _class_offsets(delta: np.ndarray, classes: np.ndarray, good: np.ndarray, lay: Layout) -> dict[str, float]:
    """Median orientation offset from nominal of each angle/colour class; a class off by more than
    :data:`MAX_CLASS_OFFSET_DEG` raises (angles in the opposite sense, offset, or the wrong layout)."""
    offsets = {}
    for k in np.unique(classes):
        sel = (classes == k) & good
        med = float(np.median(delta[sel])) if sel.any() else 0.0
        offsets[class_name(lay, int(k))] = med
        if abs(med) > MAX_CLASS_OFFSET_DEG:
            raise CalibrationError(
                f"pixels of the {class_name(lay, int(k))}-degree class face {ANGLES[int(k) % 4] + med:.1f} "
                f"degrees (median), {med:+.1f} from nominal: expected within {MAX_CLASS_OFFSET_DEG:g}. "
                f"Are the polarizer angles measured in the opposite sense, offset (try zero='sensor'), "
                f"or is the layout ({lay}) wrong?")
    return offsets


def _polarizer_outliers(maps: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], classes: np.ndarray,
                        good: np.ndarray, known_bad: np.ndarray, outlier_sigma: float) -> np.ndarray:
    """(H, W) bool: known bad, or a robust outlier of its class in gain, D, orientation or (above) residual.

    ``maps`` is (gain, diattenuation, orientation offset, residual); the robust spreads have the
    floors ``_FLOOR_*`` (the residual's: ``_FLOOR_RESIDUAL`` of its class median).
    """
    gain, dia, delta, resid = maps
    outlier = known_bad.copy()
    for k in np.unique(classes):
        sel = (classes == k) & good
        if not sel.any():
            continue
        res_floor = _FLOOR_RESIDUAL * float(np.median(resid[sel]))
        for vals, floor, one_sided in ((gain, _FLOOR_GAIN, False), (dia, _FLOOR_D, False),
                                       (delta, _FLOOR_THETA, False), (resid, res_floor, True)):
            v = vals[sel]
            med = np.median(v)
            s = max(robust_sigma(v), floor, 1e-9)
            z = (vals - med) / s
            hit = (z > outlier_sigma) if one_sided else (np.abs(z) > outlier_sigma)
            outlier |= hit & (classes == k)
    return outlier


def _polarizer_statistics(gain: np.ndarray, dia: np.ndarray, delta: np.ndarray, resid: np.ndarray,
                          outlier: np.ndarray, offsets: dict[str, float]) -> dict[str, Any]:
    """The polarizer stage's summary over the pixels that are not outliers."""
    ok = ~outlier
    return {
        "orientation_offset_deg": offsets,
        "orientation_spread_deg": float(np.std(delta[ok])) if ok.any() else 0.0,
        "diattenuation_median": float(np.median(dia[ok])) if ok.any() else 0.0,
        "extinction_ratio_median": float((1 + np.median(dia[ok])) / max(1 - np.median(dia[ok]), 1e-9))
        if ok.any() else 0.0,
        "gain_spread": float(np.std(gain[ok])) if ok.any() else 0.0,
        "residual_median": float(np.median(resid[ok])) if ok.any() else 0.0,
        "outliers": int(outlier.sum()),
    }


def _wrap90(d: np.ndarray) -> np.ndarray:
    """Angle differences (degrees) wrapped to [-90, 90)."""
    return np.mod(np.asarray(d, dtype=np.float64) + 90.0, 180.0) - 90.0


def _circular_mean_deg(d: np.ndarray) -> float:
    """Mean of axial angle differences (period 180 degrees), degrees in [-90, 90)."""
    r = np.deg2rad(2.0 * np.asarray(d, dtype=np.float64))
    return float(np.rad2deg(math.atan2(float(np.sin(r).mean()), float(np.cos(r).mean()))) / 2.0)
