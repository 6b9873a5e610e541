"""``polcam calibrate dark|flat|polarizer FRAMES... -o FILE``: make a calibration file from frames on disk.

:func:`add_calibrate_parser` adds the ``calibrate`` command to the ``polcam``
parser; :func:`cmd_calibrate` runs it; :func:`main` runs it standalone
(``python -m polcam.calibration dark ...``).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from polcam.calibration.estimate import calibrate_dark, calibrate_flat, calibrate_polarizer
from polcam.calibration.store import Calibration, CalibrationError, load_calibration, save_calibration
from polcam.errors import PolcamError
from polcam.frame import Frame

__all__ = ["ANGLE_KEY", "add_calibrate_parser", "angle_from_name", "angle_of", "cmd_calibrate", "list_frames", "main"]

#: Sidecar key holding the polarizer angle of a calibration frame, degrees.
ANGLE_KEY = "polarizer_deg"

_DEG_RE = re.compile(r"(?<![0-9.])(\d+(?:\.\d+)?)\s*deg", re.IGNORECASE)
_NUM_RE = re.compile(r"\d+(?:\.\d+)?")

_LIVE_NOTE = ("Frames are read from files (png, tif, pgm, raw, npy, dng, ... with their <stem>.json "
              "sidecars); capturing them live from a camera belongs to 'polcam capture' and is not "
              "part of this command yet.")


def angle_from_name(stem: str) -> float | None:
    """The polarizer angle written in a file name, or ``None``.

    A number followed by ``deg`` wins (``pol_22.5deg_003`` -> 22.5); otherwise a
    name holding exactly one number gives it (``angle_045`` -> 45).  Names
    with several numbers and no ``deg`` are ambiguous (``None``).
    """
    hits = _DEG_RE.findall(stem)
    if len(hits) == 1:
        return float(hits[0])
    if len(hits) > 1:
        return None
    nums = _NUM_RE.findall(stem)
    return float(nums[0]) if len(nums) == 1 else None


def angle_of(path: Path, *, source: str = "auto") -> float:
    """The polarizer angle of a calibration frame, from its sidecar or its name.

    Parameters
    ----------
    path
        The raw frame.
    source
        ``"auto"`` (the sidecar's ``polarizer_deg``, else the name; both must
        agree when both are there), ``"sidecar"`` or ``"name"``.

    Raises
    ------
    CalibrationError
        No angle found, a sidecar value that is not a finite number, or
        sidecar and name disagreeing.
    """
    from polcam.io import read_sidecar

    side = read_sidecar(path) or {}
    val = side.get(ANGLE_KEY)
    if val is not None and (isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val)):
        raise CalibrationError(f"sidecar key {ANGLE_KEY!r} has value {val!r}: expected a finite number of degrees",
                               path=path)
    named = angle_from_name(path.stem)
    if source == "sidecar":
        if val is None:
            raise CalibrationError(f"no {ANGLE_KEY!r} in the sidecar {path.stem}.json: expected the polarizer "
                                   "angle in degrees", path=path)
        return float(val)
    if source == "name":
        if named is None:
            raise CalibrationError("no polarizer angle in the file name: expected e.g. 'pol_045deg.png' "
                                   "(a number followed by 'deg', or a single number)", path=path)
        return named
    if val is not None and named is not None:
        diff = abs((float(val) - named + 90.0) % 180.0 - 90.0)
        if diff > 0.01:
            raise CalibrationError(
                f"polarizer angle {float(val):g} in the sidecar but {named:g} in the file name: "
                "expected them to agree (or use --angles-from sidecar|name)", path=path)
    if val is not None:
        return float(val)
    if named is not None:
        return named
    raise CalibrationError(
        f"polarizer angle unknown: expected a sidecar key {ANGLE_KEY!r} or the angle in the file name "
        "(e.g. 'pol_045deg.png')", path=path)


def list_frames(paths: Sequence[Path], *, recursive: bool = False) -> list[Path]:
    """Raw frame files among ``paths`` (folders expanded, sorted; sidecars skipped).

    Raises
    ------
    CalibrationError
        A path that does not exist, or no frames at all.
    """
    from polcam.io import RAW_EXTENSIONS

    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            it = p.rglob("*") if recursive else p.iterdir()
            out += sorted(f for f in it if f.is_file() and f.suffix.lower() in RAW_EXTENSIONS
                          and not f.name.startswith("."))
        elif p.is_file():
            out.append(p)
        else:
            raise CalibrationError("no such file or folder", path=p)
    if not out:
        shown = ", ".join(str(p) for p in paths)
        raise CalibrationError(f"no raw frames found in {shown} (extensions: {', '.join(RAW_EXTENSIONS[:10])}, ...)")
    return out


def _read(files: Sequence[Path], layout: str | None) -> Iterator[Frame]:
    from polcam.io import read_frame

    for f in files:
        yield read_frame(f, layout=layout)


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Run ``polcam calibrate STAGE``; returns the exit status (errors raise :class:`PolcamError`)."""
    stage = args.calibrate_stage
    out = Path(args.out)
    if out.exists() and not args.force:
        raise CalibrationError("output exists: expected a new file name, or --force to replace it", path=out)
    files = list_frames(args.frames, recursive=args.recursive)
    base: Calibration | None = load_calibration(args.calibration) if args.calibration else None
    common: dict[str, Any] = {"layout": args.layout, "base": base, "camera_id": args.camera_id,
                              "check_settings": not args.any_exposure}
    if stage == "dark":
        cal = calibrate_dark(_read(files, args.layout), hot_sigma=args.hot_sigma, **common)
    elif stage == "flat":
        cal = calibrate_flat(_read(files, args.layout), dead_sigma=args.dead_sigma, **common)
    elif stage == "polarizer":
        angles = [angle_of(f, source=args.angles_from) for f in files]
        cal = calibrate_polarizer(_read(files, args.layout), angles, source_dolp=args.polarizer_dolp,
                                  zero=args.zero, outlier_sigma=args.outlier_sigma, **common)
    else:  # pragma: no cover - argparse restricts the choices
        raise CalibrationError(f"unknown calibration stage {stage!r}")
    cal.stages[stage]["inputs"] = [str(f) for f in files]
    out.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(out, cal)
    if args.json:
        print(json.dumps({"file": str(out), "stages": cal.stages}, indent=2, default=str))
    else:
        print(f"{stage}: {len(files)} frames -> {out}")
        print(cal.describe())
    return 0


def _add_stage(sub: Any, stage: str, help_text: str, description: str) -> argparse.ArgumentParser:
    p = sub.add_parser(stage, help=help_text, description=f"{description} {_LIVE_NOTE}")
    p.add_argument("frames", nargs="+", type=Path, metavar="FRAMES",
                   help="folder(s) of raw frames, or frame files")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="FILE",
                   help="calibration file to write (.npz)")
    p.add_argument("--layout", help="sensor layout (imx250mzr, imx250myr, mono:A,B,C,D, color:A,B,C,D:BAYER); "
                                    "default: from the sidecars / pixel format")
    p.add_argument("--calibration", type=Path, metavar="BASE",
                   help="earlier calibration of the same camera (e.g. the dark for a flat, dark+flat for the "
                        "polarizer): applied to these frames first and copied into FILE")
    p.add_argument("--camera-id", help="camera identifier to record when the frames carry none")
    p.add_argument("--any-exposure", action="store_true",
                   help="accept frames whose exposure or gain differ from BASE's dark")
    p.add_argument("--recursive", action="store_true", help="descend into sub-folders")
    p.add_argument("--force", action="store_true", help="replace FILE if it exists")
    p.add_argument("--json", action="store_true", help="print what was measured as JSON")
    p.set_defaults(func=cmd_calibrate, calibrate_stage=stage)
    return p


def add_calibrate_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``calibrate dark|flat|polarizer`` to a ``polcam`` sub-command set.

    Parameters
    ----------
    subparsers
        What ``ArgumentParser.add_subparsers()`` returned.

    Returns
    -------
    argparse.ArgumentParser
        The ``calibrate`` parser; each stage sets ``func=cmd_calibrate``.
    """
    c = subparsers.add_parser(
        "calibrate", help="make a calibration file: dark, flat field, per-pixel polarizer model",
        description="Measure a camera's dark level and hot pixels (dark), per-pixel gain (flat) and "
                    "per-pixel polarizer gain, diattenuation and orientation (polarizer) from frames on "
                    "disk, and write them to one .npz file that 'polcam process --calibration FILE' "
                    "applies (docs/calibration.md). Chain the stages with --calibration: "
                    "dark -> flat -> polarizer. " + _LIVE_NOTE)
    sub = c.add_subparsers(dest="calibrate_stage", required=True, metavar="STAGE")
    d = _add_stage(sub, "dark", "lens capped: dark level, temporal noise, hot pixels",
                   "N frames (16 or more) with the lens capped, at the exposure, gain and bit depth of the "
                   "frames to correct: per-pixel mean dark level, temporal noise and hot/cold/noisy pixels "
                   "(robust outliers).")
    d.add_argument("--hot-sigma", type=float, default=6.0,
                   help="robust standard deviations that make a pixel hot (default 6)")
    f = _add_stage(sub, "flat", "uniform unpolarized light: per-pixel gain",
                   "Frames of uniform, unpolarized light (integrating sphere, diffuser), well exposed and not "
                   "saturated: per-pixel gain normalised to mean 1 in each angle/colour class, and dead "
                   "pixels. Give the dark with --calibration.")
    f.add_argument("--dead-sigma", type=float, default=6.0,
                   help="robust standard deviations that make a pixel's gain abnormal (default 6)")
    p = _add_stage(sub, "polarizer", "light through a rotated linear polarizer: per-pixel g, D, theta",
                   "Frames of uniform light through a linear polarizer at 8 or more known angles spread over "
                   "180 degrees (gaps of at most 45), several frames per angle welcome. The angle of each "
                   f"frame comes from its sidecar key '{ANGLE_KEY}' or its file name ('pol_045deg.png', "
                   "'angle_22.5deg_3.tif', or a name with a single number), in degrees from the image x "
                   "axis towards the layout's 45-degree polarizer. Give dark and flat with --calibration.")
    p.add_argument("--angles-from", choices=("auto", "sidecar", "name"), default="auto",
                   help=f"where the angles come from (default auto: sidecar '{ANGLE_KEY}', else the name)")
    p.add_argument("--polarizer-dolp", type=float, default=1.0,
                   help="degree of polarization of the calibration light, (ER-1)/(ER+1) of the reference "
                        "polarizer (default 1)")
    p.add_argument("--zero", choices=("polarizer", "sensor"), default="polarizer",
                   help="polarizer: the angles are exact in the image frame (default); sensor: remove the "
                        "mean rotation of all pixels (polarizer zero not aligned with the image x axis)")
    p.add_argument("--outlier-sigma", type=float, default=6.0,
                   help="robust standard deviations that make a pixel's fit an outlier (default 6)")
    return c


def main(argv: Sequence[str] | None = None) -> int:
    """Standalone ``calibrate`` command (``python -m polcam.calibration dark ...``)."""
    parser = argparse.ArgumentParser(prog="python -m polcam.calibration",
                                     description="polcam calibrate, standalone; 'bench' runs the benchmark.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    cal = add_calibrate_parser(sub)
    args_list = list(sys.argv[1:] if argv is None else argv)
    # accept both "calibrate dark ..." and "dark ..."
    if args_list and args_list[0] in ("dark", "flat", "polarizer"):
        args_list = ["calibrate", *args_list]
    args = parser.parse_args(args_list)
    del cal
    try:
        return int(args.func(args) or 0)
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
