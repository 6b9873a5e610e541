"""Checking a separation option's value against its declared type, before a method runs.

The types are typing expressions: a method's keyword annotations
(``max_iter: int = 50``), or the mapping a method that takes ``**options``
declares at registration (``register(..., options={"max_iter": int, ...})``).
Understood: ``Any``, ``int``, ``float``, ``bool``, ``str``, ``None``, unions
(``X | Y``, ``Optional``), ``Literal[...]``, ``tuple[X, Y, Z]`` and
``tuple[X, ...]``, ``list[X]``, ``Sequence[X]``, ``dict[...]``; anything else
is accepted unchecked.  Numbers are checked as numbers, not by Python class:
an ``int`` option takes any integer but a bool, a ``float`` option any real
number but a bool; a tuple or list option takes a tuple, list or 1-D array
(a JSON value from the command line is a list).
"""

from __future__ import annotations

import numbers
import types
import typing
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["matches", "describe"]


def _args(hint: Any) -> tuple[Any, ...]:
    return typing.get_args(hint)


def _is_union(hint: Any) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType)


def matches(value: Any, hint: Any) -> bool:
    """Whether ``value`` is of the type ``hint`` describes (see the module docstring)."""
    if hint is Any or hint is object:
        return True
    if hint is None or hint is type(None):
        return value is None
    if _is_union(hint):
        return any(matches(value, h) for h in _args(hint))
    origin = typing.get_origin(hint)
    if origin is typing.Literal:
        return any(value == v and type(value) is type(v) for v in _args(hint))
    if hint is bool:
        return isinstance(value, (bool, np.bool_))
    if hint is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
    if hint is float:
        return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if hint is str:
        return isinstance(value, str)
    if origin in (tuple, list, Sequence) or hint in (tuple, list):
        if isinstance(value, np.ndarray):
            if value.ndim != 1:
                return False
            value = value.tolist()
        if not isinstance(value, (tuple, list)):
            return False
        inner = _args(hint)
        if origin is tuple and inner and inner[-1] is not Ellipsis:
            return len(value) == len(inner) and all(matches(v, h) for v, h in zip(value, inner))
        return not inner or all(matches(v, inner[0]) for v in value)
    if origin is dict or hint is dict:
        return isinstance(value, dict)
    return True                                   # a type this checker does not know: unchecked


def describe(hint: Any) -> str:
    """``hint`` in words for a message: ``"an integer"``, ``"a number or None"``, ..."""
    if hint is None or hint is type(None):
        return "None"
    if _is_union(hint):
        parts = [describe(h) for h in _args(hint)]
        parts = [p for p in parts if p != "None"] + (["None"] if "None" in parts else [])
        return " or ".join(parts)
    origin = typing.get_origin(hint)
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(v) for v in _args(hint))
    names = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
    if hint in names:
        return names[hint]
    if origin in (tuple, list, Sequence) or hint in (tuple, list):
        inner = _args(hint)
        if origin is tuple and inner and inner[-1] is not Ellipsis:
            if len(set(inner)) == 1:
                return f"a list of {len(inner)} {_plural(inner[0])}"
            return "a list [" + ", ".join(describe(h) for h in inner) + "]"
        return f"a list of {_plural(inner[0])}" if inner else "a list"
    if origin is dict or hint is dict:
        return "a mapping ({...})"
    return getattr(hint, "__name__", str(hint))


def _plural(hint: Any) -> str:
    return {int: "integers", float: "numbers", str: "strings", bool: "booleans"}.get(hint, describe(hint))
