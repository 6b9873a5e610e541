"""Making a calibration from frames: dark and flat field.

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
Every function takes frames as :class:`polcam.frame.Frame` objects or arrays of
counts (an (N, H, W) array, or a sequence), and an optional ``base``
calibration whose dark (and flat) are applied to the frames first and whose
maps are carried into the result, so ``dark -> flat -> polarizer``
(:mod:`polcam.calibration.polarizer`) builds one file.  Bad input (too few frames or angles, frames of different sizes,
layouts, cameras or settings, saturated or too dark frames) raises
:class:`~polcam.calibration.store.CalibrationError` naming the frame and the
values.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from polcam.calibration._series import (
    LOCAL,
    MIN_SIGNAL,
    Frames,
    Stats,
    check_saturation,
    class_index,
    class_mean,
    class_name,
    local_outliers,
    mosaic_correction,
    new_calibration,
    read_frames,
    robust_sigma,
    stage_info,
)
from polcam.calibration.polarizer import MAX_ANGLE_GAP_DEG, MIN_ANGLES, calibrate_polarizer, check_angles
from polcam.calibration.store import Calibration, CalibrationError
from polcam.mosaic import Layout

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

# Floors of the robust spreads in the dark outlier test (counts): the dark level's and the temporal
# noise's, so that a noiseless synthetic sensor flags nothing.
_FLOOR_DARK_LEVEL = 0.5
_FLOOR_DARK_NOISE = 0.25
#: Floor of the robust spread of the flat's deviation from its local median (relative gain).
_FLOOR_FLAT = 1e-4
#: A pixel whose flat gain is under this share of its local median is dead (vignetting and the
#: micro-lens pattern never halve a gain from one pixel to the next).
_DEAD_GAIN = 0.5
#: Passes of the dead-pixel search: each takes the dead pixels found out of the class means.
_DEAD_PASSES = 2


# ---------------------------------------------------------------------------
# dark
# ---------------------------------------------------------------------------

#: Largest mean level of a dark frame above its black level, as a share of the range (white level
#: minus black level): a capped sensor reads its black level, dark current and read noise; more
#: than this is light (a lit scene, a lens not capped) or a black level the frame does not declare.
DARK_MAX_LEVEL = 0.05


def _check_dark(counts: np.ndarray, stats: Stats) -> None:
    """Refuse a dark frame whose mean level is more than DARK_MAX_LEVEL of the range above black."""
    mean = float(np.mean(counts))
    span = stats.white_level - stats.black_level
    above = (mean - stats.black_level) / span if span > 0 else 0.0
    if above > DARK_MAX_LEVEL:
        raise CalibrationError(
            f"{stats.names[-1]}: not a dark frame: mean level {mean:.4g} counts, {above:.1%} of the range above "
            f"the black level {stats.black_level:.4g}; expected at most {DARK_MAX_LEVEL:.0%} (cap the lens; a "
            "camera that adds a black level the frames do not declare: give black_level in their sidecars)")


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
    stats, dark, noise = _dark_mean_and_noise(frames, layout=layout, base=base)
    level_out, _dev, level_sigma = local_outliers(dark, hot_sigma, floor=_FLOOR_DARK_LEVEL)
    noise_med = float(np.median(noise))
    noise_sigma = max(robust_sigma(noise), _FLOOR_DARK_NOISE)
    noisy = noise > noise_med + hot_sigma * noise_sigma
    hot = level_out | noisy
    cal = new_calibration(stats, base)
    cal.maps["dark"] = dark.astype(np.float32)
    cal.maps["dark_noise"] = noise.astype(np.float32)
    cal.maps["hot"] = hot
    cal.exposure_us, cal.gain_db, cal.bit_depth = stats.exposure_us, stats.gain_db, stats.bit_depth
    cal.black_level, cal.white_level = stats.black_level, stats.white_level
    if cal.camera_id is None:
        cal.camera_id = camera_id
    good = ~hot
    cal.stages["dark"] = stage_info(stats, hot_sigma=hot_sigma, statistics={
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


def _dark_mean_and_noise(frames: Frames, *, layout: str | Layout | None,
                         base: Calibration | None) -> tuple[Stats, np.ndarray, np.ndarray]:
    """Per-pixel mean (counts) and temporal standard deviation of at least 2 dark frames, (H, W) float64.

    The sums are taken about the first frame's median, which keeps the variance exact.
    """
    total: np.ndarray | None = None
    total2: np.ndarray | None = None
    stats: Stats | None = None
    shift = 0.0
    for _, counts, _frame, stats in read_frames(frames, layout=layout, base=base, what="dark",
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
    return stats, mean + shift, np.sqrt(var)


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
    stats: Stats | None = None
    for _, counts, _frame, stats in read_frames(frames, layout=layout, base=base, what="flat",
                                                 check_settings=check_settings):
        total = counts.copy() if total is None else total + counts
    assert stats is not None and total is not None
    check_saturation(stats, "flat")
    offset, _ = mosaic_correction(base, stats)
    signal = total / stats.count - offset
    span = stats.white_level - float(np.median(offset))
    level = float(np.median(signal))
    if not level > MIN_SIGNAL * span:
        raise CalibrationError(
            f"flat frames too dark: median signal {level:.4g} counts above the dark, expected at least "
            f"2% of the range ({MIN_SIGNAL * span:.4g}); raise the exposure or the light")
    h, w = stats.shape
    classes = class_index(stats.layout, h, w)
    hot = base.maps["hot"] if base is not None and base.has("dark") else np.zeros((h, w), dtype=bool)
    flat, dead, good = _flat_and_dead(signal, classes, hot, dead_sigma)
    cal = new_calibration(stats, base)
    if cal.camera_id is None:
        cal.camera_id = camera_id
    cal.maps["flat"] = flat.astype(np.float32)
    cal.maps["dead"] = dead
    class_means = {}
    for k in np.unique(classes):
        sel = (classes == k) & good
        class_means[class_name(stats.layout, int(k))] = float(signal[sel].mean()) if sel.any() else None
    cal.stages["flat"] = stage_info(stats, dead_sigma=dead_sigma, dark_from_base=bool(base and base.has("dark")),
                                     statistics={
                                         "median_signal_counts": level,
                                         "gain_spread": float(np.std(flat[good])),
                                         "dead_pixels": int(dead.sum()),
                                         "class_mean_counts": class_means,
                                     })
    cal.__post_init__()
    return cal


def _flat_and_dead(signal: np.ndarray, classes: np.ndarray, hot: np.ndarray,
                   dead_sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The flat (signal over its class mean) and the dead pixels, found and left out of the means twice.

    Dead: a robust outlier of the local median (``dead_sigma``), or a gain under
    ``_DEAD_GAIN`` of it.  Returns flat (1 where not finite or not positive), dead and the good
    pixels the class means were taken over, each (H, W).
    """
    good = ~hot & (signal > 0)
    flat = signal / class_mean(signal, classes, good)
    dead = np.zeros(signal.shape, dtype=bool)
    for _ in range(_DEAD_PASSES):
        out, _dev, sig = local_outliers(flat, dead_sigma, floor=_FLOOR_FLAT)
        low = flat < _DEAD_GAIN * ndimage.median_filter(flat, size=LOCAL, mode="reflect")
        dead = (out | low) & ~hot
        good = ~hot & ~dead & (signal > 0)
        flat = signal / class_mean(signal, classes, good)
    return np.where(np.isfinite(flat) & (flat > 0), flat, 1.0), dead, good
