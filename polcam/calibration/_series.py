"""Reading a series of calibration frames: the checks, per-class statistics and the calibration it starts.

Shared by the three fits of :mod:`polcam.calibration.estimate`: frames come as
:class:`polcam.frame.Frame` objects or arrays of counts, each is checked against the first (size,
layout, bit depth, camera, exposure, gain), and what the series showed (:class:`Stats`) starts
the resulting :class:`~polcam.calibration.store.Calibration`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from polcam.calibration.store import Calibration, CalibrationError, utc_now
from polcam.frame import Frame
from polcam.mosaic import ANGLES, Layout, parse_layout

__all__ = ["LOCAL", "MIN_SIGNAL", "FrameLike", "Frames", "Stats", "check_saturation", "class_index", "class_mean", "class_name",
           "local_outliers", "mosaic_correction", "new_calibration", "read_frames", "robust_sigma", "stage_info"]

FrameLike = Frame | np.ndarray
Frames = Iterable[FrameLike] | np.ndarray

#: Standard deviation of a normal distribution over its median absolute deviation, 1 / Phi^-1(3/4).
_MAD_TO_SIGMA = 1.482602218505602
#: Side of the window of the local medians that dark and flat outliers are measured against, pixels.
LOCAL = 7
#: Least median signal of the flat and polarizer frames, as a share of the range above the dark level: below it
#: the fit's precision (shot and read noise over the signal) is too poor to calibrate.
MIN_SIGNAL = 0.02


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


def class_name(layout: Layout, k: int) -> str:
    angle = ANGLES[k % 4]
    if not layout.is_color:
        return f"{angle}"
    return f"{'RGB'[k // 4]}{angle}"


def class_mean(values: np.ndarray, classes: np.ndarray, good: np.ndarray) -> np.ndarray:
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
class Stats:
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


def read_frames(frames: Frames, *, layout: str | Layout | None, base: Calibration | None,
                 what: str, check_settings: bool) -> Iterator[tuple[int, np.ndarray, Frame, Stats]]:
    """Yield ``(i, counts float64, frame, stats)`` after checking each frame against the first."""
    lay = None if layout is None else parse_layout(layout)
    stats: Stats | None = None
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
            stats = Stats(layout=flay, shape=(h, w), bit_depth=int(frame.bit_depth),
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


def _num(v: Any) -> float | None:
    return None if v is None else float(v)


def _same(name: str, key: str, got: Any, want: Any, ok: bool) -> None:
    if not ok:
        raise CalibrationError(f"{name}: {key} {got} differs from the first frame's {want}: "
                               "every frame of one calibration must share it")


def check_saturation(stats: Stats, what: str, limit: float = 1e-3) -> None:
    total = stats.count * stats.shape[0] * stats.shape[1]
    if total and stats.saturated / total > limit:
        raise CalibrationError(
            f"{what} frames are saturated: {stats.saturated / total:.2%} of the samples reach the white level "
            f"{stats.white_level:g} (expected under {limit:.1%}); lower the exposure or the light")


def new_calibration(stats: Stats, base: Calibration | None) -> Calibration:
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


def stage_info(stats: Stats, **extra: Any) -> dict[str, Any]:
    info: dict[str, Any] = {
        "frames": stats.count, "exposure_us": stats.exposure_us, "gain_db": stats.gain_db,
        "bit_depth": stats.bit_depth, "black_level": stats.black_level, "white_level": stats.white_level,
    }
    info.update(extra)
    return info


def mosaic_correction(base: Calibration | None, stats: Stats) -> tuple[np.ndarray | float, np.ndarray | float]:
    """(offset, flat) to turn counts into dark-subtracted, flat-corrected signal."""
    offset: np.ndarray | float = stats.black_level
    flat: np.ndarray | float = 1.0
    if base is not None and base.has("dark"):
        offset = base.maps["dark"].astype(np.float64)
    if base is not None and base.has("flat"):
        flat = base.maps["flat"].astype(np.float64)
    return offset, flat


def local_outliers(values: np.ndarray, sigma: float, *, floor: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Robust outliers of ``values`` against their local median: (mask, deviation, robust sigma)."""
    local = ndimage.median_filter(values, size=LOCAL, mode="reflect")
    dev = values - local
    s = max(robust_sigma(dev), floor)
    return np.abs(dev) > sigma * s, dev, s
