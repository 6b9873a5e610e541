"""polcam.sinks.files: the one output format table and the product writer."""

from __future__ import annotations

import json

import numpy as np
import pytest

from polcam.errors import FrameWriteError, MethodError
from polcam.io import read_image
from polcam.sinks.files import FORMATS, check_format, extension, write_meta, write_products


def test_format_table():
    assert FORMATS == {"exr": (".exr", None), "tiff": (".tif", "float32"), "tiff16": (".tif", "uint16")}
    assert extension("tiff16") == ".tif" and check_format("exr") == "exr"
    with pytest.raises(MethodError, match="'png'.*exr, tiff, tiff16"):
        extension("png")


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_products_round_trip(tmp_path, fmt):
    unit = np.linspace(0, 1, 12, dtype=np.float32).reshape(3, 4)
    signed = unit * 4 - 2
    names = write_products(tmp_path / "f", {"dolp": unit, "s1": signed}, fmt=fmt, unit=("dolp",),
                           metadata={"input": "x.png"})
    assert names == [f"dolp{extension(fmt)}", f"s1{extension(fmt)}"]
    dolp, meta = read_image(tmp_path / "f" / names[0])
    s1, _ = read_image(tmp_path / "f" / names[1])
    tol = 1 / 65535 if fmt == "tiff16" else 0
    np.testing.assert_allclose(dolp.reshape(3, 4), unit, atol=tol)
    np.testing.assert_allclose(s1.reshape(3, 4), signed, atol=1e-6)   # signed maps stay float
    assert meta.get("product") == "dolp" and meta.get("input") == "x.png"


def test_meta_json_and_unwritable_target(tmp_path):
    path = write_meta(tmp_path / "f", {"a": 1})
    assert json.loads(path.read_text()) == {"a": 1}
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(FrameWriteError, match="cannot create the output folder"):
        write_products(blocker / "sub", {"dolp": np.zeros((2, 2), np.float32)})
