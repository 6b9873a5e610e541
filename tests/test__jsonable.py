"""polcam._jsonable: plain JSON from nested results."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from polcam._jsonable import jsonable


def test_numpy_values_and_non_finite_floats_become_plain_json():
    src = {1: (np.float32(0.5), np.int64(3)), "a": np.array([[1.0, np.nan]]), "b": [np.float64(np.inf), None],
           "c": float("-inf"), "d": True}
    out = jsonable(src)
    assert out == {"1": [0.5, 3], "a": [[1.0, None]], "b": [None, None], "c": None, "d": True}
    assert json.loads(json.dumps(out, allow_nan=False)) == out      # standard JSON, no NaN


def test_other_objects_are_kept_or_named():
    p = Path("x/y")
    assert jsonable({"p": p})["p"] is p
    assert jsonable({"p": p}, other="str") == {"p": str(p)}
