"""A registry of named methods: what the separation and demosaicing registries share.

Each method package keeps one :class:`Registry` of its own entries (a frozen
``MethodSpec`` per name) with a canonical listing order and a default per kind
of input; its ``register`` decorator adds to it, its ``methods`` and
``method_spec`` read it.  An unknown name is a :class:`~polcam.errors.MethodError`
naming the known ones.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Generic, TypeVar

from polcam.errors import MethodError

__all__ = ["Registry"]

S = TypeVar("S")


class Registry(Generic[S]):
    """Entries by name, listed in a canonical order, with a default name per kind of input.

    Parameters
    ----------
    what
        What an entry is, for messages (``"separation method"``).
    order
        The names listed first, in this order; names registered and not listed
        here follow, sorted.
    defaults
        Kind of input -> the name used when none is given (``{"stack": "wen21", ...}``).
    """

    def __init__(self, what: str, *, order: Sequence[str] = (), defaults: Mapping[str, str] | None = None) -> None:
        self.what = what
        self.order: tuple[str, ...] = tuple(order)
        self.defaults: dict[str, str] = dict(defaults or {})
        self._entries: dict[str, S] = {}

    def add(self, name: str, entry: S) -> None:
        """Register ``entry`` under ``name`` (replacing an entry of that name)."""
        self._entries[name] = entry

    def remove(self, name: str) -> S:
        """Unregister ``name``; returns its entry.  :class:`MethodError` if it is not registered."""
        entry = self.get(name)
        del self._entries[name]
        return entry

    def names(self) -> tuple[str, ...]:
        """The registered names: those of :attr:`order` first, in that order, then the rest sorted."""
        listed = [n for n in self.order if n in self._entries]
        return tuple(listed + sorted(n for n in self._entries if n not in self.order))

    def get(self, name: str) -> S:
        """The entry of ``name``; a :class:`MethodError` naming the known names if there is none."""
        try:
            return self._entries[name]
        except KeyError:
            raise MethodError(f"{self.what} {name!r} is unknown; expected one of {', '.join(self.names())}") from None

    def default(self, kind: str) -> str:
        """The name used for an input of ``kind`` when none is given; :class:`MethodError` for an unknown kind."""
        try:
            return self.defaults[kind]
        except KeyError:
            raise MethodError(f"input form {kind!r}: expected one of {', '.join(self.defaults)}") from None

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __len__(self) -> int:
        return len(self._entries)
