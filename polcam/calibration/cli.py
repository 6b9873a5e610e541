"""``polcam calibrate dark|flat|polarizer (FRAMES... | --device ID --frames N) -o FILE``.

A calibration file from frames on disk, or from frames grabbed live from a
camera (``--device``: an Aravis camera id or ``replay:DIR``, with the camera
options of ``polcam capture``).

Live, each stage takes exactly N good frames (incomplete and dropped frames
are counted, recorded in the stage's info and reported; a camera that ends
or falls silent before N good frames is an error and nothing is written).
The frames stream into :func:`~polcam.calibration.calibrate_dark` /
:func:`~polcam.calibration.calibrate_flat` /
:func:`~polcam.calibration.calibrate_polarizer` one at a time.  The polarizer
stage asks on stderr, for each angle of ``--angles``, ``set the polarizer to
X deg and press Enter``, reads a line from stdin, then grabs N frames at that
angle; a live camera is stopped while the polarizer turns, so no frame
exposed before Enter is used.  ``--keep DIR`` writes every frame used, as the
camera sent it, with its sidecar (polarizer frames also with
``polarizer_deg``), so the calibration can be redone from disk.

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
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from polcam.calibration.estimate import calibrate_dark, calibrate_flat, calibrate_polarizer, check_angles
from polcam.calibration.store import Calibration, CalibrationError, load_calibration, save_calibration
from polcam.frame import Frame

if TYPE_CHECKING:
    from polcam.camera.base import Camera

__all__ = ["ANGLE_KEY", "FrameGrabber", "add_calibrate_parser", "angle_from_name", "angle_of", "cmd_calibrate",
           "list_frames", "main", "parse_angles"]

#: Sidecar key holding the polarizer angle of a calibration frame, degrees.
ANGLE_KEY = "polarizer_deg"

_DEG_RE = re.compile(r"(?<![0-9.])(\d+(?:\.\d+)?)\s*deg", re.IGNORECASE)
_NUM_RE = re.compile(r"\d+(?:\.\d+)?")

_LIVE_NOTE = ("Give either FRAMES, files or folders of raw frames (png, tif, pgm, raw, npy, dng, ... with "
              "their <stem>.json sidecars), or --device ID --frames N to grab N good frames live from a "
              "camera (an Aravis id or replay:DIR; camera options as for 'polcam capture'; --keep DIR "
              "saves the frames used so the calibration can be redone from disk).")


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


def parse_angles(text: str) -> list[float]:
    """Polarizer angles from ``--angles``.

    Parameters
    ----------
    text
        Comma-separated numbers of degrees, e.g. ``"0,22.5,45,67.5"`` (spaces
        allowed; any real values, the fit takes them modulo 180).

    Returns
    -------
    list of float
        The angles in the order given, degrees.

    Raises
    ------
    CalibrationError
        A value that is not a finite number.
    """
    out = []
    for part in str(text).replace(" ", "").split(","):
        try:
            val = float(part)
        except ValueError:
            val = math.nan
        if not math.isfinite(val):
            raise CalibrationError(f"--angles {text!r}: {part!r} is not a number; expected comma-separated "
                                   "polarizer angles in degrees, e.g. 0,22.5,45,67.5,90,112.5,135,157.5")
        out.append(val)
    return out


def _plain(obj: Any) -> Any:
    """``obj`` with tuples as lists and non-finite floats as ``None`` (for the file's JSON)."""
    from polcam._jsonable import jsonable

    return jsonable(obj, other="str")


class FrameGrabber:
    """Exactly N good frames at a time from an open, configured camera, for a calibration stage.

    Frames stream out one at a time (nothing is held); incomplete and
    dropped frames are counted over every acquisition; with ``keep`` every
    frame used is written there, as the camera sent it, with its sidecar.
    Replayed frames carry the camera id of their recording
    (:func:`polcam.camera.replay.as_recorded`).

    Parameters
    ----------
    camera
        Open and configured camera (not started).
    stage
        ``"dark"``, ``"flat"`` or ``"polarizer"`` (names the kept files and the errors).
    idle_timeout
        Seconds without a frame before giving up.
    software_trigger
        Fire the camera's software trigger for each frame.
    keep
        Folder for the frames used (must exist), or ``None``.
    """

    def __init__(self, camera: Camera, stage: str, *, idle_timeout: float = 10.0,
                 software_trigger: bool = False, keep: Path | None = None) -> None:
        self.camera = camera
        self.stage = stage
        self.idle_timeout = float(idle_timeout)
        self.software_trigger = bool(software_trigger)
        self.keep = keep
        self.taken = 0
        self.incomplete = 0
        self.dropped = 0
        self.kept: list[str] = []

    # ------------------------------------------------------------------ counts
    def _counts(self) -> tuple[int, int]:
        """(incomplete, dropped) so far, the running acquisition included."""
        inc, drop = self.incomplete, self.dropped
        if self.camera.running:
            st = self.camera.stats()
            inc, drop = inc + st.incomplete, drop + st.dropped
        return inc, drop

    def pause(self) -> None:
        """Stop acquisition (if running), adding its counts to the totals."""
        cam = self.camera
        if cam.running:
            st = cam.stats()  # before stopping: what happened while frames were wanted
            self.incomplete += st.incomplete
            self.dropped += st.dropped
            cam.stop()

    def info(self) -> dict[str, Any]:
        """Frame counts for the stage info: ``frames_good`` (used), ``frames_incomplete``, ``frames_dropped``."""
        inc, drop = self._counts()
        out: dict[str, Any] = {"frames_good": self.taken, "frames_incomplete": inc, "frames_dropped": drop}
        if self.keep is not None:
            out["kept"] = str(self.keep)
            out["inputs"] = list(self.kept)
        return out

    # ------------------------------------------------------------------ frames
    def _fail(self, what: str, got: int, n: int, label: str) -> CalibrationError:
        inc, drop = self._counts()
        return CalibrationError(
            f"camera {self.camera.camera_id} {what} after {got} of the {n} good frames asked for {label} "
            f"({inc} incomplete and {drop} dropped frames so far): expected {n} good frames; "
            "no calibration written")

    def grab(self, n: int, *, label: str | None = None, angle: float | None = None) -> Iterator[Frame]:
        """The next ``n`` good frames (acquisition started if needed, left running).

        Parameters
        ----------
        n
            Good frames to yield (incomplete ones are counted, never yielded).
        label
            What the frames are for, in error messages (default: the stage).
        angle
            Polarizer angle of these frames, degrees (written to the kept
            sidecars as ``polarizer_deg``), or ``None``.

        Yields
        ------
        Frame
            Each frame as the camera sent it ((H, W) uint8/uint16 counts with
            its metadata), replayed ones with their recording's camera id.

        Raises
        ------
        CalibrationError
            The camera ends (a replay folder played out) or sends no frame for
            ``idle_timeout`` seconds before ``n`` good frames.
        """
        from polcam.camera.replay import as_recorded

        label = label or f"the {self.stage}"
        cam = self.camera
        if not cam.running:
            cam.start()
        got = 0
        last = time.monotonic()
        outstanding = False
        fired = 0.0
        while got < n:
            now = time.monotonic()
            if self.software_trigger and (not outstanding or now - fired > 1.0):
                cam.trigger()
                outstanding, fired = True, now
            frame = cam.read(timeout=0.1)
            if frame is None:
                if cam.exhausted:
                    raise self._fail("ran out of frames", got, n, label)
                if time.monotonic() - last > self.idle_timeout:
                    raise self._fail(f"sent no frame for {self.idle_timeout:g} s", got, n, label)
                continue
            outstanding = False
            last = time.monotonic()
            frame = as_recorded(frame)
            if self.keep is not None:
                self._keep(frame, angle)
            got += 1
            self.taken += 1
            yield frame

    def _keep(self, frame: Frame, angle: float | None) -> None:
        from polcam.capture import write_captured_frame

        seq = self.taken
        if angle is None:
            name = f"{self.stage}_{seq:05d}.raw"
            extra = None
        else:  # the angle in the name too (modulo 180, as the fit takes it), so both sources agree
            name = f"pol_{seq:05d}_{float(angle) % 180.0:07.3f}deg.raw"
            extra = {ANGLE_KEY: float(angle)}
        assert self.keep is not None
        path = write_captured_frame(self.keep / name, frame, extra=extra)
        self.kept.append(str(path))

    def stage_frames(self, n: int) -> Iterator[Frame]:
        """``n`` good frames for a dark or flat, then acquisition stops."""
        yield from self.grab(n)
        self.pause()

    def polarizer_frames(self, angles: Sequence[float], n: int) -> Iterator[Frame]:
        """For each angle: ask for it on stderr, wait for Enter on stdin, then ``n`` good frames.

        A live camera is stopped while the polarizer turns, so no frame exposed
        before Enter is used; a recording played losslessly
        (:attr:`~polcam.camera.base.Camera.waits_for_reader`) simply goes on.

        Raises
        ------
        CalibrationError
            Standard input ends before an angle is confirmed, or the camera
            fails as in :meth:`grab`.
        """
        m = len(angles)
        for k, a in enumerate(angles):
            if not self.camera.waits_for_reader:
                self.pause()
            print(f"[{k + 1}/{m}] set the polarizer to {a:g} deg and press Enter", file=sys.stderr, flush=True)
            line = sys.stdin.readline() if sys.stdin is not None else ""
            if not line:
                self.pause()
                kept = f"; the {len(self.kept)} frames kept so far are in {self.keep}" if self.keep else ""
                raise CalibrationError(
                    f"standard input ended before the polarizer was set to {a:g} deg (angle {k + 1} of {m}): "
                    f"expected Enter once the polarizer is at each angle; no calibration written{kept}")
            yield from self.grab(n, label=f"the polarizer at {a:g} deg", angle=a)
        self.pause()


def _keep_folder(path: Path) -> Path:
    """Create ``--keep DIR``; refuse one that already holds raw frames."""
    from polcam.io import RAW_EXTENSIONS

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise CalibrationError("--keep: not a folder", path=path)
    if path.is_dir():
        old = [f for f in path.iterdir() if f.suffix.lower() in RAW_EXTENSIONS and not f.name.startswith(".")]
        if old:
            raise CalibrationError(f"--keep folder already holds {len(old)} raw frame(s): expected a new or empty "
                                   "folder for the frames of this calibration", path=path)
    path.mkdir(parents=True, exist_ok=True)
    return path


# options for --device only (destination -> flag)
_DEVICE_ONLY = {"count": "--frames", "angles": "--angles", "keep": "--keep"}


def _check_source(args: argparse.Namespace) -> None:
    from polcam.capture import CAMERA_SETTINGS

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
    from polcam.camera import open_camera
    from polcam.capture import camera_options, configure_camera

    angles: list[float] = []
    if stage == "polarizer":
        angles = parse_angles(args.angles)
        check_angles(angles)  # before the camera is touched
    keep = _keep_folder(args.keep) if args.keep is not None else None
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
    cal.stages[stage].update(_plain(info))
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
    from polcam.capture import add_camera_arguments

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
    from polcam.cli import run_command

    return run_command(args)
