"""``polcam calibrate dark|flat|polarizer (FRAMES... | --device ID --frames N) -o FILE``.

A calibration file from frames on disk, or from frames grabbed live from a
camera (``--device``: an Aravis camera id or ``replay:DIR``, with the camera
options of ``polcam capture``); the frames stream into
:func:`~polcam.calibration.calibrate_dark` /
:func:`~polcam.calibration.calibrate_flat` /
:func:`~polcam.calibration.calibrate_polarizer` one at a time
(:mod:`polcam.acquisition.calibration_frames` says how live frames are taken).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from polcam.acquisition.calibration_frames import (
    ANGLE_KEY,
    FrameGrabber,
    angle_of,
    keep_folder,
    list_frames,
    parse_angles,
    plain,
    read_frames,
)
from polcam.calibration.estimate import calibrate_dark, calibrate_flat, calibrate_polarizer, check_angles
from polcam.calibration.store import Calibration, CalibrationError, load_calibration, save_calibration
from polcam.camera import open_camera
from polcam.commands._args import CAMERA_SETTINGS, add_camera_arguments, camera_options, configure_camera, run_command

__all__ = ["add_calibrate_parser", "cmd_calibrate", "main"]

_LIVE_NOTE = ("Give either FRAMES, files or folders of raw frames (png, tif, pgm, raw, npy, dng, ... with "
              "their <stem>.json sidecars), or --device ID --frames N to grab N good frames live from a "
              "camera (an Aravis id or replay:DIR; camera options as for 'polcam capture'; --keep DIR "
              "saves the frames used so the calibration can be redone from disk).")

# options for --device only (destination -> flag)
_DEVICE_ONLY = {"count": "--frames", "angles": "--angles", "keep": "--keep"}


def _check_source(args: argparse.Namespace) -> None:
    if args.frames and args.device:
        raise CalibrationError(f"both FRAMES ({' '.join(map(str, args.frames))}) and --device {args.device} "
                               "given: expected one source, frames on disk or a live camera")
    if not args.frames and not args.device:
        raise CalibrationError("no frames: give FRAMES (folders or files of raw frames) or --device ID "
                               "--frames N to grab them from a camera")
    if args.frames:
        given = [flag for dest, flag in {**_DEVICE_ONLY, **CAMERA_SETTINGS}.items()
                 if getattr(args, dest, None) is not None]
        if given:
            raise CalibrationError(f"{', '.join(given)} given with FRAMES: these options are for --device "
                                   "(frames grabbed from a camera)")
        return
    if args.recursive:
        raise CalibrationError("--recursive given with --device: it is for FRAMES folders")
    if args.count is None:
        raise CalibrationError(f"--device {args.device} without --frames N: expected the number of good "
                               f"frames to grab{' at each angle' if args.calibrate_stage == 'polarizer' else ''}")
    if args.count < 1:
        raise CalibrationError(f"--frames {args.count}: expected a positive number of frames")
    if args.calibrate_stage == "polarizer" and args.angles is None:
        raise CalibrationError(f"--device {args.device} without --angles: expected the polarizer angles to "
                               "step through, e.g. --angles 0,22.5,45,67.5,90,112.5,135,157.5")


def _live(args: argparse.Namespace, stage: str, common: dict[str, Any]) -> tuple[Calibration, str]:
    """Grab the frames of ``stage`` from ``--device`` and calibrate; returns (calibration, what was used)."""

    angles: list[float] = []
    if stage == "polarizer":
        angles = parse_angles(args.angles)
        check_angles(angles)  # before the camera is touched
    keep = keep_folder(args.keep) if args.keep is not None else None
    n = int(args.count)
    with open_camera(args.device, **camera_options(args)) as cam:
        settings = configure_camera(cam, args, quiet=args.json)
        grabber = FrameGrabber(cam, stage, idle_timeout=args.timeout,
                               software_trigger=args.trigger == "software", keep=keep)
        if stage == "dark":
            cal = calibrate_dark(grabber.stage_frames(n), hot_sigma=args.hot_sigma, **common)
        elif stage == "flat":
            cal = calibrate_flat(grabber.stage_frames(n), dead_sigma=args.dead_sigma, **common)
        else:
            per_frame = [a for a in angles for _ in range(n)]
            cal = calibrate_polarizer(grabber.polarizer_frames(angles, n), per_frame,
                                      source_dolp=args.polarizer_dolp, zero=args.zero,
                                      outlier_sigma=args.outlier_sigma, **common)
        grabber.pause()
        info: dict[str, Any] = {"source": "camera", "device": str(args.device), "camera_id": cam.camera_id,
                                "camera": cam.info, "settings": settings}
        if stage == "polarizer":
            info["frames_per_angle"] = n
        info.update(grabber.info())
    cal.stages[stage].update(plain(info))
    inc, drop = info["frames_incomplete"], info["frames_dropped"]
    used = f"{grabber.taken} frames from camera {cam.camera_id} ({inc} incomplete, {drop} dropped)"
    return cal, used


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Run ``polcam calibrate STAGE``; returns the exit status (errors raise :class:`PolcamError`)."""
    stage = args.calibrate_stage
    out = Path(args.out)
    if out.exists() and not args.force:
        raise CalibrationError("output exists: expected a new file name, or --force to replace it", path=out)
    _check_source(args)
    base: Calibration | None = load_calibration(args.calibration) if args.calibration else None
    common: dict[str, Any] = {"layout": args.layout, "base": base, "camera_id": args.camera_id,
                              "check_settings": not args.any_exposure}
    if args.device:
        cal, used = _live(args, stage, common)
    else:
        files = list_frames(args.frames, recursive=args.recursive)
        if stage == "dark":
            cal = calibrate_dark(read_frames(files, args.layout), hot_sigma=args.hot_sigma, **common)
        elif stage == "flat":
            cal = calibrate_flat(read_frames(files, args.layout), dead_sigma=args.dead_sigma, **common)
        elif stage == "polarizer":
            angles = [angle_of(f, source=args.angles_from) for f in files]
            cal = calibrate_polarizer(read_frames(files, args.layout), angles, source_dolp=args.polarizer_dolp,
                                      zero=args.zero, outlier_sigma=args.outlier_sigma, **common)
        else:  # pragma: no cover - argparse restricts the choices
            raise CalibrationError(f"unknown calibration stage {stage!r}")
        cal.stages[stage]["inputs"] = [str(f) for f in files]
        used = f"{len(files)} frames"
    out.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(out, cal)
    if args.json:
        print(json.dumps({"file": str(out), "stages": cal.stages}, indent=2, default=str))
    else:
        print(f"{stage}: {used} -> {out}")
        print(cal.describe())
    return 0


def _add_stage(sub: Any, stage: str, help_text: str, description: str) -> argparse.ArgumentParser:
    p = sub.add_parser(stage, help=help_text, description=f"{description} {_LIVE_NOTE}")
    p.add_argument("frames", nargs="*", type=Path, metavar="FRAMES",
                   help="folder(s) of raw frames, or frame files (or --device instead)")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="FILE",
                   help="calibration file to write (.npz)")
    p.add_argument("--device", metavar="ID",
                   help="grab the frames live from this camera (an Aravis id, serial or address, or "
                        "replay:DIR) instead of FRAMES")
    p.add_argument("--frames", dest="count", type=int, metavar="N",
                   help="with --device: good frames to grab" + {
                       "dark": " (16 or more recommended)", "flat": " (the gain's precision grows as sqrt(N))",
                       "polarizer": " at each angle"}.get(stage, ""))
    p.add_argument("--keep", type=Path, metavar="DIR",
                   help="with --device: write the frames used to DIR (raw, as the camera sent them, with "
                        "sidecars" + (f", '{ANGLE_KEY}' among them" if stage == "polarizer" else "")
                        + ") so the calibration can be redone from disk")
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
    if stage == "polarizer":
        p.add_argument("--angles", metavar="A,B,...",
                       help="with --device (required there): the polarizer angles to step through, degrees, "
                            "e.g. 0,22.5,45,67.5,90,112.5,135,157.5 (8 or more); for each one the command "
                            "asks on stderr to set the polarizer and waits for Enter on stdin")
    g = p.add_argument_group("camera options (with --device, as for 'polcam capture')")
    add_camera_arguments(g, layout=False)
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
                    "applies (docs/guide/calibration.md). Chain the stages with --calibration: "
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

    return run_command(args)
