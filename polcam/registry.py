"""A registry of named methods: what the separation and demosaicing registries share.

Each method package keeps one :class:`Registry` of its own entries (a frozen
``MethodSpec`` per name) with a canonical listing order and a default per kind
of input; its ``register`` decorator adds to it, its ``methods`` and
``method_spec`` read it.  An unknown name is a :class:`~polcam.errors.MethodError`
naming the known ones.

A registry may also take *plugins*: the modules other distributions name under
an entry-point group (``[project.entry-points."polcam.separation"]`` in their
``pyproject.toml``, ``halve = "my_package.halve"``).  They are imported the
first time the registry is listed or asked for a name it does not hold, and
register their entries as polcam's own method modules do; so an installed
plugin's method is there for every command, in every process.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import ModuleType
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
    plugins
        The entry-point group whose modules register further entries (loaded once, when the
        registry is first listed or asked for a name it does not hold); None: none.
    """

    def __init__(self, what: str, *, order: Sequence[str] = (), defaults: Mapping[str, str] | None = None,
                 plugins: str | None = None) -> None:
        self.what = what
        self.order: tuple[str, ...] = tuple(order)
        self.defaults: dict[str, str] = dict(defaults or {})
        self.plugins = plugins
        self._plugins_loaded = plugins is None
        self._entries: dict[str, S] = {}

    def load_plugins(self) -> None:
        """Import the modules of the :attr:`plugins` entry-point group (once): each registers its entries.

        An entry point naming a callable (``"pkg.mod:register_all"``) has it called.

        Raises
        ------
        MethodError
            A plugin that fails to import, naming it and the reason.
        """
        if self._plugins_loaded:
            return
        self._plugins_loaded = True        # first: a plugin importing its package's registry is no loop
        from importlib.metadata import entry_points

        for ep in entry_points(group=str(self.plugins)):
            try:
                obj = ep.load()
                if callable(obj) and not isinstance(obj, ModuleType):
                    obj()
            except Exception as exc:  # noqa: BLE001 - reported with the plugin's name
                raise MethodError(f"{self.what} plugin {ep.name!r} ({ep.value}, entry point group "
                                  f"{self.plugins}) failed to load: {type(exc).__name__}: {exc}") from exc

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
        self.load_plugins()
        listed = [n for n in self.order if n in self._entries]
        return tuple(listed + sorted(n for n in self._entries if n not in self.order))

    def get(self, name: str) -> S:
        """The entry of ``name``; a :class:`MethodError` naming the known names if there is none."""
        if name not in self._entries:
            self.load_plugins()
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
