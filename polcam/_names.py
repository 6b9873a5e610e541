"""What the method registries (separation, demosaicing) share: listing and looking up by name."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeVar

from polcam.errors import MethodError

__all__ = ["lookup", "ordered"]

T = TypeVar("T")


def ordered(registered: Mapping[str, object], order: Sequence[str]) -> tuple[str, ...]:
    """The names of ``registered``: those in ``order`` first, in that order, then the rest sorted."""
    known = [m for m in order if m in registered]
    return tuple(known + sorted(m for m in registered if m not in order))


def lookup(registered: Mapping[str, T], name: str, *, what: str, order: Sequence[str]) -> T:
    """``registered[name]``; a :class:`MethodError` naming ``what`` and the known names if absent."""
    try:
        return registered[name]
    except KeyError:
        raise MethodError(
            f"{what} {name!r} is unknown; expected one of {', '.join(ordered(registered, order))}"
        ) from None
