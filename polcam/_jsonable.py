"""Plain-JSON copies of nested results (for meta.json, summaries and calibration files)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["jsonable"]


def jsonable(obj: Any, *, other: str = "keep") -> Any:
    """``obj`` with JSON's types only: dict keys as strings, tuples and arrays as lists,
    numpy scalars as Python numbers, and non-finite floats as ``None``.

    Parameters
    ----------
    obj
        Nested dicts, lists, tuples, numpy arrays and scalars.
    other
        What happens to any other object: ``"keep"`` it (``json.dumps`` may then
        need a ``default=``) or turn it into its ``"str"``.

    Returns
    -------
    Any
        A copy that ``json.dumps`` writes as standard JSON (no ``NaN``).
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v, other=other) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, other=other) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist(), other=other)
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if other == "str" and not (isinstance(obj, (str, int, float, bool)) or obj is None):
        return str(obj)
    return obj
