"""The Frame container: normalisation and sidecar."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.frame import SIDECAR_KEYS, Frame
from polcam.mosaic import parse_layout


def test_normalisation_uses_black_and_white_levels():
    raw = np.array([[64, 4095], [2079, 0]], dtype=np.uint16)
    f = Frame(raw, "imx250mzr", bit_depth=12, black_level=64)
    assert f.white_level == 4095
    np.testing.assert_allclose(f.normalized(), (raw.astype(np.float64) - 64) / (4095 - 64), rtol=1e-6)
    assert f.normalized().dtype == np.float32
    assert f.layout == parse_layout("imx250mzr")


def test_bad_levels_are_refused():
    with pytest.raises(ValueError, match="not above black level"):
        Frame(np.zeros((2, 2), np.uint8), black_level=300, white_level=255).normalized()


def test_sidecar_has_the_design_keys():
    f = Frame(np.zeros((4, 6), np.uint8), "imx250myr",
              metadata={"exposure_us": 1000.0, "frame_id": 7, "unrelated": 1})
    side = f.sidecar()
    assert side["width"] == 6 and side["height"] == 4 and side["layout"] == "imx250myr"
    assert side["exposure_us"] == 1000.0 and side["frame_id"] == 7
    assert "unrelated" not in side
    assert set(side) <= set(SIDECAR_KEYS)
