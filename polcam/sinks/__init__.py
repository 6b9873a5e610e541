"""Where results go: one interface, :class:`polcam.sinks.base.Sink`.

A sink has ``log(index, record)`` (a :class:`~polcam.sinks.base.Record`: what
one frame produced) and ``close()``; :class:`~polcam.sinks.base.FanOut` hands
each record to several.  The sinks:

- :class:`polcam.acquisition.saving.FrameSaver`: a capture's frames, losslessly;
- :class:`polcam.sinks.files.ProductFiles`: a processed frame's products and
  ``meta.json`` (:mod:`polcam.sinks.files` also holds the output format table);
- :class:`polcam.sinks.rerun.RerunSink`: the Rerun view (raw, S0, DoLP, AoLP,
  diffuse, specular, statistics) of a capture, a batch or ``polcam view``, to
  a viewer, the web viewer or a ``.rrd`` file: one writer, one meaning per
  entity path;
- :class:`polcam.sinks.recording.RecordingSink`: ``polcam process --rerun FILE.rrd``.

Adding a sink: one module here with a class that has ``log`` and ``close``
(subclass :class:`~polcam.sinks.base.SinkBase` for ``with``), handed to
:func:`polcam.acquisition.run_capture` (``sinks=``: every frame received;
``Capture(live_sink=...)``: the live view's maps, layers and statistics) or
:func:`polcam.process.run` (``sinks=``: every finished frame folder); a
command line flag for it goes in :mod:`polcam.commands`.

Rerun is imported only when a Rerun sink is created.
"""

from __future__ import annotations

from polcam.sinks.base import FanOut, Record, Sink, SinkBase

__all__ = ["ENTITIES", "FanOut", "Record", "RerunSink", "Sink", "SinkBase"]


def __getattr__(name: str):  # lazy: importing polcam.sinks does not import rerun
    if name in ("ENTITIES", "RerunSink"):
        from polcam.sinks import rerun as _rerun

        return getattr(_rerun, name)
    raise AttributeError(f"module 'polcam.sinks' has no attribute {name!r}")
