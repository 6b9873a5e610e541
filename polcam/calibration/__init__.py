"""Calibration of polarization cameras: dark, flat field and the per-pixel polarizer model.

Each pixel k of a division-of-focal-plane sensor reads (docs/guide/calibration.md)::

    I_k = g_k / 2 * (S0 + D_k (S1 cos 2 theta_k + S2 sin 2 theta_k)) + d_k

with its own gain ``g``, diattenuation ``D = (ER - 1) / (ER + 1)``, polarizer
orientation ``theta`` and dark level ``d``.  This package measures those maps
from frames and corrects frames with them:

- :func:`calibrate_dark`, :func:`calibrate_flat`, :func:`calibrate_polarizer`
  make a :class:`Calibration` from frames (capped lens; uniform unpolarized
  light; uniform light through a linear polarizer at M >= 8 known angles);
- :func:`save_calibration` / :func:`load_calibration`: one versioned ``.npz``
  file without pickles (:mod:`polcam.calibration.store`);
- :func:`apply_calibration` corrects a raw frame (dark, flat, defective
  pixels, and the per-super-pixel polarimetric correction on the mosaic);
  :func:`correct_stack` is the per-pixel polarimetric correction of a
  demosaiced stack;
- the frames to calibrate from (disk or a camera, and their polarizer angles) are
  taken by :mod:`polcam.acquisition.calibration_frames` for ``polcam calibrate
  dark|flat|polarizer`` (:mod:`polcam.commands.calibrate`); the benchmark on a
  synthetic sensor is ``polcam bench calibration`` (:mod:`polcam.bench.calibration`).

A calibration refuses frames of another camera, layout, size or ROI (and a
dark, frames of another exposure, gain or bit depth) with a
:class:`CalibrationError` naming both values.
"""

from __future__ import annotations

from polcam.calibration.apply import apply_calibration, correct_stack, fill_defects
from polcam.calibration.estimate import (
    MIN_ANGLES,
    calibrate_dark,
    calibrate_flat,
    calibrate_polarizer,
    check_angles,
)
from polcam.calibration.model import (
    analysis_matrices,
    correction_matrices,
    diattenuation_to_extinction,
    extinction_to_diattenuation,
    forward,
    measurement_rows,
)
from polcam.calibration.store import (
    FORMAT,
    MAPS,
    VERSION,
    Calibration,
    CalibrationError,
    load_calibration,
    save_calibration,
)

__all__ = [
    "FORMAT",
    "MAPS",
    "MIN_ANGLES",
    "VERSION",
    "Calibration",
    "CalibrationError",
    "analysis_matrices",
    "apply_calibration",
    "calibrate_dark",
    "calibrate_flat",
    "calibrate_polarizer",
    "check_angles",
    "correct_stack",
    "correction_matrices",
    "diattenuation_to_extinction",
    "extinction_to_diattenuation",
    "fill_defects",
    "forward",
    "load_calibration",
    "measurement_rows",
    "save_calibration",
]

