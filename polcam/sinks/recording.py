"""A batch as a Rerun recording: ``polcam process --rerun FILE.rrd``.

One time step per finished frame on the ``frame`` sequence timeline (the
frame's position in the run's sorted input list), logged through
:class:`polcam.sinks.rerun.RerunSink` with the entity paths and encodings a
live capture uses: the frame folder's products read back from disk
(``/polarization/*``, ``/layers/*``) and its raw frame (``/camera/raw``, every
frame), at the full size of the products, without the capture statistics.
"""

from __future__ import annotations

from pathlib import Path

from polcam.sinks.rerun import RerunSink

__all__ = ["RecordingSink"]


class RecordingSink(RerunSink):
    """A ``.rrd`` recording of finished frame folders (:class:`polcam.sinks.base.Sink`).

    :meth:`log` takes a :class:`polcam.sinks.base.Record` whose ``folder`` is
    a finished frame folder; :meth:`close` flushes the file.

    Parameters
    ----------
    path
        The recording file, ending in ``.rrd`` (its folder is created).

    Raises
    ------
    ValueError
        ``path`` does not end in ``.rrd``.
    """

    def __init__(self, path: str | Path) -> None:
        if Path(path).suffix.lower() != ".rrd":
            raise ValueError(f"Rerun recording {str(path)!r}: expected a file ending in .rrd")
        super().__init__(Path(path), raw_every=1, view_scale=1.0, live=False)
