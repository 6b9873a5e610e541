"""The calibration of one camera: its maps, where they came from, and the file that holds them.

File format (version 1): one NumPy ``.npz`` archive (``numpy.savez_compressed``,
no pickled objects; read back with ``allow_pickle=False``) holding

``meta``
    a 0-d unicode array: a JSON object with ``format`` (``"polcam-calibration"``),
    ``version`` (1), ``camera_id``, ``layout`` (spelled out, e.g.
    ``mono:90,45,135,0``), ``width``, ``height``, ``bit_depth``, ``black_level``,
    ``white_level``, ``exposure_us``, ``gain_db``, ``roi``, ``reverse_x``,
    ``reverse_y`` (``null`` when unknown), ``created`` (UTC, ISO 8601),
    ``polcam_version``, and ``stages``: per stage (``dark``, ``flat``,
    ``polarizer``) how it was made (frames, settings, thresholds, statistics);
one (height, width) array per map (:data:`MAPS`)
    ``dark`` and ``dark_noise`` (float32, counts), ``hot`` (bool), ``flat``
    (float32, per-pixel gain, mean 1 in each angle/colour class), ``dead``
    (bool), ``gain`` (float32, mean 1 in each colour class), ``diattenuation``
    (float32, [0, 1]), ``orientation_deg`` (float32, [0, 180)), ``residual``
    (float32, RMS fit residual over ``c0``) and ``outlier`` (bool).  A stage's
    maps are all present or all absent.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import zipfile
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from polcam._version import __version__
from polcam.errors import LayoutError, PolcamError
from polcam.frame import Frame
from polcam.io.atomic import atomic_write
from polcam.mosaic import Layout, parse_layout

__all__ = [
    "FORMAT",
    "MAPS",
    "STAGES",
    "VERSION",
    "Calibration",
    "CalibrationError",
    "load_calibration",
    "save_calibration",
    "utc_now",
]

#: Value of ``meta["format"]`` in every calibration file.
FORMAT = "polcam-calibration"
#: Version of the file format this module writes (and the newest it reads).
VERSION = 1

#: Map name -> (dtype, stage, description).
MAPS: dict[str, tuple[type, str, str]] = {
    "dark": (np.float32, "dark", "mean dark level, counts (includes the black level)"),
    "dark_noise": (np.float32, "dark", "temporal standard deviation of the dark, counts"),
    "hot": (np.bool_, "dark", "hot, cold or noisy pixel (robust outlier of the dark)"),
    "flat": (np.float32, "flat", "per-pixel gain, mean 1 in each (angle, colour) class"),
    "dead": (np.bool_, "flat", "dead or abnormal-gain pixel (robust outlier of the flat)"),
    "gain": (np.float32, "polarizer", "polarizer-model gain g, mean 1 in each colour class"),
    "diattenuation": (np.float32, "polarizer", "diattenuation D = (ER - 1) / (ER + 1), [0, 1]"),
    "orientation_deg": (np.float32, "polarizer", "polarizer orientation theta, degrees in [0, 180)"),
    "residual": (np.float32, "polarizer", "RMS residual of the sinusoid fit over c0"),
    "outlier": (np.bool_, "polarizer", "pixel whose polarizer fit is a robust outlier"),
}

#: Stages in the order they are applied, with their maps.
STAGES: dict[str, tuple[str, ...]] = {
    stage: tuple(name for name, spec in MAPS.items() if spec[1] == stage)
    for stage in ("dark", "flat", "polarizer")
}

# relative exposure and absolute gain differences tolerated between a dark and a frame
_EXPOSURE_RTOL = 0.01
_GAIN_ATOL_DB = 0.05


class CalibrationError(PolcamError):
    """A calibration that cannot be made, read or applied (bad frames, wrong file, mismatched camera)."""


def utc_now() -> str:
    """The time now in UTC, ISO 8601 to the second (a calibration's ``created``)."""
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


@dataclass
class Calibration:
    """Dark, flat and polarizer maps of one camera at one readout geometry.

    Attributes
    ----------
    layout
        Sensor layout of the frames it was made from (image frame).
    height, width
        Frame size in pixels (even).
    bit_depth
        Significant bits of the frames' counts.
    camera_id, exposure_us, gain_db, black_level, white_level, roi, reverse_x, reverse_y
        What the frames said (``None`` when unknown); ``exposure_us`` and
        ``gain_db`` are those of the dark (a dark is valid only at them).
    maps
        Name -> (height, width) array, see :data:`MAPS`.
    stages
        Stage name -> dict of how it was made (frames, thresholds, statistics).
    created, polcam_version
        When and by which polcam the file was made.
    source
        The file it was loaded from (``None`` when made in memory); named in
        error messages.
    """

    layout: Layout
    height: int
    width: int
    bit_depth: int = 12
    camera_id: str | None = None
    exposure_us: float | None = None
    gain_db: float | None = None
    black_level: float | None = None
    white_level: float | None = None
    roi: list[int] | None = None
    reverse_x: bool | None = None
    reverse_y: bool | None = None
    maps: dict[str, np.ndarray] = field(default_factory=dict)
    stages: dict[str, dict[str, Any]] = field(default_factory=dict)
    created: str = field(default_factory=utc_now)
    polcam_version: str = __version__
    source: str | None = None
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        try:
            self.layout = parse_layout(self.layout)
        except LayoutError as exc:
            raise CalibrationError(f"layout {self.layout!r}: {exc.reason}", path=self.source) from exc
        for key in ("height", "width", "bit_depth"):
            val = getattr(self, key)
            if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or int(val) <= 0:
                raise CalibrationError(f"{key} {val!r}: expected a positive integer", path=self.source)
            setattr(self, key, int(val))
        if self.height % 2 or self.width % 2:
            raise CalibrationError(
                f"size {self.width}x{self.height}: expected even width and height (2x2 polarizer cells)",
                path=self.source)
        checked: dict[str, np.ndarray] = {}
        for name, arr in self.maps.items():
            if name not in MAPS:
                raise CalibrationError(f"unknown map {name!r}; expected some of {', '.join(MAPS)}",
                                       path=self.source)
            a = np.asarray(arr)
            if a.shape != (self.height, self.width):
                raise CalibrationError(
                    f"map {name!r} has shape {a.shape}: expected ({self.height}, {self.width}) "
                    "(height, width) like the calibration", path=self.source)
            dtype = MAPS[name][0]
            if dtype is np.bool_:
                if a.dtype != np.bool_:
                    raise CalibrationError(f"map {name!r} of dtype {a.dtype}: expected bool", path=self.source)
            else:
                if not np.issubdtype(a.dtype, np.floating) and not np.issubdtype(a.dtype, np.integer):
                    raise CalibrationError(f"map {name!r} of dtype {a.dtype}: expected numbers",
                                           path=self.source)
                if not np.all(np.isfinite(a)):
                    raise CalibrationError(f"map {name!r} holds NaN or infinite values", path=self.source)
            checked[name] = np.ascontiguousarray(a, dtype=dtype)
        for stage, names in STAGES.items():
            have = [n for n in names if n in checked]
            if have and len(have) != len(names):
                missing = [n for n in names if n not in checked]
                raise CalibrationError(
                    f"stage {stage!r} is incomplete: maps {', '.join(missing)} missing "
                    f"(a {stage} calibration has {', '.join(names)})", path=self.source)
        self.maps = checked
        self._cache = {}

    # ---------------------------------------------------------------- queries
    @property
    def shape(self) -> tuple[int, int]:
        """(height, width)."""
        return self.height, self.width

    def has(self, stage: str) -> bool:
        """True when the maps of ``stage`` (``dark``, ``flat``, ``polarizer``) are present."""
        return all(n in self.maps for n in STAGES[stage])

    @property
    def applied_stages(self) -> list[str]:
        """The stages present, in the order they are applied."""
        return [s for s in STAGES if self.has(s)]

    def defects(self) -> np.ndarray:
        """Pixels to replace from their neighbours: hot | dead | outlier ((H, W) bool)."""
        out = np.zeros(self.shape, dtype=bool)
        for name in ("hot", "dead", "outlier"):
            if name in self.maps:
                out |= self.maps[name]
        return out

    def describe(self) -> str:
        """What the file holds, one line per fact, for the CLI and logs."""
        lines = [
            f"camera {self.camera_id or '(unknown)'}, layout {self.layout}, {self.width}x{self.height}, "
            f"{self.bit_depth}-bit, exposure {self.exposure_us if self.exposure_us is not None else '?'} us, "
            f"gain {self.gain_db if self.gain_db is not None else '?'} dB",
        ]
        for stage in self.applied_stages:
            info = self.stages.get(stage, {})
            stats = info.get("statistics", {})
            text = ", ".join(f"{k} {_fmt(v)}" for k, v in stats.items())
            lines.append(f"{stage}: {info.get('frames', '?')} frames; {text}")
        return "\n".join(lines)

    def copy(self) -> Calibration:
        """A deep copy (maps copied), without the cached matrices."""
        return Calibration(
            layout=self.layout, height=self.height, width=self.width, bit_depth=self.bit_depth,
            camera_id=self.camera_id, exposure_us=self.exposure_us, gain_db=self.gain_db,
            black_level=self.black_level, white_level=self.white_level,
            roi=None if self.roi is None else list(self.roi), reverse_x=self.reverse_x,
            reverse_y=self.reverse_y, maps={k: v.copy() for k, v in self.maps.items()},
            stages=json.loads(json.dumps(self.stages)), created=self.created,
            polcam_version=self.polcam_version, source=self.source,
        )

    # ---------------------------------------------------------- compatibility
    def check_frame(self, frame: Frame, *, check_settings: bool = True) -> Layout:
        """Refuse a frame this calibration does not describe.

        Parameters
        ----------
        frame
            The raw frame (its layout may be ``None``: the calibration's is used).
        check_settings
            With a dark map, also refuse a different exposure, gain or bit
            depth (a dark is only valid at the settings it was taken at).

        Returns
        -------
        Layout
            The layout to use (the frame's, equal to the calibration's).

        Raises
        ------
        CalibrationError
            Different size, layout, camera id, ROI or mirroring, and (with
            ``check_settings`` and a dark) exposure, gain or bit depth; the
            message names the frame, the calibration file and both values.
        """
        where = frame.metadata.get("path") or "the frame"
        what = f"calibration {self.source}" if self.source else "the calibration"
        h, w = frame.shape

        def fail(key: str, got: Any, want: Any, hint: str = "") -> None:
            raise CalibrationError(
                f"{key} mismatch: {where} has {key} {got}, {what} is for {want}{hint}", path=None)

        if (h, w) != self.shape:
            fail("size", f"{w}x{h}", f"{self.width}x{self.height}",
                 " (width x height); calibrate at the frame's ROI")
        if frame.layout is not None and frame.layout != self.layout:
            fail("layout", frame.layout, self.layout)
        cam = frame.metadata.get("camera_id")
        if cam is not None and self.camera_id is not None and str(cam) != self.camera_id:
            fail("camera_id", repr(str(cam)), repr(self.camera_id))
        roi = frame.metadata.get("roi")
        if roi is not None and self.roi is not None and [int(v) for v in roi] != list(self.roi):
            fail("roi", list(roi), list(self.roi), " ([x, y, w, h] on the sensor)")
        for key in ("reverse_x", "reverse_y"):
            val = frame.metadata.get(key)
            mine = getattr(self, key)
            if val is not None and mine is not None and bool(val) != bool(mine):
                fail(key, bool(val), bool(mine))
        if check_settings and self.has("dark"):
            hint = (" (a dark is only valid at the exposure, gain and bit depth it was taken at; "
                    "check_settings=False, or --any-exposure, accepts the frame anyway)")
            if int(frame.bit_depth) != self.bit_depth:
                fail("bit_depth", frame.bit_depth, self.bit_depth, hint)
            exp = frame.metadata.get("exposure_us")
            if exp is not None and self.exposure_us is not None and not math.isclose(
                    float(exp), self.exposure_us, rel_tol=_EXPOSURE_RTOL, abs_tol=1e-9):
                fail("exposure_us", f"{float(exp):g}", f"{self.exposure_us:g}", hint)
            gain = frame.metadata.get("gain_db")
            if gain is not None and self.gain_db is not None and abs(float(gain) - self.gain_db) > _GAIN_ATOL_DB:
                fail("gain_db", f"{float(gain):g}", f"{self.gain_db:g}", hint)
        return frame.layout or self.layout

    # ------------------------------------------------------------------ meta
    def meta(self) -> dict[str, Any]:
        """The JSON metadata written to the file."""
        return {
            "format": FORMAT, "version": VERSION, "camera_id": self.camera_id,
            "layout": self.layout.name, "width": self.width, "height": self.height,
            "bit_depth": self.bit_depth, "black_level": self.black_level,
            "white_level": self.white_level, "exposure_us": self.exposure_us,
            "gain_db": self.gain_db, "roi": self.roi, "reverse_x": self.reverse_x,
            "reverse_y": self.reverse_y, "created": self.created,
            "polcam_version": self.polcam_version, "stages": self.stages,
        }


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_fmt(x)}" for k, x in v.items()) + "}"
    return str(v)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def save_calibration(path: str | PathLike[str], calibration: Calibration) -> Path:
    """Write a calibration file atomically (a crash leaves any old file untouched).

    Parameters
    ----------
    path
        Target file; by convention ``*.npz`` (the name is used as given).
    calibration
        What to write.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    polcam.errors.FrameWriteError
        The folder is missing or not writable, the disk is full, ...
    CalibrationError
        A calibration without any map.
    """
    target = Path(path)
    if not calibration.maps:
        raise CalibrationError("nothing to save: the calibration holds no map", path=target)
    text = json.dumps(calibration.meta(), default=_json_default, allow_nan=False)
    arrays = {name: np.ascontiguousarray(arr) for name, arr in calibration.maps.items()}
    with atomic_write(target, "wb") as fh:
        np.savez_compressed(fh, meta=np.array(text), **arrays)
    return target


def _opt(meta: dict[str, Any], key: str, kinds: tuple[type, ...], path: Path) -> Any:
    val = meta.get(key)
    if val is None:
        return None
    if not isinstance(val, kinds) or (isinstance(val, bool) and bool not in kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise CalibrationError(f"meta key {key!r} has value {val!r}: expected {names} or null", path=path)
    return val


def load_calibration(path: str | PathLike[str]) -> Calibration:
    """Read a calibration file written by :func:`save_calibration`.

    Parameters
    ----------
    path
        The ``.npz`` file.

    Returns
    -------
    Calibration
        With ``source`` set to ``path``.

    Raises
    ------
    CalibrationError
        Missing or unreadable file, not a polcam calibration, a newer format
        version, pickled objects, missing or malformed metadata, maps of the
        wrong shape or an incomplete stage; the message starts with the file.
    """
    p = Path(path)
    if not p.is_file():
        raise CalibrationError("calibration file not found", path=p)
    raw_meta, arrays = _read_archive(p)
    meta = _checked_meta(raw_meta, p)
    num = (int, float)
    cal = Calibration(
        layout=meta["layout"], height=meta["height"], width=meta["width"], bit_depth=meta["bit_depth"],
        camera_id=_opt(meta, "camera_id", (str,), p),
        exposure_us=_float(_opt(meta, "exposure_us", num, p)),
        gain_db=_float(_opt(meta, "gain_db", num, p)),
        black_level=_float(_opt(meta, "black_level", num, p)),
        white_level=_float(_opt(meta, "white_level", num, p)),
        roi=meta.get("roi"),
        reverse_x=_opt(meta, "reverse_x", (bool,), p), reverse_y=_opt(meta, "reverse_y", (bool,), p),
        maps=arrays, stages=meta.get("stages") or {}, created=str(meta.get("created", "")),
        polcam_version=str(meta.get("polcam_version", "unknown")), source=str(p),
    )
    return cal


def _read_archive(p: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The ``meta`` entry and the maps of a calibration ``.npz`` (no pickles), or a CalibrationError naming ``p``."""
    try:
        is_zip = zipfile.is_zipfile(p)
    except OSError as exc:
        raise CalibrationError(f"cannot read: {exc.strerror or exc}", path=p) from exc
    if not is_zip:
        raise CalibrationError("cannot read: not a NumPy .npz archive (expected a file written by "
                               "polcam calibrate)", path=p)
    try:
        with np.load(p, allow_pickle=False) as z:
            names = list(z.files)
            if "meta" not in names:
                raise CalibrationError(
                    "no 'meta' entry: not a polcam calibration file (expected an .npz written by "
                    "polcam calibrate)", path=p)
            raw_meta = z["meta"]
            arrays = {n: z[n] for n in names if n != "meta"}
    except CalibrationError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise CalibrationError(f"cannot read: not a NumPy .npz archive ({exc})", path=p) from exc
    except ValueError as exc:
        # allow_pickle=False refuses object arrays with a ValueError
        raise CalibrationError(f"cannot read: {exc} (calibration files hold plain arrays only)", path=p) from exc
    return raw_meta, arrays


def _checked_meta(raw_meta: np.ndarray, p: Path) -> dict[str, Any]:
    """The calibration's metadata: JSON of this format, a version this polcam reads, the required keys."""
    if raw_meta.ndim != 0 or raw_meta.dtype.kind != "U":
        raise CalibrationError(f"'meta' entry of dtype {raw_meta.dtype} and shape {raw_meta.shape}: "
                               "expected a JSON string", path=p)
    try:
        meta = json.loads(str(raw_meta))
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"'meta' entry is not valid JSON: {exc}", path=p) from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CalibrationError(f"meta format {meta.get('format') if isinstance(meta, dict) else meta!r}: "
                               f"expected {FORMAT!r}", path=p)
    version = meta.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise CalibrationError(f"meta version {version!r}: expected a positive integer", path=p)
    if version > VERSION:
        raise CalibrationError(
            f"file format version {version} is newer than this polcam reads (up to {VERSION}): "
            "update polcam", path=p)
    for key in ("layout", "width", "height", "bit_depth"):
        if key not in meta or meta[key] is None:
            raise CalibrationError(f"meta key {key!r} missing", path=p)
    stages = meta.get("stages") or {}
    if not isinstance(stages, dict):
        raise CalibrationError(f"meta key 'stages' has value {stages!r}: expected an object", path=p)
    roi = meta.get("roi")
    if roi is not None and not (isinstance(roi, list) and len(roi) == 4 and all(
            isinstance(v, int) and not isinstance(v, bool) for v in roi)):
        raise CalibrationError(f"meta key 'roi' has value {roi!r}: expected [x, y, w, h] integers", path=p)
    return meta


def _float(v: Any) -> float | None:
    return None if v is None else float(v)
