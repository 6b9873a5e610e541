"""polcam.io.decoders: declared sizes are bounded before any allocation of that size."""

from __future__ import annotations

import json

import numpy as np
import pytest

from polcam.errors import FrameReadError
from polcam.io import read_frame, write_frame
from polcam.io.decoders import MAX_PIXELS
from polcam.frame import Frame


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
