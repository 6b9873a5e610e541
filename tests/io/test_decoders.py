"""polcam.io.decoders: one decoder per extension, header sizes, declared sizes bounded before any allocation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from polcam.errors import FrameReadError
from polcam.frame import Frame
from polcam.io import read_frame, write_frame
from polcam.io.decoders import MAX_PIXELS
from polcam.mosaic import parse_layout


def test_a_pgm_header_of_60000_squared_is_refused_unread(tmp_path):
    p = tmp_path / "huge.pgm"
    p.write_bytes(b"P5\n60000 60000\n65535\n" + b"\0" * 16)
    with pytest.raises(FrameReadError, match=r"60000x60000 = 3600000000 pixels, more than the limit"):
        read_frame(p, layout="imx250mzr")


def test_a_raw_sidecar_of_200000_squared_is_refused(tmp_path):
    p = tmp_path / "f.raw"
    p.write_bytes(b"\0" * 64)
    (tmp_path / "f.json").write_text(json.dumps({"width": 200000, "height": 200000}))
    with pytest.raises(FrameReadError, match="200000x200000.*--max-pixels"):
        read_frame(p, layout="imx250mzr")


def test_the_limit_can_be_raised_and_lowered(tmp_path):
    path = write_frame(tmp_path / "f.png", Frame(mosaic=np.arange(64 * 48, dtype=np.uint16).reshape(48, 64),
                                                 layout="imx250mzr", bit_depth=12, white_level=4095))
    assert MAX_PIXELS >= 2448 * 2048 * 4                     # real sensors read with the default
    assert read_frame(path).mosaic.shape == (48, 64)
    with pytest.raises(FrameReadError, match="3072 pixels, more than the limit of 3000"):
        read_frame(path, max_pixels=3000)
    assert read_frame(path, max_pixels=3072).mosaic.shape == (48, 64)


def test_one_decoder_per_extension_and_unknown_ones_refused(tmp_path):
    from polcam.io.decoders import DECODERS, RAW_EXTENSIONS, decoder_for

    listed = [ext for d in DECODERS for ext in d.extensions]
    assert len(listed) == len(set(listed)) and tuple(listed) == RAW_EXTENSIONS
    assert decoder_for(tmp_path / "a.TIF").name == "OpenImageIO"
    assert decoder_for(tmp_path / "a.pgm").name == "PNM"
    assert decoder_for(tmp_path / "a.bin").sized_by_metadata
    assert decoder_for(tmp_path / "a.NEF").name == "LibRaw"
    with pytest.raises(FrameReadError, match=r"a\.jpg.*unsupported file type '\.jpg'; supported: \.png"):
        decoder_for(tmp_path / "a.jpg")


@pytest.mark.parametrize("ext", [".png", ".tif", ".pgm", ".npy", ".raw"])
def test_each_decoder_reads_the_size_its_header_declares(tmp_path, ext):
    from polcam.io.decoders import decoder_for
    from polcam.io.readers import declared_size

    mosaic = (np.arange(6 * 10, dtype=np.uint16).reshape(6, 10) * 7) % 4096
    if ext == ".pgm":   # polcam writes no PGM: a 12-bit P5 file by hand (maxval 4095, big-endian words)
        path = tmp_path / "f.pgm"
        path.write_bytes(b"P5\n# a comment\n10 6\n4095\n" + mosaic.astype(">u2").tobytes())
        (tmp_path / "f.json").write_text(json.dumps({"layout": "imx250mzr"}))
    else:
        path = write_frame(tmp_path / f"f{ext}", Frame(mosaic=mosaic, layout="imx250mzr", bit_depth=12,
                                                      white_level=4095))
    assert decoder_for(path).size(path) == declared_size(path) == (10, 6)
    frame = read_frame(path)
    np.testing.assert_array_equal(frame.mosaic, mosaic)
    assert frame.bit_depth == 12 and frame.layout == parse_layout("imx250mzr")
