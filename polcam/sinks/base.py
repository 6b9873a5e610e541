"""The sink interface: where a frame's results go, whoever produced them.

A sink is any object with ``log(index, record)`` and ``close()``
(:class:`Sink`, a structural protocol: nothing to inherit).  Producers hand a
:class:`Record` per frame (capture: every received frame, and the live view's
maps, layers and statistics; process: every finished frame folder) and close
the sink once when they end, however they end.  :class:`FanOut` hands each
record to several sinks.  :class:`SinkBase` gives a sink ``with`` support.

The sinks polcam has:

- :class:`polcam.acquisition.saving.FrameSaver`: a capture's frames and
  sidecars, losslessly and atomically, on writer threads;
- :class:`polcam.sinks.files.ProductFiles`: a processed frame's products and
  its ``meta.json`` (last);
- :class:`polcam.sinks.rerun.RerunSink`: the Rerun view (viewer, web viewer or
  ``.rrd``) of a capture, a batch or ``polcam view``;
- :class:`polcam.sinks.recording.RecordingSink`: a batch as a ``.rrd``
  recording, one time step per finished frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, Self, runtime_checkable

if TYPE_CHECKING:
    import numpy as np

    from polcam.frame import Frame

__all__ = ["FanOut", "Record", "Sink", "SinkBase"]


@dataclass(frozen=True)
class Record:
    """What one frame produced so far; each sink takes the parts it handles.

    Attributes
    ----------
    frame
        The frame as the camera sent it (raw mosaic, sidecar metadata), or ``None``.
    products
        Name -> image: ``s0`` (S0 in [0, 2]), ``dolp`` ([0, 1]), ``aolp``
        (radians, [0, pi)), ``diffuse``, ``specular`` ([0, 1], the scale of
        one polarization image), ...; (h, w) or (h, w, 3) arrays.
    scale
        Name -> factor: ``products[name] * scale[name]`` is the product in the
        unit above (1 where not given; the live view's fixed-point maps).
    stats
        Capture statistics: ``fps``, ``dropped``, ``incomplete``,
        ``separation_seconds``, ``maps_fps``, ``layers_fps`` (``None``: not logged).
    timestamp_ns
        The camera's timestamp of the frame, or ``None``.
    folder
        A frame folder: where a file sink writes ``products`` and ``meta``, or
        a finished one that a Rerun sink reads back (``polcam process``).
    name
        The frame's name in a batch (its folder below the output folder), or ``None``.
    meta
        The frame's ``meta.json`` content (a file sink writes it after the products).
    """

    frame: Frame | None = None
    products: Mapping[str, np.ndarray] = field(default_factory=dict)
    scale: Mapping[str, float] = field(default_factory=dict)
    stats: Mapping[str, float | None] = field(default_factory=dict)
    timestamp_ns: int | None = None
    folder: Path | None = None
    name: str | None = None
    meta: Mapping[str, Any] | None = None


@runtime_checkable
class Sink(Protocol):
    """Where results go: ``log`` each frame's record, ``close`` once at the end."""

    def log(self, index: int, record: Record) -> None:
        """Take frame ``index``'s record (may block: a lossless writer waits for room)."""

    def close(self) -> None:
        """Finish: flush or write what is pending, release files, threads and viewers."""


class SinkBase:
    """``with`` support for a sink: ``close()`` on leaving the block, however it is left."""

    def log(self, index: int, record: Record) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


class FanOut(SinkBase):
    """Hand every record to each of ``sinks``, in order; close them all.

    Parameters
    ----------
    sinks
        The sinks (``None`` entries are left out).

    Notes
    -----
    :meth:`close` closes every sink even when one of them raises, then
    raises the first error.
    """

    def __init__(self, sinks: Iterable[Sink | None] = ()) -> None:
        self.sinks: list[Sink] = [s for s in sinks if s is not None]

    def __len__(self) -> int:
        return len(self.sinks)

    def log(self, index: int, record: Record) -> None:
        """Log ``record`` to each sink in turn."""
        for sink in self.sinks:
            sink.log(index, record)

    def close(self) -> None:
        """Close each sink; the first error is raised after all were closed."""
        first: BaseException | None = None
        for sink in self.sinks:
            try:
                sink.close()
            except BaseException as exc:  # noqa: BLE001 - the others are closed all the same
                if first is None:
                    first = exc
        if first is not None:
            raise first
