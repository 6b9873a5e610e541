"""Tests of polcam.io.readers.read_frame.

Input files are made with tools other than the reader's (OpenCV, tifffile,
hand-written TIFF/PGM bytes), so the expected counts are known independently.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from polcam.errors import FrameReadError, PixelFormatError
from polcam.io.packing import pack
from polcam.io.readers import RAW_EXTENSIONS, declared_size, interleave_angles, read_frame
from polcam.mosaic import ANGLES, parse_layout

REAL_PNG = Path(__import__("os").environ.get("POLCAM_SHARED_DATA", Path(__file__).resolve().parents[3] / "shared" / "data")) / "real-imx250mzr" / "fruits.png"


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _sidecar(path: Path, **keys: object) -> None:
    path.with_name(path.stem + ".json").write_text(json.dumps(keys))


def _tiff_12bit(path: Path, counts: np.ndarray) -> None:
    """A baseline little-endian TIFF with BitsPerSample=12, written byte by byte.

    TIFF packs samples wider than 8 bits most-significant bit first; each row
    starts on a byte boundary (width even here, so rows are whole bytes).
    """
    h, w = counts.shape
    assert w % 2 == 0
    rows = bytearray()
    for row in counts.astype(int):
        for a, b in zip(row[0::2], row[1::2]):
            rows += bytes([a >> 4, ((a & 0xF) << 4) | (b >> 8), b & 0xFF])
    entries = [  # (tag, type, count, value); type 3 = SHORT, 4 = LONG
        (256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 12), (259, 3, 1, 1), (262, 3, 1, 1),
        (273, 4, 1, 0), (277, 3, 1, 1), (278, 4, 1, h), (279, 4, 1, len(rows)),
    ]
    ifd_size = 2 + 12 * len(entries) + 4
    data_offset = 8 + ifd_size
    out = bytearray(b"II" + struct.pack("<HI", 42, 8))
    out += struct.pack("<H", len(entries))
    for tag, typ, count, value in entries:
        if tag == 273:
            value = data_offset
        if typ == 3:
            out += struct.pack("<HHIHH", tag, typ, count, value, 0)
        else:
            out += struct.pack("<HHII", tag, typ, count, value)
    out += struct.pack("<I", 0)
    out += rows
    path.write_bytes(bytes(out))


def _dng(path: Path, mosaic: np.ndarray, *, black: tuple[int, ...], white: int,
         linear_raw: bool = False) -> None:
    """A DNG (CFA, RGGB) written with tifffile and the DNG 1.4 tags LibRaw needs."""
    import tifffile

    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),       # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),       # DNGBackwardVersion
        (50708, "s", 0, "polcam test camera", True),  # UniqueCameraModel
        (50717, "H", 1, white, True),              # WhiteLevel
    ]
    if linear_raw:
        tifffile.imwrite(path, mosaic, photometric=34892, extratags=tags, compression=None,
                         metadata=None, subfiletype=0, planarconfig="contig")
        return
    tags += [
        (33421, "H", 2, (2, 2), True),             # CFARepeatPatternDim
        (33422, "B", 4, (0, 1, 1, 2), True),       # CFAPattern R G / G B
        (50710, "B", 3, (0, 1, 2), True),          # CFAPlaneColor
        (50711, "H", 1, 1, True),                  # CFALayout rectangular
        (50713, "H", 2, (2, 2), True),             # BlackLevelRepeatDim
        (50714, "H", len(black), black, True),     # BlackLevel per CFA position
    ]
    tifffile.imwrite(path, mosaic, photometric=32803, extratags=tags, compression=None,
                     metadata=None, subfiletype=0)


# ------------------------------------------------------------ real data
def test_real_imx250mzr_png() -> None:
    if not REAL_PNG.exists():
        pytest.skip("real IMX250MZR frame not available")
    frame = read_frame(REAL_PNG, layout="imx250mzr")
    assert frame.mosaic.shape == (2048, 2448)
    assert frame.mosaic.dtype == np.uint8
    assert frame.bit_depth == 8 and frame.white_level == 255.0 and frame.black_level == 0.0
    assert frame.layout == parse_layout("imx250mzr")
    assert frame.metadata["path"] == str(REAL_PNG) and frame.metadata["format"] == "png"
    # the same counts as an independent decoder
    ref = cv2.imread(str(REAL_PNG), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(frame.mosaic, ref)
    plain = read_frame(REAL_PNG)
    assert plain.layout is None  # nothing says where the polarizers are


# ---------------------------------------------------- OpenImageIO formats
@pytest.mark.parametrize("ext,dtype", [(".png", np.uint8), (".png", np.uint16), (".tif", np.uint8),
                                       (".tif", np.uint16), (".tiff", np.uint16), (".bmp", np.uint8)])
def test_oiio_formats_read_exact_counts(tmp_path: Path, ext: str, dtype: type) -> None:
    info = np.iinfo(dtype)
    counts = _rng().integers(0, int(info.max) + 1, size=(6, 10), dtype=dtype)
    counts[0, 0], counts[0, 1] = 0, info.max
    path = tmp_path / f"m{ext}"
    assert cv2.imwrite(str(path), counts)
    frame = read_frame(path)
    assert frame.mosaic.dtype == dtype
    np.testing.assert_array_equal(frame.mosaic, counts)
    assert frame.bit_depth == 8 * np.dtype(dtype).itemsize
    assert frame.white_level == float(info.max)


def test_msb_aligned_12_bit_in_16_bit_tiff(tmp_path: Path) -> None:
    counts = _rng(1).integers(0, 4096, size=(8, 12), dtype=np.uint16)
    counts[0, :2] = (0, 4095)
    path = tmp_path / "shifted.tif"
    assert cv2.imwrite(str(path), (counts << 4).astype(np.uint16))
    _sidecar(path, bit_depth=12, msb_aligned=True, layout="imx250mzr")
    frame = read_frame(path)
    np.testing.assert_array_equal(frame.mosaic, counts)
    assert frame.bit_depth == 12 and frame.white_level == 4095.0
    assert frame.metadata["msb_aligned"] is True and frame.metadata["layout"] == "imx250mzr"
    # keywords do the same without a sidecar, and win over it
    path.with_name("shifted.json").unlink()
    np.testing.assert_array_equal(read_frame(path, bit_depth=12, msb_aligned=True).mosaic, counts)
    # without msb_aligned, the values do not fit 12 bits: the message says why and what to do
    with pytest.raises(FrameReadError) as err:
        read_frame(path, bit_depth=12)
    msg = str(err.value)
    assert "shifted.tif" in msg and "above the 12-bit range" in msg and "msb_aligned" in msg


def test_12_bit_tiff_on_disk_reads_back_as_counts(tmp_path: Path) -> None:
    counts = np.arange(4096, dtype=np.uint16).reshape(64, 64)  # every 12-bit value once
    path = tmp_path / "twelve.tif"
    _tiff_12bit(path, counts)
    frame = read_frame(path)
    np.testing.assert_array_equal(frame.mosaic, counts)
    assert frame.bit_depth == 12 and frame.white_level == 4095.0


@pytest.mark.parametrize("maxval", [255, 1023, 4095, 65535])
def test_pgm_binary_keeps_counts_and_maxval(tmp_path: Path, maxval: int) -> None:
    counts = _rng(2).integers(0, maxval + 1, size=(4, 6))
    counts[0, 0] = maxval
    wide = maxval > 255
    raster = counts.astype(">u2" if wide else np.uint8).tobytes()
    path = tmp_path / "m.pgm"
    path.write_bytes(b"P5\n# made by the test\n6 4\n" + str(maxval).encode() + b"\n" + raster)
    frame = read_frame(path)
    np.testing.assert_array_equal(frame.mosaic, counts)
    assert frame.mosaic.dtype == (np.uint16 if wide else np.uint8)
    assert frame.white_level == float(maxval)
    assert frame.bit_depth == maxval.bit_length()


def test_pgm_ascii(tmp_path: Path) -> None:
    path = tmp_path / "a.pgm"
    path.write_text("P2\n4 2\n4095\n0 1 2 3\n4095 5 6 7\n")
    frame = read_frame(path)
    assert frame.mosaic.tolist() == [[0, 1, 2, 3], [4095, 5, 6, 7]]
    assert frame.bit_depth == 12


def test_embedded_description_json_is_read(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    counts = _rng(3).integers(0, 4096, size=(4, 6)).astype(np.uint16)
    path = tmp_path / "desc.tif"
    spec = oiio.ImageSpec(6, 4, 1, oiio.UINT16)
    spec.attribute("ImageDescription", json.dumps({"layout": "imx250myr", "bit_depth": 12,
                                                   "black_level": 10, "operator": "bench 2"}))
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(counts[:, :, None]) and out.close()
    frame = read_frame(path)
    assert frame.layout == parse_layout("imx250myr")
    assert frame.bit_depth == 12 and frame.black_level == 10.0
    assert frame.metadata["operator"] == "bench 2"
    # sidecar beats the file, keyword beats both
    _sidecar(path, layout="mono:0,45,135,90")
    assert read_frame(path).layout == parse_layout("mono:0,45,135,90")
    assert read_frame(path, layout="imx250mzr").layout == parse_layout("imx250mzr")


def test_roi_and_reverse_do_not_re_derive_the_layout(tmp_path: Path) -> None:
    path = tmp_path / "roi.png"
    cv2.imwrite(str(path), np.zeros((4, 6), np.uint8))
    # an odd x offset and a mirror would both change the sensor layout; the
    # sidecar's layout is already that of the delivered image and is used as is
    _sidecar(path, layout="imx250mzr", roi=[1, 0, 6, 4], reverse_x=True, note="kept")
    frame = read_frame(path)
    assert frame.layout == parse_layout("imx250mzr")
    assert frame.metadata["roi"] == [1, 0, 6, 4] and frame.metadata["reverse_x"] is True
    assert frame.metadata["note"] == "kept"


# ---------------------------------------------------------- raw dumps
RAW_FORMATS = [
    ("Mono8", None, 8), ("Mono10p", None, 10), ("Mono10Packed", None, 10), ("Mono12", None, 12),
    ("Mono12p", None, 12), ("Mono12Packed", None, 12), ("Mono16", None, 16),
    ("PolarizeMono12p", "LUCID Vision Labs", 12), ("Polarized10p", "FLIR", 10),
    ("BayerRGPolarized8", "FLIR", 8), ("PolarizedBayerBG12p", "The Imaging Source Europe GmbH", 12),
]


@pytest.mark.parametrize("name,vendor,bits", RAW_FORMATS)
def test_raw_dump_every_packing(tmp_path: Path, name: str, vendor: str | None, bits: int) -> None:
    from polcam.mosaic import layout_for_format, pixel_format

    fmt = pixel_format(name, vendor)
    h, w = 4, 8
    counts = _rng(4).integers(0, 1 << bits, size=(h, w))
    path = tmp_path / "dump.raw"
    path.write_bytes(pack(counts, packing=fmt.packing))
    _sidecar(path, width=w, height=h, pixel_format=name, vendor=vendor, frame_id=9)
    frame = read_frame(path)
    np.testing.assert_array_equal(frame.mosaic, counts)
    assert frame.mosaic.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert frame.bit_depth == bits
    assert frame.metadata["format"] == "raw" and frame.metadata["frame_id"] == 9
    assert frame.metadata["pixel_format"] == name
    if fmt.kind.startswith("polar"):
        assert frame.layout == layout_for_format(fmt)
    else:
        assert frame.layout is None  # plain formats need --layout
        assert read_frame(path, layout="imx250mzr").layout == parse_layout("imx250mzr")


def test_raw_from_keywords_without_sidecar(tmp_path: Path) -> None:
    counts = _rng(5).integers(0, 4096, size=(2, 4))
    path = tmp_path / "k.bin"
    path.write_bytes(pack(counts, packing="12packed"))
    frame = read_frame(path, width=4, height=2, pixel_format="Mono12Packed", layout="imx250mzr")
    np.testing.assert_array_equal(frame.mosaic, counts)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_raw_without_pixel_format_uses_the_size(tmp_path: Path, dtype: type) -> None:
    counts = _rng(6).integers(0, 200, size=(4, 6)).astype(dtype)
    path = tmp_path / "plain.raw"
    path.write_bytes(counts.astype(np.dtype(dtype).newbyteorder("<")).tobytes())
    _sidecar(path, width=6, height=4)
    frame = read_frame(path)
    assert frame.mosaic.dtype == dtype
    np.testing.assert_array_equal(frame.mosaic, counts)


@pytest.mark.parametrize("name,packing,bits", [
    ("PolarizedAngles_0d_45d_90d_135d_Mono8", "8", 8),
    ("PolarizedAngles_0d_45d_90d_135d_Mono12p", "12p", 12),
])
@pytest.mark.parametrize("size_as", ["camera", "mosaic"])
def test_lucid_angle_planes_are_re_interleaved(tmp_path: Path, name: str, packing: str, bits: int,
                                               size_as: str) -> None:
    hh, hw = 3, 5  # half-resolution planes
    planes = _rng(7).integers(0, 1 << bits, size=(hh, hw, 4))  # angles 0, 45, 90, 135 per pixel
    path = tmp_path / "angles.raw"
    path.write_bytes(pack(planes, packing=packing))
    w, h = (hw, hh) if size_as == "camera" else (2 * hw, 2 * hh)
    _sidecar(path, width=w, height=h, pixel_format=name, vendor="LUCID Vision Labs")
    frame = read_frame(path)
    assert frame.mosaic.shape == (2 * hh, 2 * hw)
    assert frame.layout == parse_layout("mono:0,45,135,90")
    # every mosaic pixel holds the plane of the angle the layout puts there
    idx = frame.layout.angle_index(2 * hh, 2 * hw)
    rr, cc = np.indices((2 * hh, 2 * hw))
    np.testing.assert_array_equal(frame.mosaic, planes[rr // 2, cc // 2, idx])
    assert ANGLES[idx[0, 0]] == 0 and ANGLES[idx[1, 1]] == 90


def test_lucid_bayer_angles_layout(tmp_path: Path) -> None:
    planes = _rng(8).integers(0, 256, size=(2, 2, 4))
    path = tmp_path / "ab.raw"
    path.write_bytes(planes.astype(np.uint8).tobytes())
    frame = read_frame(path, width=2, height=2, vendor="LUCID Vision Labs",
                       pixel_format="PolarizedAngles_0d_45d_90d_135d_BayerRG8")
    assert frame.layout == parse_layout("color:0,45,135,90:RGGB")
    np.testing.assert_array_equal(frame.mosaic, interleave_angles(planes.astype(np.uint8)))


def test_derived_format_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "dolp.raw"
    path.write_bytes(bytes(16))
    _sidecar(path, width=4, height=4, pixel_format="PolarizedDolp_Mono8", vendor="LUCID Vision Labs")
    with pytest.raises(PixelFormatError) as err:
        read_frame(path)
    assert "dolp.raw" in str(err.value) and "not a raw mosaic" in str(err.value)


def test_unknown_pixel_format_lists_supported(tmp_path: Path) -> None:
    path = tmp_path / "u.raw"
    path.write_bytes(bytes(16))
    with pytest.raises(PixelFormatError) as err:
        read_frame(path, width=4, height=4, pixel_format="Mono14p")
    msg = str(err.value)
    assert "u.raw" in msg and "'Mono14p'" in msg and "supported" in msg and "Mono12p" in msg


def test_raw_needs_width_and_height(tmp_path: Path) -> None:
    path = tmp_path / "nosize.raw"
    path.write_bytes(bytes(16))
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    msg = str(err.value)
    assert "nosize.raw" in msg and "width and height" in msg and "nosize.json" in msg


def test_raw_wrong_size_vs_sidecar(tmp_path: Path) -> None:
    path = tmp_path / "short.raw"
    path.write_bytes(bytes(47))  # a 8x8 Mono12p frame needs 96 bytes
    _sidecar(path, width=8, height=8, pixel_format="Mono12p")
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    msg = str(err.value)
    assert "short.raw" in msg and "expected 96 bytes" in msg and "found 47 bytes" in msg
    assert "short.json" in msg  # where the size came from
    # without a pixel format, only 8-bit or 16-bit sizes fit
    path.with_name("short.json").unlink()
    path.write_bytes(bytes(10))
    with pytest.raises(FrameReadError, match=r"short.raw: expected 64 bytes \(8-bit\) or 128 bytes"):
        read_frame(path, width=8, height=8)


# -------------------------------------------------------------- npy
def test_npy_integer_arrays(tmp_path: Path) -> None:
    counts = _rng(9).integers(0, 4096, size=(4, 6))
    path = tmp_path / "c.npy"
    np.save(path, counts.astype(np.int64))
    frame = read_frame(path, bit_depth=12)
    assert frame.mosaic.dtype == np.uint16
    np.testing.assert_array_equal(frame.mosaic, counts)
    np.save(path, counts.astype(np.uint8) // 16)
    assert read_frame(path).mosaic.dtype == np.uint8


def test_npy_float_needs_white_level_and_whole_numbers(tmp_path: Path) -> None:
    counts = _rng(10).integers(0, 1024, size=(4, 4)).astype(np.float64)
    path = tmp_path / "f.npy"
    np.save(path, counts)
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    assert "f.npy" in str(err.value) and "white_level" in str(err.value)
    frame = read_frame(path, white_level=1023)
    np.testing.assert_array_equal(frame.mosaic, counts)
    assert frame.white_level == 1023.0 and frame.bit_depth == 10  # the bits of the white level
    np.save(path, counts + 0.25)
    with pytest.raises(FrameReadError, match="f.npy.*fractional"):
        read_frame(path, white_level=1023)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_npy_nan_inf(tmp_path: Path, bad: float) -> None:
    arr = np.zeros((4, 4))
    arr[2, 3] = bad
    path = tmp_path / "nan.npy"
    np.save(path, arr)
    with pytest.raises(FrameReadError) as err:
        read_frame(path, white_level=1.0)
    msg = str(err.value)
    assert "nan.npy" in msg and "NaN/inf" in msg and "row 2, column 3" in msg


def test_npy_not_2d(tmp_path: Path) -> None:
    path = tmp_path / "cube.npy"
    np.save(path, np.zeros((2, 4, 4), np.uint16))
    with pytest.raises(FrameReadError, match=r"cube.npy.*\(2, 4, 4\).*2-D"):
        read_frame(path)


def test_npy_object_array_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "obj.npy"
    np.save(path, np.array([[1, None], [2, 3]], dtype=object), allow_pickle=True)
    with pytest.raises(FrameReadError, match="obj.npy.*objects"):
        read_frame(path)


def test_npy_negative_values(tmp_path: Path) -> None:
    path = tmp_path / "neg.npy"
    np.save(path, np.array([[0, -1], [2, 3]], dtype=np.int16))
    with pytest.raises(FrameReadError, match="neg.npy.*negative"):
        read_frame(path)


# -------------------------------------------------------------- DNG
def test_dng_through_libraw(tmp_path: Path) -> None:
    mosaic = _rng(11).integers(70, 4000, size=(32, 48)).astype(np.uint16)
    path = tmp_path / "shot.dng"
    _dng(path, mosaic, black=(60, 62, 64, 66), white=4095)
    frame = read_frame(path)
    np.testing.assert_array_equal(frame.mosaic, mosaic)
    assert frame.black_level == pytest.approx(63.0)  # mean of the four CFA black levels
    assert frame.white_level == 4095.0
    assert frame.bit_depth == 12
    assert frame.metadata["format"] == "dng"
    assert frame.metadata["cfa_pattern"] == [[0, 1], [3, 2]]  # LibRaw: R G / G2 B
    # keyword overrides LibRaw's levels
    assert read_frame(path, black_level=0, layout="imx250myr").black_level == 0.0


def test_dng_counts_above_libraw_white_level_are_kept(tmp_path: Path) -> None:
    mosaic = np.full((24, 24), 100, np.uint16)
    mosaic[5, 7] = 4000  # above the recorded WhiteLevel of 3000
    path = tmp_path / "hot.dng"
    _dng(path, mosaic, black=(0, 0, 0, 0), white=3000)
    frame = read_frame(path)
    assert frame.white_level == 3000.0 and frame.bit_depth == 12
    assert frame.mosaic[5, 7] == 4000
    with pytest.raises(FrameReadError, match="hot.dng.*above the white level 3000"):
        read_frame(path, white_level=3000)  # a level the caller states is a limit


def test_linear_raw_dng_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "lin.dng"
    _dng(path, _rng(12).integers(0, 4000, size=(24, 24, 3)).astype(np.uint16), black=(0,), white=4095,
         linear_raw=True)
    with pytest.raises(FrameReadError, match="lin.dng.*demosaiced"):
        read_frame(path)


def test_not_a_camera_raw(tmp_path: Path) -> None:
    path = tmp_path / "fake.nef"
    path.write_bytes(b"this is not a raw file at all" * 10)
    with pytest.raises(FrameReadError, match="fake.nef.*LibRaw"):
        read_frame(path)


# ------------------------------------------------------- bad input
def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FrameReadError, match="ghost.png: file not found"):
        read_frame(tmp_path / "ghost.png")


@pytest.mark.parametrize("ext", [".png", ".raw", ".npy", ".dng"])
def test_empty_file(tmp_path: Path, ext: str) -> None:
    path = tmp_path / f"empty{ext}"
    path.write_bytes(b"")
    with pytest.raises(FrameReadError, match=f"empty{ext}: file is empty"):
        read_frame(path)


@pytest.mark.parametrize("ext", [".png", ".tif", ".bmp", ".npy", ".pgm"])
def test_truncated_file(tmp_path: Path, ext: str) -> None:
    counts = _rng(13).integers(0, 256, size=(64, 64), dtype=np.uint8)
    path = tmp_path / f"cut{ext}"
    if ext == ".npy":
        np.save(path, counts)
    elif ext == ".pgm":
        path.write_bytes(b"P5\n64 64\n255\n" + counts.tobytes())
    else:
        import OpenImageIO as oiio  # TIFF/BMP with the pixels after the header, so a cut loses pixels

        spec = oiio.ImageSpec(64, 64, 1, oiio.UINT8)
        spec.attribute("compression", "none")
        out = oiio.ImageOutput.create(str(path))
        assert out.open(str(path), spec) and out.write_image(counts[:, :, None]) and out.close()
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    assert f"cut{ext}" in str(err.value)
    assert "truncated" in str(err.value)


def test_odd_dimensions(tmp_path: Path) -> None:
    path = tmp_path / "odd.png"
    cv2.imwrite(str(path), np.zeros((4, 5), np.uint8))
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    assert "odd.png" in str(err.value) and "5x4" in str(err.value) and "even" in str(err.value)


def test_three_channel_image_is_not_a_mosaic(tmp_path: Path) -> None:
    path = tmp_path / "rgb.png"
    cv2.imwrite(str(path), np.zeros((4, 6, 3), np.uint8))
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    assert "rgb.png" in str(err.value) and "3 channels" in str(err.value)
    assert "not a raw mosaic" in str(err.value)
    ppm = tmp_path / "rgb.ppm"
    ppm.write_bytes(b"P6\n2 2\n255\n" + bytes(12))
    with pytest.raises(FrameReadError, match="rgb.ppm.*3 channels"):
        read_frame(ppm)


def test_unsupported_extension_lists_supported(tmp_path: Path) -> None:
    path = tmp_path / "photo.jpg"
    path.write_bytes(b"\xff\xd8\xff")
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    msg = str(err.value)
    assert "photo.jpg" in msg and "'.jpg'" in msg
    assert all(ext in msg for ext in (".png", ".raw", ".npy", ".dng"))
    assert ".raw" in RAW_EXTENSIONS and ".dng" in RAW_EXTENSIONS


def test_values_above_bit_depth(tmp_path: Path) -> None:
    path = tmp_path / "hot.png"
    counts = np.zeros((4, 4), np.uint8)
    counts[1, 2] = 200
    cv2.imwrite(str(path), counts)
    _sidecar(path, bit_depth=6)
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    msg = str(err.value)
    assert "hot.png" in msg and "200" in msg and "6-bit range [0, 63]" in msg and "hot.json" in msg


def test_values_above_white_level(tmp_path: Path) -> None:
    path = tmp_path / "sat.png"
    counts = np.full((4, 4), 10, np.uint8)
    counts[3, 3] = 250
    cv2.imwrite(str(path), counts)
    _sidecar(path, white_level=240)
    with pytest.raises(FrameReadError) as err:
        read_frame(path)
    assert "sat.png" in str(err.value) and "white level 240" in str(err.value)


def test_bit_depth_wider_than_the_file(tmp_path: Path) -> None:
    path = tmp_path / "eight.png"
    cv2.imwrite(str(path), np.zeros((2, 2), np.uint8))
    with pytest.raises(FrameReadError, match="eight.png.*bit_depth 12.*8-bit samples"):
        read_frame(path, bit_depth=12)


def test_bad_keyword_and_bad_sidecar(tmp_path: Path) -> None:
    path = tmp_path / "k.png"
    cv2.imwrite(str(path), np.zeros((2, 2), np.uint8))
    with pytest.raises(FrameReadError, match=r"k.png.*'width'.*keyword arguments.*-4"):
        read_frame(path, width=-4)
    with pytest.raises(FrameReadError, match=r"k.png.*'layout'.*keyword"):
        read_frame(path, layout="zigzag")
    _sidecar(path, msb_aligned="yes")
    with pytest.raises(FrameReadError, match=r"k.json.*'msb_aligned'.*'yes'.*true or false"):
        read_frame(path)


def test_white_not_above_black(tmp_path: Path) -> None:
    path = tmp_path / "wb.png"
    cv2.imwrite(str(path), np.zeros((2, 2), np.uint8))
    with pytest.raises(FrameReadError, match="wb.png.*'white_level'.*10.*above black_level 20"):
        read_frame(path, black_level=20, white_level=10)
    _sidecar(path, black_level=20)  # the two levels from different places
    with pytest.raises(FrameReadError, match="wb.png.*white level 10.0 is not above black level 20.0"):
        read_frame(path, white_level=10)


def test_sidecar_size_that_contradicts_the_image_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "f.png"
    assert cv2.imwrite(str(path), _rng().integers(0, 255, (8, 12), dtype=np.uint8))
    _sidecar(path, layout="imx250mzr", width=2448, height=2048)
    with pytest.raises(FrameReadError, match=r"f\.png: the sidecar f\.json gives 2448x2048 .* the image is 12x8"):
        read_frame(path)
    _sidecar(path, layout="imx250mzr", width=12, height=8)      # agreeing sizes are fine
    assert read_frame(path).mosaic.shape == (8, 12)


def test_declared_size_reads_headers_only(tmp_path: Path) -> None:
    png = tmp_path / "a.png"
    assert cv2.imwrite(str(png), np.zeros((6, 10), np.uint8))
    npy = tmp_path / "b.npy"
    np.save(npy, np.zeros((4, 14), np.uint16))
    pgm = tmp_path / "c.pgm"
    pgm.write_bytes(b"P5\n# comment\n11000 9000\n255\n" + bytes(16))   # truncated: the header is enough
    raw = tmp_path / "d.raw"
    raw.write_bytes(bytes(4))
    _sidecar(raw, width=64, height=32)
    assert [declared_size(p) for p in (png, npy, pgm, raw)] == [(10, 6), (14, 4), (11000, 9000), (64, 32)]
    (tmp_path / "e.png").write_bytes(b"not an image")
    assert declared_size(tmp_path / "e.png") is None


def test_an_error_repeated_per_scanline_is_one_line(tmp_path: Path) -> None:
    """A 138-byte TIFF that declares 4000x4000 16-bit pixels: one line, with the count of the rest."""
    w = h = 4000
    entries = [(256, 4, w), (257, 4, h), (258, 3, 16), (259, 3, 1), (262, 3, 1), (273, 4, 134),
               (277, 3, 1), (278, 4, h), (279, 4, w * h * 2), (284, 3, 1)]
    ifd = struct.pack("<H", len(entries)) + b"".join(
        struct.pack("<HHII", t, k, 1, v) if k == 4 else struct.pack("<HHIHH", t, k, 1, v, 0) for t, k, v in entries)
    path = tmp_path / "tiny.tif"
    path.write_bytes(b"II*\x00" + struct.pack("<I", 8) + ifd + struct.pack("<I", 0) + bytes(4))
    with pytest.raises(FrameReadError) as info:
        read_frame(path, layout="imx250mzr")
    msg = str(info.value)
    assert "\n" not in msg and len(msg) < 400 and "more lines like it" in msg and msg.startswith(str(path))
