"""Tests of polcam.calibration.store: the calibration file and the refusal of mismatched frames."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from polcam.calibration.store import (
    FORMAT,
    MAPS,
    VERSION,
    Calibration,
    CalibrationError,
    load_calibration,
    save_calibration,
)
from polcam.errors import PolcamError
from polcam.frame import Frame

H, W = 8, 12


def full_calibration(**kw) -> Calibration:
    rng = np.random.default_rng(0)
    maps = {}
    for name, (dtype, _stage, _desc) in MAPS.items():
        maps[name] = (rng.random((H, W)) < 0.1) if dtype is np.bool_ else rng.random((H, W)).astype(np.float32)
    args = dict(layout="imx250myr", height=H, width=W, bit_depth=12, camera_id="cam-1", exposure_us=5000.0,
                gain_db=1.5, black_level=64.0, white_level=4095.0, roi=[8, 4, W, H], reverse_x=False,
                reverse_y=False, maps=maps,
                stages={"dark": {"frames": 16, "statistics": {"hot_pixels": 3}}, "flat": {"frames": 8},
                        "polarizer": {"frames": 64, "angles_deg": [0.0, 22.5]}})
    args.update(kw)
    return Calibration(**args)


def frame(**meta) -> Frame:
    base = {"camera_id": "cam-1", "exposure_us": 5000.0, "gain_db": 1.5, "roi": [8, 4, W, H]}
    base.update(meta)
    return Frame(np.zeros((H, W), np.uint16), layout="imx250myr", bit_depth=12, black_level=64.0,
                 metadata={k: v for k, v in base.items() if v is not None})


def test_round_trip_keeps_every_map_and_field(tmp_path):
    cal = full_calibration()
    path = save_calibration(tmp_path / "cal.npz", cal)
    back = load_calibration(path)
    assert back.source == str(path)
    for name in MAPS:
        assert back.maps[name].dtype == cal.maps[name].dtype
        np.testing.assert_array_equal(back.maps[name], cal.maps[name])
    for key in ("layout", "height", "width", "bit_depth", "camera_id", "exposure_us", "gain_db", "black_level",
                "white_level", "roi", "reverse_x", "reverse_y", "stages", "created", "polcam_version"):
        assert getattr(back, key) == getattr(cal, key), key
    assert back.applied_stages == ["dark", "flat", "polarizer"]


def test_file_is_a_plain_npz_with_versioned_json_meta(tmp_path):
    path = save_calibration(tmp_path / "cal.npz", full_calibration())
    with np.load(path, allow_pickle=False) as z:  # loads without pickles
        meta = json.loads(str(z["meta"]))
        assert set(z.files) == {"meta", *MAPS}
    assert meta["format"] == FORMAT and meta["version"] == VERSION == 1
    assert meta["layout"] == "color:90,45,135,0:RGGB"
    assert (meta["camera_id"], meta["width"], meta["height"], meta["exposure_us"], meta["gain_db"]) == (
        "cam-1", W, H, 5000.0, 1.5)


def test_partial_calibration_round_trips(tmp_path):
    cal = full_calibration(maps={"dark": np.full((H, W), 64.5, np.float32),
                                 "dark_noise": np.ones((H, W), np.float32),
                                 "hot": np.zeros((H, W), bool)})
    back = load_calibration(save_calibration(tmp_path / "dark.npz", cal))
    assert back.applied_stages == ["dark"] and back.has("dark") and not back.has("polarizer")


def test_save_is_atomic_and_refuses_an_empty_calibration(tmp_path):
    target = tmp_path / "cal.npz"
    target.write_bytes(b"old")
    with pytest.raises(CalibrationError, match="holds no map"):
        save_calibration(target, full_calibration(maps={}))
    assert target.read_bytes() == b"old"
    with pytest.raises(PolcamError, match="does not exist"):
        save_calibration(tmp_path / "missing" / "cal.npz", full_calibration())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.npz"]  # no temporary left behind


@pytest.mark.parametrize(("meta", "maps", "message"), [
    ({"format": "something-else", "version": 1}, {}, "expected 'polcam-calibration'"),
    ({"format": FORMAT, "version": 99}, {}, "version 99 is newer"),
    ({"format": FORMAT, "version": 1, "layout": "imx250mzr", "width": W}, {}, "meta key 'height' missing"),
    ({"format": FORMAT, "version": 1, "layout": "nonsense", "width": W, "height": H, "bit_depth": 12}, {},
     "layout 'nonsense'"),
    ({"format": FORMAT, "version": 1, "layout": "imx250mzr", "width": W, "height": H, "bit_depth": 12},
     {"dark": np.zeros((H, W + 2), np.float32)}, "map 'dark' has shape"),
    ({"format": FORMAT, "version": 1, "layout": "imx250mzr", "width": W, "height": H, "bit_depth": 12},
     {"dark": np.zeros((H, W), np.float32)}, "stage 'dark' is incomplete: maps dark_noise, hot missing"),
    ({"format": FORMAT, "version": 1, "layout": "imx250mzr", "width": W, "height": H, "bit_depth": 12},
     {"bogus": np.zeros((H, W), np.float32)}, "unknown map 'bogus'"),
    ({"format": FORMAT, "version": 1, "layout": "imx250mzr", "width": W, "height": H, "bit_depth": 12,
      "camera_id": 7}, {}, "meta key 'camera_id' has value 7"),
])
def test_bad_files_are_refused_with_the_file_named(tmp_path, meta, maps, message):
    path = tmp_path / "bad.npz"
    np.savez(path, meta=np.array(json.dumps(meta)), **maps)
    with pytest.raises(CalibrationError, match=message) as info:
        load_calibration(path)
    assert str(info.value).startswith(str(path))


def test_unreadable_files_are_refused(tmp_path):
    with pytest.raises(CalibrationError, match="not found"):
        load_calibration(tmp_path / "nope.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"this is not a zip archive")
    with pytest.raises(CalibrationError, match="not a NumPy .npz archive"):
        load_calibration(junk)
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, meta=np.array([{"format": FORMAT}], dtype=object))
    with pytest.raises(CalibrationError, match="plain arrays only"):
        load_calibration(pickled)
    nometa = tmp_path / "nometa.npz"
    np.savez(nometa, dark=np.zeros((2, 2)))
    with pytest.raises(CalibrationError, match="no 'meta' entry"):
        load_calibration(nometa)
    assert zipfile.is_zipfile(nometa)


def test_matching_frame_is_accepted_and_unknown_layout_takes_the_calibrations():
    cal = full_calibration()
    assert cal.check_frame(frame()) == cal.layout
    bare = Frame(np.zeros((H, W), np.uint16), bit_depth=12)  # no layout, no metadata
    assert cal.check_frame(bare) == cal.layout


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"camera_id": "cam-2"},
     "camera_id mismatch: the frame has camera_id 'cam-2', the calibration is for 'cam-1'"),
    ({"roi": [0, 0, W, H]}, r"roi mismatch: .*\[0, 0, 12, 8\].*\[8, 4, 12, 8\]"),
    ({"exposure_us": 10000.0}, "exposure_us mismatch: .* 10000, .* 5000"),
    ({"gain_db": 6.0}, "gain_db mismatch: .* 6, .* 1.5"),
    ({"reverse_x": True}, "reverse_x mismatch"),
])
def test_mismatched_frames_are_refused_naming_both_values(kwargs, message):
    with pytest.raises(CalibrationError, match=message):
        full_calibration().check_frame(frame(**kwargs))


def test_mismatched_size_and_layout_are_refused_naming_both_values(tmp_path):
    cal = load_calibration(save_calibration(tmp_path / "cal.npz", full_calibration()))
    wrong_size = Frame(np.zeros((H, W + 4), np.uint16), layout="imx250myr", bit_depth=12,
                       metadata={"path": "shot_001.png"})
    with pytest.raises(CalibrationError, match=r"size mismatch: shot_001.png has size 16x8, calibration .*cal.npz "
                                               r"is for 12x8"):
        cal.check_frame(wrong_size)
    wrong_layout = Frame(np.zeros((H, W), np.uint16), layout="imx250mzr", bit_depth=12)
    with pytest.raises(CalibrationError, match="layout mismatch: the frame has layout imx250mzr, .* imx250myr"):
        cal.check_frame(wrong_layout)


def test_settings_are_only_checked_for_a_dark_and_can_be_waived():
    cal = full_calibration()
    other_depth = Frame(np.zeros((H, W), np.uint8), layout="imx250myr", bit_depth=8,
                        metadata={"camera_id": "cam-1"})
    with pytest.raises(CalibrationError, match="bit_depth mismatch"):
        cal.check_frame(other_depth)
    cal.check_frame(other_depth, check_settings=False)
    no_dark = full_calibration(maps={k: v for k, v in full_calibration().maps.items()
                                     if k not in ("dark", "dark_noise", "hot")})
    no_dark.check_frame(frame(exposure_us=123.0))  # a flat/polarizer does not depend on exposure


def test_constructor_validates_its_inputs():
    with pytest.raises(CalibrationError, match="expected even width and height"):
        Calibration(layout="imx250mzr", height=7, width=8)
    with pytest.raises(CalibrationError, match="NaN"):
        Calibration(layout="imx250mzr", height=2, width=2,
                    maps={"dark": np.full((2, 2), np.nan, np.float32), "dark_noise": np.ones((2, 2), np.float32),
                          "hot": np.zeros((2, 2), bool)})
    with pytest.raises(CalibrationError, match="expected bool"):
        Calibration(layout="imx250mzr", height=2, width=2,
                    maps={"dark": np.ones((2, 2), np.float32), "dark_noise": np.ones((2, 2), np.float32),
                          "hot": np.zeros((2, 2), np.float32)})


def test_describe_names_camera_and_stages():
    text = full_calibration().describe()
    assert "cam-1" in text and "imx250myr" in text and "dark: 16 frames; hot_pixels 3" in text
