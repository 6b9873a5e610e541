"""Tests of polcam.io.writers: float images with metadata, raw frames with sidecars."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from polcam.errors import FrameWriteError
from polcam.frame import Frame
from polcam.io.packing import packed_size
from polcam.io.readers import read_frame
from polcam.io.sidecar import read_sidecar
from polcam.io.writers import read_image, write_frame, write_image
from polcam.mosaic import parse_layout, pixel_format

META = {"method": "tensor", "iterations": 37, "converged": True, "lambda": 0.0125,
        "layout": "imx250myr", "angles": [0, 45, 90, 135], "info": {"seconds": 1.5}}


def _image(shape: tuple[int, ...], seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).random(shape).astype(np.float32)


def _oiio_channel_names(path: Path) -> tuple[str, ...]:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    try:
        return tuple(inp.spec().channelnames)
    finally:
        inp.close()


# ----------------------------------------------------------- write_image
@pytest.mark.parametrize("ext", [".exr", ".tif", ".tiff"])
@pytest.mark.parametrize("shape,names", [((5, 7), ("Y",)), ((5, 7, 1), ("Y",)), ((5, 7, 2), ("Y", "A")),
                                         ((5, 7, 3), ("R", "G", "B")), ((5, 7, 4), ("R", "G", "B", "A"))])
def test_float32_round_trip_is_exact(tmp_path: Path, ext: str, shape: tuple[int, ...],
                                     names: tuple[str, ...]) -> None:
    img = _image(shape) * 3 - 1  # linear values outside [0, 1] are kept in float files
    path = write_image(tmp_path / f"layer{ext}", img, metadata=META)
    back, meta = read_image(path)
    np.testing.assert_array_equal(back, img[:, :, 0] if img.ndim == 3 and img.shape[2] == 1 else img)
    assert back.dtype == np.float32
    assert meta == META
    if ext == ".exr":  # TIFF has no channel names (readers guess them)
        assert _oiio_channel_names(path) == names


def test_non_square_2d_array_is_not_transposed(tmp_path: Path) -> None:
    # OpenImageIO 3.2: a 2-D array through ImageOutput.write_image came out transposed
    img = np.arange(3 * 8, dtype=np.float32).reshape(3, 8) / 24
    for ext in (".exr", ".tif"):
        back, _ = read_image(write_image(tmp_path / f"ramp{ext}", img))
        assert back.shape == (3, 8)
        np.testing.assert_array_equal(back, img)


def test_exr_half(tmp_path: Path) -> None:
    img = _image((4, 6, 3), seed=1) * 100
    path = write_image(tmp_path / "h.exr", img, dtype="half", metadata={"k": "v"})
    back, meta = read_image(path)
    np.testing.assert_array_equal(back, img.astype(np.float16).astype(np.float32))
    assert meta == {"k": "v"}
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp.spec().format == oiio.HALF
    inp.close()


def test_exr_half_refuses_values_beyond_its_range(tmp_path: Path) -> None:
    img = np.zeros((2, 2), np.float32)
    img[1, 1] = 70000.0
    with pytest.raises(FrameWriteError, match="big.exr.*70000.*half"):
        write_image(tmp_path / "big.exr", img, dtype="half")
    assert not (tmp_path / "big.exr").exists()


def test_exr_metadata_is_stored_as_polcam_string_attributes(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    path = write_image(tmp_path / "m.exr", _image((2, 2)), metadata={"iterations": 12, "layout": "imx250mzr"})
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    assert spec.getattribute("polcam:iterations") == "12"
    assert spec.getattribute("polcam:layout") == '"imx250mzr"'
    inp.close()


def test_tiff_uint16_scaling_rounding_and_clipping(tmp_path: Path) -> None:
    values = np.array([[0.0, 1.0, 0.5, 0.25], [-0.1, 1.2, 1 / 65535, 0.9999999]], dtype=np.float32)
    path = write_image(tmp_path / "s.tif", values, dtype="uint16", metadata={"scale": "0..65535"})
    stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # an independent decoder
    assert stored.dtype == np.uint16
    # 0.5 * 65535 = 32767.5 -> 32768 (round half to even), 0.25 * 65535 = 16383.75 -> 16384
    assert stored.tolist() == [[0, 65535, 32768, 16384], [0, 65535, 1, 65535]]
    back, meta = read_image(path)
    np.testing.assert_allclose(back, stored / 65535.0, rtol=0, atol=1e-7)
    assert meta == {"scale": "0..65535"}


def test_tiff_float32_is_32_bit_float(tmp_path: Path) -> None:
    import tifffile

    img = _image((3, 4, 3), seed=2)
    path = write_image(tmp_path / "f.tif", img)
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        assert page.dtype == np.float32 and page.samplesperpixel == 3
    stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # independent decoder, BGR order
    np.testing.assert_array_equal(stored[:, :, ::-1], img)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_refused(tmp_path: Path, bad: float) -> None:
    img = np.zeros((3, 4, 3), np.float32)
    img[2, 1, 0] = bad
    with pytest.raises(FrameWriteError) as err:
        write_image(tmp_path / "nan.exr", img)
    assert "nan.exr" in str(err.value) and "NaN/inf" in str(err.value) and "row 2, column 1" in str(err.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("array,phrase", [
    (np.zeros((4, 4), np.uint16), "floating point"),
    (np.zeros((4, 4, 5), np.float32), "C in 1..4"),
    (np.zeros((2, 4, 4, 1), np.float32), "(H, W)"),
    (np.zeros((0, 4), np.float32), "H, W > 0"),
])
def test_bad_arrays(tmp_path: Path, array: np.ndarray, phrase: str) -> None:
    with pytest.raises(FrameWriteError) as err:
        write_image(tmp_path / "bad.exr", array)
    assert "bad.exr" in str(err.value) and phrase in str(err.value)


def test_bad_extension_dtype_and_metadata(tmp_path: Path) -> None:
    img = np.zeros((2, 2), np.float32)
    with pytest.raises(FrameWriteError, match=r"x.png.*'.png'.*\.exr, \.tif, \.tiff"):
        write_image(tmp_path / "x.png", img)
    with pytest.raises(FrameWriteError, match=r"x.tif.*dtype 'half'"):
        write_image(tmp_path / "x.tif", img, dtype="half")
    with pytest.raises(FrameWriteError, match=r"x.exr.*dtype 'uint16'"):
        write_image(tmp_path / "x.exr", img, dtype="uint16")
    with pytest.raises(FrameWriteError, match=r"x.exr.*'when'"):
        write_image(tmp_path / "x.exr", img, metadata={"when": object()})
    with pytest.raises(FrameWriteError, match=r"x.tif.*'gain'"):
        write_image(tmp_path / "x.tif", img, metadata={"gain": float("nan")})
    assert list(tmp_path.iterdir()) == []


def test_overwrite_replaces_the_file(tmp_path: Path) -> None:
    path = tmp_path / "o.exr"
    write_image(path, np.zeros((2, 2), np.float32), metadata={"v": 1})
    write_image(path, np.ones((2, 2), np.float32), metadata={"v": 2})
    back, meta = read_image(path)
    assert back.tolist() == [[1, 1], [1, 1]] and meta == {"v": 2}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.exr"]


# ----------------------------------------------------------- write_frame
def _frame(bits: int, *, h: int = 4, w: int = 6, seed: int = 3, **kw: object) -> Frame:
    dtype = np.uint8 if bits <= 8 else np.uint16
    counts = np.random.default_rng(seed).integers(0, 1 << bits, size=(h, w)).astype(dtype)
    counts[0, 0] = (1 << bits) - 1
    return Frame(mosaic=counts, bit_depth=bits, **kw)  # type: ignore[arg-type]


def _assert_same_frame(a: Frame, b: Frame) -> None:
    np.testing.assert_array_equal(a.mosaic, b.mosaic)
    assert a.mosaic.dtype == b.mosaic.dtype
    assert (a.layout, a.bit_depth, a.black_level, a.white_level) == (
        b.layout, b.bit_depth, b.black_level, b.white_level)


@pytest.mark.parametrize("name,vendor,bits", [
    ("Mono12p", None, 12), ("Mono10p", None, 10), ("Mono12Packed", None, 12), ("Mono10Packed", None, 10),
    ("Mono16", None, 16), ("Mono12", None, 12), ("PolarizeMono8", "LUCID Vision Labs", 8),
    ("BayerRGPolarized12p", "FLIR", 12),
])
def test_write_frame_raw_in_the_pixel_format(tmp_path: Path, name: str, vendor: str | None,
                                             bits: int) -> None:
    fmt = pixel_format(name, vendor)
    layout = "imx250myr" if "Bayer" in name else "imx250mzr"
    frame = _frame(bits, h=4, w=8, layout=layout, black_level=3.0, white_level=float((1 << bits) - 1),
                   metadata={"pixel_format": name, "vendor": vendor, "exposure_us": 1000.0, "frame_id": 5})
    path = write_frame(tmp_path / "f.raw", frame)
    assert path.stat().st_size == packed_size(fmt.packing, 4 * 8) == fmt.frame_bytes(8, 4)
    side = read_sidecar(path)
    assert side is not None and side["pixel_format"] == name and side["frame_id"] == 5
    back = read_frame(path)
    _assert_same_frame(back, frame)
    assert back.metadata["exposure_us"] == 1000.0


def test_write_frame_lucid_angles_round_trip(tmp_path: Path) -> None:
    name = "PolarizedAngles_0d_45d_90d_135d_Mono12p"
    frame = _frame(12, h=6, w=10, layout="mono:0,45,135,90",
                   metadata={"pixel_format": name, "vendor": "LUCID Vision Labs"})
    path = write_frame(tmp_path / "a.raw", frame)
    assert path.stat().st_size == packed_size("12p", 6 * 10)
    _assert_same_frame(read_frame(path), frame)
    # the file holds the camera's angle planes: pixel (0, 0) of the 0-degree plane first
    from polcam.io.packing import unpack

    planes = unpack(path.read_bytes(), packing="12p", width=5, height=3, channels=4)
    np.testing.assert_array_equal(planes[..., 0], frame.mosaic[0::2, 0::2])
    np.testing.assert_array_equal(planes[..., 2], frame.mosaic[1::2, 1::2])
    bad = _frame(12, layout="imx250mzr", metadata={"pixel_format": name, "vendor": "LUCID Vision Labs"})
    with pytest.raises(FrameWriteError, match="b.raw.*0,45 / 135,90"):
        write_frame(tmp_path / "b.raw", bad)


@pytest.mark.parametrize("ext", [".raw", ".tif", ".tiff", ".png", ".npy"])
@pytest.mark.parametrize("bits", [8, 12, 16])
def test_write_frame_containers_round_trip(tmp_path: Path, ext: str, bits: int) -> None:
    frame = _frame(bits, layout="imx250mzr", black_level=2.0, metadata={"camera_id": "cam-1"})
    path = write_frame(tmp_path / f"frame{ext}", frame)
    assert path.name == f"frame{ext}"
    back = read_frame(path)
    _assert_same_frame(back, frame)
    assert back.metadata["camera_id"] == "cam-1"
    side = json.loads((tmp_path / "frame.json").read_text())
    assert side == frame.sidecar()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f"frame{ext}", "frame.json"])


def test_write_frame_tiff_is_uncompressed_with_embedded_metadata(tmp_path: Path) -> None:
    import tifffile

    frame = _frame(12, layout="imx250mzr")
    path = write_frame(tmp_path / "u.tif", frame)
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        assert page.compression == 1  # COMPRESSION.NONE
        np.testing.assert_array_equal(page.asarray(), frame.mosaic)
        assert json.loads(page.description)["layout"] == "imx250mzr"
    (tmp_path / "u.json").unlink()  # the TIFF alone still says what it is
    _assert_same_frame(read_frame(path), frame)


def test_write_frame_msb_aligned_source_is_not_shifted_twice(tmp_path: Path) -> None:
    counts = np.random.default_rng(4).integers(0, 4096, size=(4, 4)).astype(np.uint16)
    src = tmp_path / "src.tif"
    cv2.imwrite(str(src), counts << 4)
    (tmp_path / "src.json").write_text(json.dumps({"bit_depth": 12, "msb_aligned": True}))
    frame = read_frame(src)
    out = write_frame(tmp_path / "copy.png", frame)
    assert read_sidecar(out)["msb_aligned"] is False  # type: ignore[index]
    np.testing.assert_array_equal(read_frame(out).mosaic, counts)


def test_write_frame_bad_input(tmp_path: Path) -> None:
    with pytest.raises(FrameWriteError, match=r"x.jpg.*'.jpg'.*\.raw"):
        write_frame(tmp_path / "x.jpg", _frame(8))
    with pytest.raises(FrameWriteError, match="x.raw.*uint8 or uint16"):
        write_frame(tmp_path / "x.raw", Frame(mosaic=np.zeros((2, 2), np.float32)))
    too_wide = _frame(16, metadata={"pixel_format": "Mono12p"})
    with pytest.raises(FrameWriteError, match=r"x.raw.*\[0, 4095\].*Mono12p"):
        write_frame(tmp_path / "x.raw", too_wide)
    with pytest.raises(FrameWriteError, match="x.raw.*Mono14p"):
        write_frame(tmp_path / "x.raw", _frame(8, metadata={"pixel_format": "Mono14p"}))
    assert list(tmp_path.iterdir()) == []


def test_write_frame_failure_leaves_neither_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import polcam.io.writers as writers

    def broken(*args: object, **kwargs: object) -> None:
        raise FrameWriteError("simulated encoder failure", path=tmp_path / "w.tif")

    monkeypatch.setattr(writers, "_write_oiio", broken)
    with pytest.raises(FrameWriteError, match="simulated"):
        write_frame(tmp_path / "w.tif", _frame(8))
    assert list(tmp_path.iterdir()) == []


def test_read_image_errors(tmp_path: Path) -> None:
    from polcam.errors import FrameReadError

    with pytest.raises(FrameReadError, match="none.exr: file not found"):
        read_image(tmp_path / "none.exr")
    (tmp_path / "e.exr").write_bytes(b"")
    with pytest.raises(FrameReadError, match="e.exr: file is empty"):
        read_image(tmp_path / "e.exr")
    path = write_image(tmp_path / "t.exr", _image((32, 32, 3)))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(FrameReadError, match="t.exr"):
        read_image(path)


def test_layout_object_in_metadata_is_written_as_its_name(tmp_path: Path) -> None:
    path = write_image(tmp_path / "l.exr", _image((2, 2)), metadata={"layout": parse_layout("imx250myr")})
    assert read_image(path)[1] == {"layout": "imx250myr"}
