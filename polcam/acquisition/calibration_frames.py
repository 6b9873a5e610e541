"""Calibration frames: where they come from and which polarizer angle each was taken at.

- :func:`list_frames`, :func:`read_frames`: frames on disk (folders expanded);
- :func:`angle_of`, :func:`angle_from_name`, :func:`parse_angles`: the
  polarizer angle of a frame (its sidecar key ``polarizer_deg``, or its name);
- :class:`FrameGrabber`: exactly N good frames at a time from a camera
  (through the camera's one read loop, :meth:`polcam.camera.base.Camera.poll_frames`),
  for ``polcam calibrate --device`` (:mod:`polcam.commands.calibrate`).

Live, each stage takes exactly N good frames (incomplete and dropped frames
are counted, recorded in the stage's info and reported; a camera that ends
or falls silent before N good frames is an error and nothing is written).
The polarizer stage asks on stderr, for each angle, ``set the polarizer to X
deg and press Enter``, reads a line from stdin, then grabs N frames at that
angle; a live camera is stopped while the polarizer turns, so no frame
exposed before Enter is used.  With ``keep`` every frame used is written, as
the camera sent it, with its sidecar (polarizer frames also with
``polarizer_deg``), so the calibration can be redone from disk.

Faults, as in ``polcam capture``: the ``--keep`` folder is checked for
writing before the camera starts (:func:`keep_folder`); a kept frame that
cannot be written, or a camera that disconnects, ends the stage with a
:class:`~polcam.calibration.store.CalibrationError` that says so, how many
frames were taken and where the kept ones are; no calibration is written,
no sidecar is left without its frame.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from polcam._jsonable import jsonable
from polcam.acquisition.saving import check_writable, write_captured_frame
from polcam.calibration.store import CalibrationError
from polcam.camera.base import CameraDisconnectedError, FrameTimeout
from polcam.camera.replay import as_recorded
from polcam.errors import FrameReadError, FrameWriteError
from polcam.frame import Frame
from polcam.io import RAW_EXTENSIONS, read_frame, read_sidecar
from polcam.io.atomic import os_reason
from polcam.io.listing import list_raw_files, raw_files_in

if TYPE_CHECKING:
    from polcam.camera.base import Camera

__all__ = ["ANGLE_KEY", "FrameGrabber", "angle_from_name", "angle_of", "keep_folder", "list_frames",
           "parse_angles", "plain", "read_frames"]

#: Sidecar key holding the polarizer angle of a calibration frame, degrees.
ANGLE_KEY = "polarizer_deg"

_DEG_RE = re.compile(r"(?<![0-9.])(\d+(?:\.\d+)?)\s*deg", re.IGNORECASE)
_NUM_RE = re.compile(r"\d+(?:\.\d+)?")


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
    try:
        out = list_raw_files(paths, recursive=recursive)
    except FrameReadError as exc:
        raise CalibrationError("no such file or folder", path=exc.path) from None
    if not out:
        shown = ", ".join(str(p) for p in paths)
        raise CalibrationError(f"no raw frames found in {shown} (extensions: {', '.join(RAW_EXTENSIONS[:10])}, ...)")
    return out


def read_frames(files: Sequence[Path], layout: str | None) -> Iterator[Frame]:
    """Each file read as a frame (:func:`polcam.io.read_frame`), one at a time."""
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


def plain(obj: Any) -> Any:
    """``obj`` with tuples as lists and non-finite floats as ``None`` (for the file's JSON)."""
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
        kept = f"; the {len(self.kept)} frames kept so far are in {self.keep}" if self.keep is not None else ""
        return CalibrationError(
            f"camera {self.camera.camera_id} {what} after {got} of the {n} good frames asked for {label} "
            f"({inc} incomplete and {drop} dropped frames so far): expected {n} good frames; "
            f"no calibration written{kept}")

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
        label = label or f"the {self.stage}"
        cam = self.camera
        if not cam.running:
            cam.start()
        got = 0
        reads = cam.poll_frames(poll=0.1, idle_timeout=self.idle_timeout, software_trigger=self.software_trigger)
        try:
            while got < n:
                try:
                    frame = next(reads)
                except StopIteration:
                    raise self._fail("ran out of frames", got, n, label) from None
                except FrameTimeout:
                    raise self._fail(f"sent no frame for {self.idle_timeout:g} s", got, n, label) from None
                except CameraDisconnectedError as exc:
                    reason = self.camera.lost or str(exc)
                    raise self._fail(f"disconnected ({reason})", got, n, label) from None
                if frame is None:
                    continue
                frame = as_recorded(frame)
                if self.keep is not None:
                    self._keep(frame, angle)
                got += 1
                self.taken += 1
                yield frame
        finally:
            reads.close()

    def _keep(self, frame: Frame, angle: float | None) -> None:
        seq = self.taken
        if angle is None:
            name = f"{self.stage}_{seq:05d}.raw"
            extra = None
        else:  # the angle in the name too (modulo 180, as the fit takes it), so both sources agree
            name = f"pol_{seq:05d}_{float(angle) % 180.0:07.3f}deg.raw"
            extra = {ANGLE_KEY: float(angle)}
        assert self.keep is not None

        try:
            path = write_captured_frame(self.keep / name, frame, extra=extra)
        except (FrameWriteError, OSError) as exc:
            self.pause()
            raise CalibrationError(
                f"cannot keep calibration frame {name}: {os_reason(exc)}; the {len(self.kept)} frames kept so far "
                f"are in {self.keep}; no calibration written", path=self.keep) from None
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


def keep_folder(path: Path) -> Path:
    """Create ``--keep DIR``; refuse one that already holds raw frames, or that cannot be written.

    Raises
    ------
    CalibrationError
        Not a folder, already holding raw frames, or not writable (read-only,
        permissions, a full disk: the message names the folder and the reason).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise CalibrationError("--keep: not a folder", path=path)
    if path.is_dir():
        old = raw_files_in(path)
        if old:
            raise CalibrationError(f"--keep folder already holds {len(old)} raw frame(s): expected a new or empty "
                                   "folder for the frames of this calibration", path=path)
    try:
        check_writable(path)
    except FrameWriteError as exc:
        raise CalibrationError(f"--keep: {exc.reason}", path=path) from None
    return path
