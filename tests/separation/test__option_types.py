"""Option values against their declared types (polcam.separation._option_types)."""

from __future__ import annotations

from typing import Any, Literal, Optional, Union

import numpy as np
import pytest

from polcam.separation._option_types import describe, matches


@pytest.mark.parametrize("value, hint, ok", [
    (3, int, True), (np.int64(3), int, True), (True, int, False), (3.0, int, False), ("3", int, False),
    (3, float, True), (2.5, float, True), (np.float32(2.5), float, True), (False, float, False),
    ("abc", float, False), (None, float, False), (None, Optional[float], True), (0.1, Optional[float], True),
    (True, bool, True), (np.bool_(True), bool, True), (1, bool, False),
    ("x", str, True), (1, str, False),
    ([1, 2, 3], tuple[float, float, float], True), ((1.0, 2, 3), tuple[float, float, float], True),
    (np.array([1.0, 2, 3]), tuple[float, float, float], True), ([1, 2], tuple[float, float, float], False),
    ([1, "a", 3], tuple[float, float, float], False), (np.ones((3, 1)), tuple[float, float, float], False),
    ("white", Union[str, tuple[float, float, float]], True), (5, Union[str, tuple[float, float, float]], False),
    ([96, 32], Union[int, tuple[int, int], None], True), ([96.5, 32], Union[int, tuple[int, int], None], False),
    ([1, 2, 3, 4], list[int], True), ([1, 2.5], list[int], False), ((1, 2), tuple[int, ...], True),
    ({"a": 1}, dict[str, Any], True), ([], dict[str, Any], False),
    ("fast", Literal["fast", "exact"], True), ("slow", Literal["fast", "exact"], False),
    (object(), Any, True), (object(), complex, True),     # a type the checker does not know: unchecked
])
def test_matches(value, hint, ok):
    assert matches(value, hint) is ok


def test_describe():
    assert describe(int) == "an integer"
    assert describe(Optional[float]) == "a number or None"
    assert describe(Union[int, tuple[int, int], None]) == "an integer or a list of 2 integers or None"
    assert describe(Union[str, tuple[float, float, float]]) == "a string or a list of 3 numbers"
    assert describe(Literal["fast", "exact"]) == "one of 'fast', 'exact'"
    assert describe(list[int]) == "a list of integers"


def test_every_tensor_option_has_a_type_that_its_default_matches():
    from polcam.separation.tensor.options import DEFAULTS, OPTION_TYPES

    assert list(OPTION_TYPES) == list(DEFAULTS)
    for key, default in DEFAULTS.items():
        assert matches(default, OPTION_TYPES[key]), key
