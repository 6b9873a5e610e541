"""Tests of polcam.io.sidecar: path, round trip, validation with clear messages."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from polcam.errors import FrameReadError, FrameWriteError
from polcam.frame import SIDECAR_KEYS
from polcam.io.sidecar import read_sidecar, sidecar_path, validate_metadata, write_sidecar

FULL = {
    "layout": "imx250mzr",
    "pixel_format": "PolarizeMono12p",
    "vendor": "LUCID Vision Labs",
    "width": 2448,
    "height": 2048,
    "bit_depth": 12,
    "msb_aligned": False,
    "black_level": 64.0,
    "white_level": 4095.0,
    "exposure_us": 5000.0,
    "gain_db": 0.5,
    "timestamp_ns": 1_700_000_000_123_456_789,
    "frame_id": 42,
    "camera_id": "PHX050S-Q 212300123",
    "roi": [0, 0, 2448, 2048],
    "reverse_x": False,
    "reverse_y": True,
}


def test_sidecar_path_is_stem_json_beside_the_file() -> None:
    assert sidecar_path("caps/frame_0001.raw") == Path("caps/frame_0001.json")
    assert sidecar_path(Path("/a/b/x.tar.raw")) == Path("/a/b/x.tar.json")
    assert sidecar_path("noext") == Path("noext.json")


def test_full_dictionary_covers_every_key() -> None:
    assert set(FULL) == set(SIDECAR_KEYS)


def test_round_trip_with_unknown_keys(tmp_path: Path) -> None:
    raw = tmp_path / "f.raw"
    data = dict(FULL, operator="A. Person", notes={"lens": "25 mm"})
    written = write_sidecar(raw, data)
    assert written == tmp_path / "f.json"
    on_disk = json.loads(written.read_text())
    assert on_disk == data
    assert read_sidecar(raw) == data
    assert read_sidecar(written) == data  # the .json path itself works too


def test_absent_sidecar_is_none(tmp_path: Path) -> None:
    assert read_sidecar(tmp_path / "nothing.raw") is None


def test_nulls_are_allowed(tmp_path: Path) -> None:
    write_sidecar(tmp_path / "a.png", {"layout": None, "width": None})
    assert read_sidecar(tmp_path / "a.png") == {"layout": None, "width": None}


def test_numpy_values_are_written_as_json(tmp_path: Path) -> None:
    write_sidecar(tmp_path / "n.raw", {"width": np.int64(8), "gain_db": np.float32(1.5),
                                       "reverse_x": np.bool_(True), "roi": np.array([0, 2, 8, 4])})
    assert read_sidecar(tmp_path / "n.raw") == {"width": 8, "gain_db": 1.5, "reverse_x": True,
                                                "roi": [0, 2, 8, 4]}


BAD = [
    ("layout", "hexagonal", "layout"),
    ("layout", 7, "layout name"),
    ("width", -3, "positive integer"),
    ("width", 2.5, "positive integer"),
    ("height", True, "positive integer"),
    ("bit_depth", 20, "1 to 16"),
    ("msb_aligned", "yes", "true or false"),
    ("msb_aligned", 1, "true or false"),
    ("reverse_x", "false", "true or false"),
    ("black_level", -1, ">= 0"),
    ("white_level", "4095", "number"),
    ("exposure_us", float("nan"), "finite"),
    ("timestamp_ns", -5, "integer >= 0"),
    ("frame_id", 1.5, "integer"),
    ("camera_id", 12, "string"),
    ("pixel_format", "", "non-empty string"),
    ("roi", [0, 0, 10], "[x, y, w, h]"),
    ("roi", [-2, 0, 10, 10], "[x, y, w, h]"),
]


@pytest.mark.parametrize("key,value,expected", BAD)
def test_bad_values_name_file_key_value_and_expectation(tmp_path: Path, key: str, value: object,
                                                        expected: str) -> None:
    side = tmp_path / "shot_3.json"
    side.write_text(json.dumps({key: value}))
    with pytest.raises(FrameReadError) as err:
        read_sidecar(tmp_path / "shot_3.raw")
    msg = str(err.value)
    assert "shot_3.json" in msg
    assert repr(key) in msg
    assert repr(value) in msg
    assert "expected" in msg and expected in msg


def test_white_not_above_black(tmp_path: Path) -> None:
    (tmp_path / "w.json").write_text(json.dumps({"black_level": 100, "white_level": 50}))
    with pytest.raises(FrameReadError) as err:
        read_sidecar(tmp_path / "w.raw")
    assert "w.json" in str(err.value) and "white_level" in str(err.value) and "black_level" in str(err.value)


def test_invalid_json_names_file_and_position(tmp_path: Path) -> None:
    (tmp_path / "j.json").write_text('{"width": 8,\n "height": }')
    with pytest.raises(FrameReadError) as err:
        read_sidecar(tmp_path / "j.raw")
    assert "j.json" in str(err.value) and "not valid JSON" in str(err.value) and "line 2" in str(err.value)


def test_top_level_must_be_an_object(tmp_path: Path) -> None:
    (tmp_path / "l.json").write_text("[1, 2]")
    with pytest.raises(FrameReadError, match="l.json.*JSON object"):
        read_sidecar(tmp_path / "l.raw")


def test_write_refuses_bad_values(tmp_path: Path) -> None:
    with pytest.raises(FrameWriteError) as err:
        write_sidecar(tmp_path / "b.raw", {"width": -1})
    assert "b.json" in str(err.value) and "'width'" in str(err.value)
    with pytest.raises(FrameWriteError, match="cannot be stored as JSON"):
        write_sidecar(tmp_path / "b.raw", {"extra": object()})
    with pytest.raises(FrameWriteError, match="'note'"):
        write_sidecar(tmp_path / "b.raw", {"note": float("inf")})
    assert not (tmp_path / "b.json").exists()


def test_validate_metadata_names_the_source() -> None:
    with pytest.raises(FrameReadError) as err:
        validate_metadata({"bit_depth": 0}, path="x.png", source="the keyword arguments")
    assert "x.png" in str(err.value) and "keyword arguments" in str(err.value)
