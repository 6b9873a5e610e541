"""Making a calibration from frames: dark, flat field and the per-pixel polarizer model.

:func:`calibrate_dark`
    N frames with the lens capped at the exposure and gain to be corrected:
    the per-pixel mean (the dark level, black level included), its temporal
    standard deviation, and a map of hot, cold and noisy pixels: robust
    outliers (median and MAD) of the dark level against its 7x7 local median,
    and of the temporal noise.
:func:`calibrate_flat`
    N frames of uniform, unpolarized light: the mean after dark subtraction,
    divided by its mean over each (angle, colour) class of pixels, so the flat
    corrects pixel-to-pixel gain (and lens vignetting) without touching the
    balance between polarizer angles, which is the polarizer model's business
    (a slightly polarized flat source would otherwise be written into the
    gains).  Dead pixels: gain under half the local median, or a robust outlier.
:func:`calibrate_polarizer`
    Frames of uniform light through a linear polarizer at M >= 8 known angles
    ``a`` spread over the half circle (largest gap 45 degrees at most).  After
    dark subtraction and flat correction each pixel is fitted by linear least
    squares with ``I(a) = c0 + c1 cos 2a + c2 sin 2a`` (the normal equations are
    accumulated frame by frame, so memory does not grow with the number of
    frames); then ``g ~ c0`` (normalised to mean 1 per colour class),
    ``D = hypot(c1, c2) / (p c0)`` with ``p`` the calibration light's degree of
    polarization, and ``theta = atan2(c2, c1) / 2`` (docs/calibration.md; Hagen
    et al. 2019 calibrate from a rotated polarizer likewise).  The fit residual (RMS over frames of the misfit, over
    ``c0``) and a map of outliers (robust outliers of g, D, theta - nominal and
    the residual within each angle/colour class) come with it.

Every function takes frames as :class:`polcam.frame.Frame` objects or arrays of
counts (an (N, H, W) array, or a sequence), and an optional ``base``
calibration whose dark (and flat) are applied to the frames first and whose
maps are carried into the result, so ``dark -> flat -> polarizer`` builds one
file.  Bad input (too few frames or angles, frames of different sizes,
layouts, cameras or settings, saturated or too dark frames) raises
:class:`~polcam.calibration.store.CalibrationError` naming the frame and the
values.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from polcam.calibration.model import model_from_coefficients, nominal_orientation
from polcam.calibration.store import Calibration, CalibrationError, utc_now
from polcam.frame import Frame
from polcam.mosaic import ANGLES, Layout, parse_layout

__all__ = [
    "DARK_MAX_LEVEL",
    "MIN_ANGLES",
    "MAX_ANGLE_GAP_DEG",
    "calibrate_dark",
    "calibrate_flat",
    "calibrate_polarizer",
    "check_angles",
    "class_index",
    "robust_sigma",
]

#: Fewest distinct polarizer angles :func:`calibrate_polarizer` accepts.
MIN_ANGLES = 8
#: Largest gap (degrees, on the 180-degree circle) between consecutive polarizer angles.
MAX_ANGLE_GAP_DEG = 45.0
#: Largest |median(theta - nominal)| of an angle class before the angles are deemed mislabelled.
MAX_CLASS_OFFSET_DEG = 20.0

FrameLike = Frame | np.ndarray
Frames = Iterable[FrameLike] | np.ndarray

_MAD_TO_SIGMA = 1.482602218505602
# Floors of the robust spread in the polarizer outlier test: deviations smaller than
# outlier_sigma times these are never outliers, whatever the spread of a very uniform
# (or skewed, like D from extinction ratios) class: gain 1 %, D 0.01, orientation
# 0.5 degree; the residual's floor is 10 % of its median.
_FLOOR_GAIN = 0.01
_FLOOR_D = 0.01
_FLOOR_THETA = 0.5
_LOCAL = 7  # window of the local medians, pixels


def robust_sigma(x: np.ndarray) -> float:
    """Standard deviation estimated as 1.4826 times the median absolute deviation (NaN-free input)."""
    x = np.asarray(x, dtype=np.float64).ravel()
    if x.size == 0:
        return 0.0
    return float(_MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


def class_index(layout: Layout, height: int, width: int, *, angle: bool = True) -> np.ndarray:
    """Class of every pixel: ``angle_index + 4 channel`` (``angle=False``: colour channel only).

    Returns
    -------
    numpy.ndarray
        (height, width) int array; values in 0..11 (colour), 0..3 (mono), or 0..2
        / 0 without the angle.
    """
    ch = layout.channel_index(height, width)
    if not angle:
        return ch
    return layout.angle_index(height, width) + 4 * ch


def _class_mean(values: np.ndarray, classes: np.ndarray, good: np.ndarray) -> np.ndarray:
    """Per-pixel mean of ``values`` over the good pixels of its class (1 where a class has none)."""
    n = int(classes.max()) + 1
    sums = np.bincount(classes[good], weights=values[good], minlength=n)
    counts = np.bincount(classes[good], minlength=n)
    means = np.where(counts > 0, sums / np.maximum(counts, 1), 1.0)
    return means[classes]


# ---------------------------------------------------------------------------
# frames
# ---------------------------------------------------------------------------

@dataclass
class _Stats:
    """What a stage learnt about its frames while reading them."""

    layout: Layout
    shape: tuple[int, int]
    bit_depth: int
    black_level: float
    white_level: float
    camera_id: str | None = None
    exposure_us: float | None = None
    gain_db: float | None = None
    roi: list[int] | None = None
    reverse_x: bool | None = None
    reverse_y: bool | None = None
    count: int = 0
    saturated: int = 0
    names: list[str] = field(default_factory=list)


def _as_frames(frames: Frames) -> Iterator[FrameLike]:
    if isinstance(frames, np.ndarray):
        if frames.ndim == 2:
            yield frames
            return
        if frames.ndim != 3:
            raise CalibrationError(f"frames array of shape {frames.shape}: expected (N, H, W) counts")
        yield from frames
        return
    if isinstance(frames, Frame):
        yield frames
        return
    yield from frames


def _frame_name(frame: FrameLike, i: int) -> str:
    if isinstance(frame, Frame) and frame.metadata.get("path"):
        return str(frame.metadata["path"])
    return f"frame {i}"


def _read_frames(frames: Frames, *, layout: str | Layout | None, base: Calibration | None,
                 what: str, check_settings: bool) -> Iterator[tuple[int, np.ndarray, Frame, _Stats]]:
    """Yield ``(i, counts float64, frame, stats)`` after checking each frame against the first."""
    lay = None if layout is None else parse_layout(layout)
    stats: _Stats | None = None
    for i, item in enumerate(_as_frames(frames)):
        name = _frame_name(item, i)
        if isinstance(item, Frame):
            frame = item
        else:
            arr = np.asarray(item)
            if arr.ndim != 2 or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
                raise CalibrationError(f"{name}: array of shape {arr.shape} and dtype {arr.dtype}: "
                                       "expected a 2-D mosaic of counts")
            depth = base.bit_depth if base is not None else (8 if arr.dtype == np.uint8 else 16)
            black = base.black_level if base is not None and base.black_level is not None else 0.0
            white = base.white_level if base is not None and base.white_level is not None else None
            frame = Frame(arr, layout=lay, bit_depth=depth, black_level=black, white_level=white)
        counts = np.asarray(frame.mosaic, dtype=np.float64)
        if counts.ndim != 2:
            raise CalibrationError(f"{name}: mosaic of shape {counts.shape}: expected (H, W)")
        if not np.all(np.isfinite(counts)):
            raise CalibrationError(f"{name}: mosaic holds NaN or infinite values")
        flay = lay or frame.layout or (base.layout if base is not None else None)
        if flay is None:
            raise CalibrationError(f"{name}: no layout: give layout= (--layout), e.g. imx250mzr or imx250myr")
        if lay is not None and frame.layout is not None and frame.layout != lay:
            # an explicit layout overrides what the file said, as everywhere in polcam
            frame = Frame(frame.mosaic, layout=lay, bit_depth=frame.bit_depth, black_level=frame.black_level,
                          white_level=frame.white_level, metadata=frame.metadata)
        elif frame.layout is None:
            frame = Frame(frame.mosaic, layout=flay, bit_depth=frame.bit_depth, black_level=frame.black_level,
                          white_level=frame.white_level, metadata=frame.metadata)
        h, w = counts.shape
        if h % 2 or w % 2 or h < 2 * flay.period or w < 2 * flay.period:
            raise CalibrationError(f"{name}: mosaic of {w}x{h} pixels: expected even dimensions of at "
                                   f"least {2 * flay.period} for layout {flay}")
        meta = frame.metadata
        if stats is None:
            stats = _Stats(layout=flay, shape=(h, w), bit_depth=int(frame.bit_depth),
                           black_level=float(frame.black_level), white_level=float(frame.white_level),
                           camera_id=None if meta.get("camera_id") is None else str(meta["camera_id"]),
                           exposure_us=_num(meta.get("exposure_us")), gain_db=_num(meta.get("gain_db")),
                           roi=None if meta.get("roi") is None else [int(v) for v in meta["roi"]],
                           reverse_x=meta.get("reverse_x"), reverse_y=meta.get("reverse_y"))
            if base is not None:
                base.check_frame(frame, check_settings=check_settings)
        else:
            _same(name, "size", f"{w}x{h}", f"{stats.shape[1]}x{stats.shape[0]}", (h, w) == stats.shape)
            _same(name, "layout", flay, stats.layout, flay == stats.layout)
            _same(name, "bit_depth", frame.bit_depth, stats.bit_depth, int(frame.bit_depth) == stats.bit_depth)
            cam = meta.get("camera_id")
            _same(name, "camera_id", cam, stats.camera_id,
                  cam is None or stats.camera_id is None or str(cam) == stats.camera_id)
            exp = _num(meta.get("exposure_us"))
            _same(name, "exposure_us", exp, stats.exposure_us,
                  exp is None or stats.exposure_us is None or math.isclose(exp, stats.exposure_us, rel_tol=1e-3))
            gain = _num(meta.get("gain_db"))
            _same(name, "gain_db", gain, stats.gain_db,
                  gain is None or stats.gain_db is None or abs(gain - stats.gain_db) <= 1e-3)
        stats.count += 1
        stats.names.append(name)
        stats.saturated += int(np.count_nonzero(counts >= stats.white_level))
        yield i, counts, frame, stats
    if stats is None:
        raise CalibrationError(f"no frames given for the {what} calibration")


def _check_dark(counts: np.ndarray, stats: _Stats) -> None:
    """Refuse a dark frame whose mean level is more than DARK_MAX_LEVEL of the range above black."""
    mean = float(np.mean(counts))
    span = stats.white_level - stats.black_level
    above = (mean - stats.black_level) / span if span > 0 else 0.0
    if above > DARK_MAX_LEVEL:
        raise CalibrationError(
            f"{stats.names[-1]}: not a dark frame: mean level {mean:.4g} counts, {above:.1%} of the range above "
            f"the black level {stats.black_level:.4g}; expected at most {DARK_MAX_LEVEL:.0%} (cap the lens; a "
            "camera that adds a black level the frames do not declare: give black_level in their sidecars)")


def _num(v: Any) -> float | None:
    return None if v is None else float(v)


def _same(name: str, key: str, got: Any, want: Any, ok: bool) -> None:
    if not ok:
        raise CalibrationError(f"{name}: {key} {got} differs from the first frame's {want}: "
                               "every frame of one calibration must share it")


def _check_saturation(stats: _Stats, what: str, limit: float = 1e-3) -> None:
    total = stats.count * stats.shape[0] * stats.shape[1]
    if total and stats.saturated / total > limit:
        raise CalibrationError(
            f"{what} frames are saturated: {stats.saturated / total:.2%} of the samples reach the white level "
            f"{stats.white_level:g} (expected under {limit:.1%}); lower the exposure or the light")


def _result(stats: _Stats, base: Calibration | None) -> Calibration:
    """A calibration carrying ``base``'s maps and the frames' metadata."""
    if base is not None:
        cal = base.copy()
        cal.source = None
        cal.created = utc_now()
        for key in ("camera_id", "roi", "reverse_x", "reverse_y"):
            if getattr(cal, key) is None and getattr(stats, key) is not None:
                setattr(cal, key, getattr(stats, key))
        return cal
    return Calibration(
        layout=stats.layout, height=stats.shape[0], width=stats.shape[1], bit_depth=stats.bit_depth,
        camera_id=stats.camera_id, exposure_us=stats.exposure_us, gain_db=stats.gain_db,
        black_level=stats.black_level, white_level=stats.white_level, roi=stats.roi,
        reverse_x=stats.reverse_x, reverse_y=stats.reverse_y,
    )


def _stage_info(stats: _Stats, **extra: Any) -> dict[str, Any]:
    info: dict[str, Any] = {
        "frames": stats.count, "exposure_us": stats.exposure_us, "gain_db": stats.gain_db,
        "bit_depth": stats.bit_depth, "black_level": stats.black_level, "white_level": stats.white_level,
    }
    info.update(extra)
    return info


def _mosaic_correction(base: Calibration | None, stats: _Stats) -> tuple[np.ndarray | float, np.ndarray | float]:
    """(offset, flat) to turn counts into dark-subtracted, flat-corrected signal."""
    offset: np.ndarray | float = stats.black_level
    flat: np.ndarray | float = 1.0
    if base is not None and base.has("dark"):
        offset = base.maps["dark"].astype(np.float64)
    if base is not None and base.has("flat"):
        flat = base.maps["flat"].astype(np.float64)
    return offset, flat


def _local_outliers(values: np.ndarray, sigma: float, *, floor: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Robust outliers of ``values`` against their local median: (mask, deviation, robust sigma)."""
    local = ndimage.median_filter(values, size=_LOCAL, mode="reflect")
    dev = values - local
    s = max(robust_sigma(dev), floor)
    return np.abs(dev) > sigma * s, dev, s


# ---------------------------------------------------------------------------
# dark
# ---------------------------------------------------------------------------

#: Largest mean level of a dark frame above its black level, as a share of the range (white level
#: minus black level): a capped sensor reads its black level, dark current and read noise; more
#: than this is light (a lit scene, a lens not capped) or a black level the frame does not declare.
DARK_MAX_LEVEL = 0.05


def calibrate_dark(frames: Frames, *, layout: str | Layout | None = None, base: Calibration | None = None,
                   hot_sigma: float = 6.0, camera_id: str | None = None,
                   check_settings: bool = True) -> Calibration:
    """Dark level, temporal noise and hot-pixel map from frames taken with the lens capped.

    Parameters
    ----------
    frames
        At least 2 dark frames ((N, H, W) counts or Frames) at the exposure,
        gain and bit depth of the frames to be corrected; the precision of
        the dark level is the read noise over sqrt(N) (16 or more recommended).
    layout
        Sensor layout when the frames do not carry one.
    base
        Earlier calibration of the same camera whose maps are carried over
        (its dark, if any, is replaced).
    hot_sigma
        A pixel is hot (or cold) when its dark level is more than ``hot_sigma``
        robust standard deviations from the median of its 7x7 neighbourhood,
        or noisy when its temporal noise exceeds the median noise by
        ``hot_sigma`` robust standard deviations (floors: 0.5 and 0.25
        counts, so a noiseless synthetic sensor flags nothing).
    camera_id
        Camera identifier to record when the frames carry none.
    check_settings
        Check ``base`` against the frames' exposure and gain.

    Returns
    -------
    Calibration
        With maps ``dark`` (float32 counts), ``dark_noise`` (float32 counts)
        and ``hot`` (bool), and the frames' exposure and gain.

    Raises
    ------
    CalibrationError
        Fewer than 2 frames, inconsistent frames, a bad ``hot_sigma``, or a
        frame that is not dark: its mean level more than :data:`DARK_MAX_LEVEL`
        of the range above its black level (the message names the frame and
        its mean level).
    """
    if not hot_sigma > 0:
        raise CalibrationError(f"hot_sigma {hot_sigma!r}: expected a positive number")
    total: np.ndarray | None = None
    total2: np.ndarray | None = None
    stats: _Stats | None = None
    shift = 0.0
    for _, counts, _frame, stats in _read_frames(frames, layout=layout, base=base, what="dark",
                                                 check_settings=False):
        if total is None:
            shift = float(np.median(counts))  # shifted sums keep the variance exact
            total = np.zeros_like(counts)
            total2 = np.zeros_like(counts)
        _check_dark(counts, stats)
        d = counts - shift
        total += d
        total2 += d * d  # type: ignore[operator]
    assert stats is not None and total is not None and total2 is not None
    n = stats.count
    if n < 2:
        raise CalibrationError(f"{n} dark frame given: expected at least 2 (16 or more recommended)")
    mean = total / n
    var = np.maximum(total2 / n - mean * mean, 0.0) * (n / (n - 1))
    dark = mean + shift
    noise = np.sqrt(var)
    level_out, _dev, level_sigma = _local_outliers(dark, hot_sigma, floor=0.5)
    noise_med = float(np.median(noise))
    noise_sigma = max(robust_sigma(noise), 0.25)
    noisy = noise > noise_med + hot_sigma * noise_sigma
    hot = level_out | noisy
    cal = _result(stats, base)
    cal.maps["dark"] = dark.astype(np.float32)
    cal.maps["dark_noise"] = noise.astype(np.float32)
    cal.maps["hot"] = hot
    cal.exposure_us, cal.gain_db, cal.bit_depth = stats.exposure_us, stats.gain_db, stats.bit_depth
    cal.black_level, cal.white_level = stats.black_level, stats.white_level
    if cal.camera_id is None:
        cal.camera_id = camera_id
    good = ~hot
    cal.stages["dark"] = _stage_info(stats, hot_sigma=hot_sigma, statistics={
        "median_counts": float(np.median(dark)),
        "spread_counts": robust_sigma(dark[good]),
        "noise_median_counts": noise_med,
        "hot_pixels": int(hot.sum()),
        "level_outliers": int(level_out.sum()),
        "noisy_pixels": int(noisy.sum()),
        "level_threshold_counts": hot_sigma * level_sigma,
    })
    cal.__post_init__()
    return cal


# ---------------------------------------------------------------------------
# flat
# ---------------------------------------------------------------------------

def calibrate_flat(frames: Frames, *, layout: str | Layout | None = None, base: Calibration | None = None,
                   dead_sigma: float = 6.0, camera_id: str | None = None,
                   check_settings: bool = True) -> Calibration:
    """Per-pixel gain from frames of uniform, unpolarized light.

    Parameters
    ----------
    frames
        Flat frames ((N, H, W) counts or Frames), well exposed (mean at a
        few tens of percent of the range, no saturation).  The gain of each
        pixel has a relative precision of about ``1 / sqrt(N * electrons)``
        (shot noise): 0.3 % per pixel needs on the order of 1e6 electrons
        summed over the frames.
    layout
        Sensor layout when the frames do not carry one.
    base
        Earlier calibration (normally the dark); its dark is subtracted
        (without it, the frames' black level) and its maps are carried over.
    dead_sigma
        Robust standard deviations from the local median beyond which a
        pixel's gain is abnormal (marked ``dead``, like gains under half the
        local median).
    camera_id
        Camera identifier to record when neither frames nor ``base`` carry one.
    check_settings
        Refuse frames whose exposure or gain differ from ``base``'s dark.

    Returns
    -------
    Calibration
        With maps ``flat`` (float32, mean 1 over the good pixels of each
        (angle, colour) class) and ``dead`` (bool).

    Raises
    ------
    CalibrationError
        No frames, inconsistent frames, saturated frames, or a mean signal
        under 2 % of the range.
    """
    if not dead_sigma > 0:
        raise CalibrationError(f"dead_sigma {dead_sigma!r}: expected a positive number")
    total: np.ndarray | None = None
    stats: _Stats | None = None
    for _, counts, _frame, stats in _read_frames(frames, layout=layout, base=base, what="flat",
                                                 check_settings=check_settings):
        total = counts.copy() if total is None else total + counts
    assert stats is not None and total is not None
    _check_saturation(stats, "flat")
    offset, _ = _mosaic_correction(base, stats)
    signal = total / stats.count - offset
    span = stats.white_level - float(np.median(offset))
    level = float(np.median(signal))
    if not level > 0.02 * span:
        raise CalibrationError(
            f"flat frames too dark: median signal {level:.4g} counts above the dark, expected at least "
            f"2% of the range ({0.02 * span:.4g}); raise the exposure or the light")
    h, w = stats.shape
    classes = class_index(stats.layout, h, w)
    hot = base.maps["hot"] if base is not None and base.has("dark") else np.zeros((h, w), dtype=bool)
    good = ~hot & (signal > 0)
    flat = signal / _class_mean(signal, classes, good)
    dead = np.zeros((h, w), dtype=bool)
    for _ in range(2):
        out, _dev, sig = _local_outliers(flat, dead_sigma, floor=1e-4)
        low = flat < 0.5 * ndimage.median_filter(flat, size=_LOCAL, mode="reflect")
        dead = (out | low) & ~hot
        good = ~hot & ~dead & (signal > 0)
        flat = signal / _class_mean(signal, classes, good)
    flat = np.where(np.isfinite(flat) & (flat > 0), flat, 1.0)
    cal = _result(stats, base)
    if cal.camera_id is None:
        cal.camera_id = camera_id
    cal.maps["flat"] = flat.astype(np.float32)
    cal.maps["dead"] = dead
    class_means = {}
    for k in np.unique(classes):
        sel = (classes == k) & good
        class_means[_class_name(stats.layout, int(k))] = float(signal[sel].mean()) if sel.any() else None
    cal.stages["flat"] = _stage_info(stats, dead_sigma=dead_sigma, dark_from_base=bool(base and base.has("dark")),
                                     statistics={
                                         "median_signal_counts": level,
                                         "gain_spread": float(np.std(flat[good])),
                                         "dead_pixels": int(dead.sum()),
                                         "class_mean_counts": class_means,
                                     })
    cal.__post_init__()
    return cal


def _class_name(layout: Layout, k: int) -> str:
    angle = ANGLES[k % 4]
    if not layout.is_color:
        return f"{angle}"
    return f"{'RGB'[k // 4]}{angle}"


# ---------------------------------------------------------------------------
# polarizer
# ---------------------------------------------------------------------------

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
        N = 256 frames of 8000 electrons (docs/calibration.md).
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
    rad = np.deg2rad(angles)
    ata = np.zeros((3, 3))
    aty: np.ndarray | None = None
    yy: np.ndarray | None = None
    offset: np.ndarray | float = 0.0
    flat: np.ndarray | float = 1.0
    stats: _Stats | None = None
    for i, counts, _frame, stats in _read_frames(frames, layout=layout, base=base, what="polarizer",
                                                 check_settings=check_settings):
        if i >= angles.size:
            raise CalibrationError(f"more frames than polarizer angles ({angles.size} given): "
                                   "expected one angle per frame")
        if aty is None:
            offset, flat = _mosaic_correction(base, stats)
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
    _check_saturation(stats, "polarizer")
    h, w = stats.shape
    coef = np.linalg.solve(ata, aty.reshape(3, -1)).reshape(3, h, w)
    n = stats.count
    rss = yy - np.einsum("khw,khw->hw", coef, aty)  # sum (y - A c)^2 = y.y - c.A^T y
    rss = np.maximum(rss, 0.0)
    c0 = coef[0]
    scale, dia, theta = model_from_coefficients(c0, coef[1], coef[2], source_dolp=source_dolp)
    with np.errstate(divide="ignore", invalid="ignore"):
        resid = np.where(c0 > 0, np.sqrt(rss / max(n - 3, 1)) / np.where(c0 > 0, c0, 1.0), 0.0)
    span = stats.white_level - float(np.median(offset))
    if not float(np.median(c0)) > 0.02 * span:
        raise CalibrationError(
            f"polarizer frames too dark: median signal {float(np.median(c0)):.4g} counts, expected at "
            f"least 2% of the range ({0.02 * span:.4g})")

    lay = stats.layout
    nominal = nominal_orientation(lay, h, w)
    known_bad = np.zeros((h, w), dtype=bool)
    if base is not None:
        for key in ("hot", "dead"):
            if key in base.maps:
                known_bad |= base.maps[key]
    known_bad |= ~(c0 > 0)
    good = ~known_bad
    med_d = float(np.median(dia[good])) if good.any() else 0.0
    if med_d < 0.5:
        raise CalibrationError(
            f"calibration light barely polarized: median diattenuation {med_d:.3f} (expected near 1 for a "
            "polarization sensor): is the polarizer in the beam, and source_dolp right?")
    delta = _wrap90(theta - nominal)
    common = 0.0
    if zero == "sensor":
        common = _circular_mean_deg(delta[good])
        theta = np.mod(theta - common, 180.0)
        delta = _wrap90(theta - nominal)
    classes = class_index(lay, h, w)
    offsets = {}
    for k in np.unique(classes):
        sel = (classes == k) & good
        med = float(np.median(delta[sel])) if sel.any() else 0.0
        offsets[_class_name(lay, int(k))] = med
        if abs(med) > MAX_CLASS_OFFSET_DEG:
            raise CalibrationError(
                f"pixels of the {_class_name(lay, int(k))}-degree class face {ANGLES[int(k) % 4] + med:.1f} "
                f"degrees (median), {med:+.1f} from nominal: expected within {MAX_CLASS_OFFSET_DEG:g}. "
                f"Are the polarizer angles measured in the opposite sense, offset (try zero='sensor'), "
                f"or is the layout ({lay}) wrong?")
    colour = class_index(lay, h, w, angle=False)
    gain = scale / _class_mean(scale, colour, good)

    outlier = known_bad.copy()
    for k in np.unique(classes):
        sel = (classes == k) & good
        if not sel.any():
            continue
        res_floor = 0.1 * float(np.median(resid[sel]))
        for vals, floor, one_sided in ((gain, _FLOOR_GAIN, False), (dia, _FLOOR_D, False),
                                       (delta, _FLOOR_THETA, False), (resid, res_floor, True)):
            v = vals[sel]
            med = np.median(v)
            s = max(robust_sigma(v), floor, 1e-9)
            z = (vals - med) / s
            hit = (z > outlier_sigma) if one_sided else (np.abs(z) > outlier_sigma)
            outlier |= hit & (classes == k)
    gain = np.where(np.isfinite(gain), gain, 0.0)
    cal = _result(stats, base)
    if cal.camera_id is None:
        cal.camera_id = camera_id
    cal.maps["gain"] = gain.astype(np.float32)
    cal.maps["diattenuation"] = dia.astype(np.float32)
    cal.maps["orientation_deg"] = np.where(theta >= 180.0, 0.0, theta).astype(np.float32)
    cal.maps["residual"] = resid.astype(np.float32)
    cal.maps["outlier"] = outlier
    ok = ~outlier
    distinct = np.unique(np.round(np.mod(angles, 180.0), 2) % 180.0)
    cal.stages["polarizer"] = _stage_info(
        stats, angles_deg=[float(a) for a in distinct], source_dolp=source_dolp, zero=zero,
        common_rotation_deg=common, outlier_sigma=outlier_sigma,
        after_dark=bool(base and base.has("dark")), after_flat=bool(base and base.has("flat")),
        statistics={
            "orientation_offset_deg": offsets,
            "orientation_spread_deg": float(np.std(delta[ok])) if ok.any() else 0.0,
            "diattenuation_median": float(np.median(dia[ok])) if ok.any() else 0.0,
            "extinction_ratio_median": float((1 + np.median(dia[ok])) / max(1 - np.median(dia[ok]), 1e-9))
            if ok.any() else 0.0,
            "gain_spread": float(np.std(gain[ok])) if ok.any() else 0.0,
            "residual_median": float(np.median(resid[ok])) if ok.any() else 0.0,
            "outliers": int(outlier.sum()),
        })
    cal.__post_init__()
    return cal


def _wrap90(d: np.ndarray) -> np.ndarray:
    """Angle differences (degrees) wrapped to [-90, 90)."""
    return np.mod(np.asarray(d, dtype=np.float64) + 90.0, 180.0) - 90.0


def _circular_mean_deg(d: np.ndarray) -> float:
    """Mean of axial angle differences (period 180 degrees), degrees in [-90, 90)."""
    r = np.deg2rad(2.0 * np.asarray(d, dtype=np.float64))
    return float(np.rad2deg(math.atan2(float(np.sin(r).mean()), float(np.cos(r).mean()))) / 2.0)
