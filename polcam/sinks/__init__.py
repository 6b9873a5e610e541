"""Where live results go.

- :mod:`polcam.sinks.rerun`: the Rerun view (raw, S0, DoLP, AoLP, diffuse,
  specular, statistics) of a capture, a batch or ``polcam view``, to a viewer,
  the web viewer or a ``.rrd`` file: one writer, one meaning per entity path.

Rerun is imported only when a sink is created.
"""

from __future__ import annotations

__all__ = ["ENTITIES", "RerunSink"]


def __getattr__(name: str):  # lazy: importing polcam.sinks does not import rerun
    if name in __all__:
        from polcam.sinks import rerun as _rerun

        return getattr(_rerun, name)
    raise AttributeError(f"module 'polcam.sinks' has no attribute {name!r}")
