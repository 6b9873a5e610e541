"""The JSON sidecar ``<stem>.json`` beside a raw frame.

Keys (:data:`polcam.frame.SIDECAR_KEYS`), each optional and ``null`` meaning
"not given":

=============== ============================================================
``layout``      layout name of the *delivered* image (``imx250mzr``,
                ``mono:90,45,135,0``, ``color:90,45,135,0:RGGB``, ...)
``pixel_format`` GenICam PixelFormat name (``Mono12p``, ``PolarizeMono8``, ...)
``vendor``      DeviceVendorName, to look the pixel format up
``width``       frame width, pixels (positive integer)
``height``      frame height, pixels (positive integer)
``bit_depth``   significant bits per pixel, 1 to 16
``msb_aligned`` true when the significant bits sit at the top of a wider word
``black_level`` counts of black (finite number >= 0)
``white_level`` counts of saturation (finite number > black_level)
``exposure_us`` exposure time, microseconds (finite number >= 0)
``gain_db``     gain, dB (finite number)
``timestamp_ns`` device timestamp, ns (integer >= 0)
``frame_id``    frame counter (integer >= 0)
``camera_id``   camera identifier (string)
``roi``         ``[x, y, w, h]`` on the sensor (integers, x, y >= 0, w, h > 0)
``reverse_x``   GenICam ReverseX (boolean)
``reverse_y``   GenICam ReverseY (boolean)
=============== ============================================================

Keys polcam does not know are kept as they are.  :func:`read_sidecar` checks
every known key and raises :class:`polcam.errors.FrameReadError` naming the
sidecar file, the key, the value and what was expected.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from polcam.errors import FrameReadError, FrameWriteError, LayoutError, PolcamError
from polcam.frame import SIDECAR_KEYS
from polcam.io.atomic import atomic_write
from polcam.mosaic import parse_layout

__all__ = ["dumps_metadata", "json_value", "read_sidecar", "sidecar_path", "validate_metadata", "write_sidecar"]


def sidecar_path(raw_path: str | PathLike[str]) -> Path:
    """The sidecar of a raw file: ``<stem>.json`` in the same folder.

    Parameters
    ----------
    raw_path
        The raw frame, e.g. ``captures/frame_0001.raw``.

    Returns
    -------
    pathlib.Path
        e.g. ``captures/frame_0001.json``.
    """
    p = Path(raw_path)
    return p.with_name(p.stem + ".json")


def _json_path(path: str | PathLike[str]) -> Path:
    p = Path(path)
    return p if p.suffix.lower() == ".json" else sidecar_path(p)


# ---------------------------------------------------------------- validation
def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_number(v: Any) -> bool:
    return (isinstance(v, (int, float, np.integer, np.floating))
            and not isinstance(v, (bool, np.bool_)))


def _is_bool(v: Any) -> bool:
    return isinstance(v, (bool, np.bool_))


def _fail(error: type[PolcamError], source: str | None, key: str, value: Any, expected: str,
          path: str | PathLike[str] | None) -> None:
    where = f" in {source}" if source else ""
    raise error(f"key {key!r}{where} has value {value!r}: expected {expected}", path=path)


def validate_metadata(
    data: Mapping[str, Any],
    *,
    path: str | PathLike[str] | None = None,
    source: str | None = None,
    error: type[PolcamError] = FrameReadError,
) -> dict[str, Any]:
    """Check the known sidecar keys of ``data`` and return a normalised copy.

    Parameters
    ----------
    data
        Sidecar dictionary (or keyword arguments, or JSON embedded in a file).
    path
        File named in error messages.
    source
        Where the values came from, for the message (``"keyword arguments"``).
    error
        Error class to raise (:class:`FrameReadError` when reading,
        :class:`FrameWriteError` when writing).

    Returns
    -------
    dict
        A copy: integers as ``int``, numbers as ``float``, booleans as
        ``bool``, ``roi`` as a list of four ints, ``layout`` as given (a
        string); unknown keys unchanged.

    Raises
    ------
    PolcamError
        ``error``, naming the key, the value and what was expected.
    """
    out: dict[str, Any] = {}
    for key, value in data.items():
        if not isinstance(key, str):
            _fail(error, source, str(key), value, "string keys", path)
        if value is None or key not in SIDECAR_KEYS:
            out[key] = value
            continue
        if key == "layout":
            if not isinstance(value, str):
                _fail(error, source, key, value, "a layout name string", path)
            try:
                parse_layout(value)
            except LayoutError as exc:
                _fail(error, source, key, value, f"a known layout ({exc.reason})", path)
            out[key] = value
        elif key in ("pixel_format", "vendor", "camera_id"):
            if not isinstance(value, str) or not value.strip():
                _fail(error, source, key, value, "a non-empty string", path)
            out[key] = value
        elif key in ("width", "height"):
            if not _is_int(value) or int(value) <= 0:
                _fail(error, source, key, value, "a positive integer (pixels)", path)
            out[key] = int(value)
        elif key == "bit_depth":
            if not _is_int(value) or not 1 <= int(value) <= 16:
                _fail(error, source, key, value, "an integer from 1 to 16", path)
            out[key] = int(value)
        elif key in ("msb_aligned", "reverse_x", "reverse_y"):
            if not _is_bool(value):
                _fail(error, source, key, value, "true or false", path)
            out[key] = bool(value)
        elif key in ("black_level", "white_level", "exposure_us"):
            if not _is_number(value) or not math.isfinite(float(value)) or float(value) < 0:
                _fail(error, source, key, value, "a finite number >= 0", path)
            out[key] = float(value)
        elif key == "gain_db":
            if not _is_number(value) or not math.isfinite(float(value)):
                _fail(error, source, key, value, "a finite number (dB)", path)
            out[key] = float(value)
        elif key in ("timestamp_ns", "frame_id"):
            if not _is_int(value) or int(value) < 0:
                _fail(error, source, key, value, "an integer >= 0", path)
            out[key] = int(value)
        elif key == "roi":
            ok = (isinstance(value, (list, tuple, np.ndarray)) and len(value) == 4
                  and all(_is_int(v) for v in value))
            if ok:
                x, y, w, h = (int(v) for v in value)
                ok = x >= 0 and y >= 0 and w > 0 and h > 0
            if not ok:
                _fail(error, source, key, value,
                      "[x, y, w, h]: four integers with x, y >= 0 and w, h > 0", path)
            out[key] = [int(v) for v in value]
        else:  # pragma: no cover - every SIDECAR_KEYS entry is handled above
            out[key] = value
    black, white = out.get("black_level"), out.get("white_level")
    if black is not None and white is not None and white <= black:
        _fail(error, source, "white_level", white, f"a value above black_level {black}", path)
    return out


# ----------------------------------------------------------------- file I/O
def read_sidecar(path: str | PathLike[str]) -> dict[str, Any] | None:
    """Read and check the sidecar of a raw file.

    Parameters
    ----------
    path
        The raw file (its ``<stem>.json`` is read) or the sidecar itself
        (a path ending in ``.json``).

    Returns
    -------
    dict or None
        The checked sidecar (see :func:`validate_metadata`), or ``None`` when
        there is no sidecar file.

    Raises
    ------
    FrameReadError
        Unreadable file, invalid JSON, a top level that is not an object, or
        a known key with a wrong type or value; the message names the sidecar.
    """
    side = _json_path(path)
    try:
        text = side.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except IsADirectoryError:
        raise FrameReadError("sidecar is a folder, expected a JSON file", path=side) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FrameReadError(f"cannot read sidecar: {exc}", path=side) from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FrameReadError(
            f"sidecar is not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})",
            path=side,
        ) from exc
    if not isinstance(data, dict):
        raise FrameReadError(
            f"sidecar top level is a {type(data).__name__}: expected a JSON object", path=side
        )
    return validate_metadata(data, path=side)


def _to_json(value: Any) -> Any:
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (Path, PathLike)):
        return str(value)
    if hasattr(value, "short_name"):  # a polcam Layout
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def json_value(key: str, value: Any, *, path: str | PathLike[str] | None = None) -> str:
    """Compact JSON text of one metadata value; refuses NaN/inf and unserialisable values.

    Raises
    ------
    FrameWriteError
        Naming ``path``, the key and the value.
    """
    try:
        return json.dumps(value, default=_to_json, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise FrameWriteError(
            f"metadata key {key!r} has value {value!r}, which cannot be stored as JSON ({exc})",
            path=path,
        ) from exc


def dumps_metadata(data: Mapping[str, Any], *, path: str | PathLike[str] | None = None,
                   indent: int | None = 2) -> str:
    """JSON text of a metadata dictionary; refuses NaN/inf and unserialisable values.

    Raises
    ------
    FrameWriteError
        Naming ``path`` and the offending key.
    """
    for key, value in data.items():
        json_value(str(key), value, path=path)
    return json.dumps(dict(data), default=_to_json, allow_nan=False, indent=indent)


def write_sidecar(path: str | PathLike[str], data: Mapping[str, Any]) -> Path:
    """Write the sidecar of a raw file atomically.

    Parameters
    ----------
    path
        The raw file (the sidecar goes to its ``<stem>.json``) or the sidecar
        path itself (ending in ``.json``).
    data
        The sidecar dictionary; known keys are checked as on reading, unknown
        keys are written as they are (they must be JSON serialisable).

    Returns
    -------
    pathlib.Path
        The sidecar written.

    Raises
    ------
    FrameWriteError
        A bad value (naming the key) or an unwritable target.
    """
    side = _json_path(path)
    if not isinstance(data, Mapping):
        raise FrameWriteError(f"sidecar data is a {type(data).__name__}: expected a dict", path=side)
    checked = validate_metadata(data, path=side, error=FrameWriteError)
    text = dumps_metadata(checked, path=side) + "\n"
    with atomic_write(side, "w") as fh:
        fh.write(text)
    return side
