"""Look at recordings, batches and raw folders in the Rerun viewer (``polcam view``'s library).

PATH is one of

* a Rerun recording (``.rrd``: ``polcam capture --rerun FILE.rrd``,
  ``polcam process --rerun FILE.rrd``, or any other);
* a ``polcam process`` output folder: every frame folder under it (one with a
  ``meta.json``) is read back from disk (diffuse, specular, s0, dolp, aolp
  as ``.exr`` or ``.tif``; the raw frame named in ``meta.json`` when it still
  exists), in name order, one ``frame`` time step each;
* a ``polcam demo`` output folder: its ``demo.rrd``, else its ``layers/``;
* a folder of raw frames: each is demosaiced (:func:`polcam.demosaic` with
  the default method, at the polarizer-cell resolution as ``polcam process``
  does by default) and separated with the default method for its form
  (:func:`polcam.separate` without a method) on the fly.

The path is checked (:func:`resolve`) before any viewer or server starts.
Everything is logged through :class:`polcam.sinks.rerun.RerunSink`, with the
same entity paths, encodings and blueprint as a batch (a live capture's, without
its statistics plots).  Without
``--web`` the native viewer opens (it needs a display); with ``--web``
Rerun's web viewer is served (:class:`polcam.sinks.rerun.WebServer`) on
127.0.0.1 unless ``--bind`` says otherwise, the URL to open is printed, and
the server runs until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

from polcam.errors import FrameReadError, LayoutError
from polcam.io import read_frame
from polcam.io.listing import is_raw_file, raw_files_in
from polcam.pipeline import run_frame
from polcam.process import layout_hint
from polcam.sinks.rerun import RerunSink
from polcam.sinks.rerun_web import WebServer, native_viewer

__all__ = ["EXPECTED", "PRODUCTS", "Target", "check_recording", "frame_folders", "kind_of", "log_path", "resolve",
           "view"]


#: What ``polcam view`` takes, said in every refusal.
EXPECTED = ("an .rrd recording, a `polcam process` output folder, a `polcam demo` output folder "
            "or a folder of raw frames")

#: The product files of a process frame folder (each as .exr, .tif or .tiff).
PRODUCTS = ("s0", "dolp", "aolp", "diffuse", "specular")


def check_recording(path: str | Path) -> list[str]:
    """Read a ``.rrd`` through with Rerun's reader; refuse one that is not a readable recording.

    Every chunk of every recording store is decoded (``rerun.chunk.RrdReader``),
    so an empty, foreign or truncated file is refused before anything is served.

    Returns
    -------
    list of str
        Notes for the user: a file that reads but ends without Rerun's footer
        (cut at a message boundary, or still being written).

    Raises
    ------
    FrameReadError
        The file cannot be read as a Rerun recording, or holds no recording
        (named, with the reader's reason).
    """
    import warnings

    import rerun.chunk as rrc

    path = Path(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            reader = rrc.RrdReader(str(path))
            recordings = reader.recordings()
            for store in recordings:
                for _ in reader.stream(store=store):
                    pass
        except (RuntimeError, ValueError, OSError) as exc:
            reason = str(exc).removeprefix(f"Failed to read RRD file at {path}: ")
            raise FrameReadError(f"not a readable Rerun recording ({reason}): expected a whole .rrd written by "
                                 "Rerun (polcam capture/process --rerun FILE.rrd)", path=path) from None
    if not recordings:
        raise FrameReadError("holds no recording (a blueprint at most): expected an .rrd with logged data",
                             path=path)
    if any("no footer" in str(w.message) for w in caught):
        return [f"note: {path} ends without Rerun's footer (cut short or still being written): showing what it holds"]
    return []


def _is_processed_folder(p: Path) -> bool:
    return (p / "meta.json").is_file() or any(True for _ in frame_folders(p))


def _check_frame_folders(p: Path) -> None:
    for folder in frame_folders(p):
        for name in PRODUCTS:
            if not any((folder / f"{name}{ext}").is_file() for ext in (".exr", ".tif", ".tiff")):
                other = " (a `polcam stokes` output?)" if name in ("diffuse", "specular") else ""
                raise FrameReadError(f"no {name}.exr or {name}.tif: not a `polcam process` frame folder{other}; "
                                     f"expected {EXPECTED}", path=folder)


class Target(NamedTuple):
    """What ``polcam view PATH`` shows (:func:`resolve`)."""

    kind: str
    path: Path
    notes: tuple[str, ...] = ()


def resolve(path: str | Path) -> Target:
    """What ``polcam view PATH`` shows: (kind, path, notes), checked before any viewer starts.

    Kinds: ``"rrd"`` (a Rerun recording, read through by
    :func:`check_recording`), ``"processed"`` (a process output folder, or one
    frame folder: every frame folder holds the five products) or ``"raw"``
    (a folder of raw frames, each with a layout from its sidecar).  A
    ``polcam demo`` output folder resolves to its ``demo.rrd``, or to its
    ``layers/`` (the process output) where there is no ``demo.rrd``.

    Raises
    ------
    FrameReadError
        A path that is none of these, an unreadable ``.rrd``, a frame folder
        without its products (named, with what was expected).
    LayoutError
        A raw frame whose sidecar names no layout.
    """
    p = Path(path)
    if p.is_file():
        if p.suffix.lower() != ".rrd":
            raise FrameReadError(f"not a Rerun recording (.rrd): expected {EXPECTED}", path=p)
        return Target("rrd", p, tuple(check_recording(p)))
    if not p.is_dir():
        raise FrameReadError(f"no such file or folder: expected {EXPECTED}", path=p)
    if not (p / "meta.json").is_file():
        if (p / "demo.rrd").is_file():
            return resolve(p / "demo.rrd")
        if (p / "layers").is_dir() and _is_processed_folder(p / "layers"):
            return resolve(p / "layers")
    if _is_processed_folder(p):
        _check_frame_folders(p)
        return Target("processed", p)
    if any(is_raw_file(f) for f in p.iterdir()):
        for f in raw_files_in(p):
            if layout_hint(f) is None:
                raise LayoutError("no layout: the file has no sidecar saying it (write one, or view it through "
                                  "`polcam process --layout NAME`)", path=f)
        return Target("raw", p)
    raise FrameReadError(f"holds neither frame folders with meta.json nor raw frames: expected {EXPECTED}", path=p)


def kind_of(path: str | Path) -> str:
    """What ``path`` is: ``"rrd"``, ``"processed"`` or ``"raw"`` (:func:`resolve`'s kind).

    Raises
    ------
    FrameReadError
        A path that is none of these (named, with what was expected).
    """
    return resolve(path)[0]


def frame_folders(root: str | Path) -> Iterator[Path]:
    """The frame folders of a process output folder (those with a ``meta.json``), in name order."""
    root = Path(root)
    if (root / "meta.json").is_file():
        yield root
        return
    yield from sorted(m.parent for m in root.rglob("meta.json"))


def log_path(sink: Any, path: str | Path, *, on_frame: Callable[[str], None] | None = None,
             stop: Callable[[], bool] | None = None) -> int:
    """Log a process output folder or a raw folder to ``sink``; returns the frames logged.

    Parameters
    ----------
    sink
        A :class:`polcam.sinks.rerun.RerunSink`.
    path
        A folder (:func:`kind_of` ``"processed"`` or ``"raw"``).
    on_frame
        Called with each frame's name once it is logged (progress).
    stop
        Polled before each frame; True ends the logging early.

    Raises
    ------
    PolcamError
        A frame that cannot be read or processed (named).
    """
    kind, path, _ = resolve(path)
    n = 0
    if kind == "processed":
        for i, folder in enumerate(frame_folders(path)):
            if stop and stop():
                break
            sink.log_output(i, folder)
            n += 1
            if on_frame:
                on_frame(folder.name)
        return n
    if kind != "raw":
        raise ValueError(f"{path}: log_path takes a folder, not an {kind} file")

    for i, f in enumerate(raw_files_in(path)):
        if stop and stop():
            break
        frame = read_frame(f)
        if frame.layout is None:
            raise LayoutError("no layout: the file has no sidecar saying it (write one, or view it through "
                              "`polcam process --layout NAME`)", path=f)
        # the per-frame pipeline with process's defaults (cell resolution, default methods)
        products = run_frame(frame, resolution="cell", separate=True).products
        ts = frame.metadata.get("timestamp_ns")
        sink.log_products(i, products, timestamp_ns=None if ts is None else int(ts), frame=frame)
        n += 1
        if on_frame:
            on_frame(f.name)
    return n


class _SignalStop:
    """While active, SIGINT and SIGTERM set :attr:`event` instead of ending the process."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> _SignalStop:
        def handler(signum: int, _frame: Any) -> None:
            self.event.set()

        self._previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
        return self

    def wait(self) -> None:
        while not self.event.wait(0.5):
            pass

    def __exit__(self, *exc: object) -> None:
        for s, h in self._previous.items():
            signal.signal(s, h)


def view(path: str | Path, *, web: bool = False, port: int = 9090, bind: str = "127.0.0.1",
         memory_limit: str = "1GiB", out: Callable[[str], None] = print,
         wait: Callable[[], Any] | None = None) -> int:
    """Show ``path`` in Rerun; the library form of ``polcam view``.

    Parameters
    ----------
    path
        An ``.rrd``, a process or demo output folder, or a raw folder (:func:`resolve`).
    web
        Serve the web viewer instead of opening the native one.
    port, bind, memory_limit
        The web viewer's port (data on port + 1), address and buffer
        (:class:`polcam.sinks.rerun.WebServer`).
    out
        Where messages go (the URL to open, warnings).
    wait
        ``web``: returns when the server should stop (default: at SIGINT or
        SIGTERM, which from the start of the call stop the logging and the
        server cleanly).

    Returns
    -------
    int
        Exit status: 0.

    Raises
    ------
    PolcamError
        A path :func:`resolve` refuses, or a ``--web`` port already in use
        (both before anything is served).
    """
    kind, path, notes = resolve(path)  # before any viewer starts: a bad path never gets a URL
    for note in notes:
        out(note)
    if not web:
        if kind == "rrd":
            native_viewer(recordings=(path,), bind=bind)
            out(f"{path} opened in the Rerun viewer")
            return 0
        sink = RerunSink("spawn", raw_every=1, view_scale=1.0, bind=bind, live=False)
        try:
            n = log_path(sink, path)
        finally:
            sink.close()
        out(f"{n} frame(s) of {path} sent to the Rerun viewer")
        return 0
    with _SignalStop() as stop:
        if kind == "rrd":
            server = WebServer(bind=bind, port=port, recordings=(path,), memory_limit=memory_limit)
            try:
                out(server.message())
                out("Ctrl-C stops the server")
                (wait or stop.wait)()
            finally:
                server.stop()
            return 0
        sink = RerunSink("serve", raw_every=1, view_scale=1.0, bind=bind, port=port, memory_limit=memory_limit,
                         live=False)
        try:
            assert sink.server is not None
            out(sink.server.message())
            n = log_path(sink, path, stop=stop.event.is_set)
            if not stop.event.is_set():
                out(f"{n} frame(s) of {path} logged; Ctrl-C stops the server")
                (wait or stop.wait)()
        finally:
            sink.close()
    return 0
