"""Offline processing of folders of raw frames: ``polcam process RAW_DIR -o OUT_DIR``.

Per input frame ``OUT_DIR/<stem>/`` receives ``diffuse``, ``specular``, ``s0``,
``dolp``, ``aolp`` (EXR float32 by default, TIFF float32 or uint16 on request)
and ``meta.json``; ``OUT_DIR/summary.json`` describes the run.  With
``recursive=True`` the stem keeps the relative folder path
(``OUT_DIR/day1/cam0/frame_0001/``) so names never collide.

Reproducible and resumable:

* ``meta.json`` records the input file and its SHA-256, the layout, the
  calibration file and its hash, the method and every option, the polcam
  version, timings and the solver's info, and a *fingerprint*: the SHA-256 of
  the canonical JSON of everything that determines the outputs (input hash,
  layout, levels, calibration hash, demosaicing, resolution, method, options,
  output format, polcam version).
* Every file is written atomically (temporary file + rename) and
  ``meta.json`` last, so it marks a finished frame.  A rerun skips a frame
  whose ``meta.json`` has the same fingerprint and whose outputs all exist
  (``force=True`` redoes it); an interrupted run loses at most the frames in
  flight, and the temporary files a killed run left behind are removed.
* A bad input (unreadable, truncated, wrong size, no layout, ...) or a failed
  write (read-only folder, full disk) is reported by name with the reason; the
  other frames go on; ``summary.json`` lists the failures and the exit status
  is non-zero.

Parallel: ``workers`` local processes (one BLAS thread each, so the machine is
not oversubscribed and the results do not depend on the thread count), or a
Dask distributed cluster (``scheduler="tcp://host:8786"``, the ``dask`` extra).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polcam import __version__
from polcam._hashing import sha256_file
from polcam.errors import PolcamError
from polcam.parallel import process_pool
from polcam.pipeline import default_demosaic
from polcam.sinks.files import FORMATS

__all__ = ["ProcessOptions", "FrameJob", "OUTPUTS", "check_run", "layout_hint", "plan", "process_frame", "run",
           "sha256_file"]

#: Products written per frame (plus meta.json).
OUTPUTS: tuple[str, ...] = ("diffuse", "specular", "s0", "dolp", "aolp")
_UNIT = ("diffuse", "specular", "dolp")          # products in [0, 1]: uint16 in tiff16
_TEMP = re.compile(r"^\..+\.tmp(\.[A-Za-z0-9]+)?$")


@dataclass(frozen=True)
class ProcessOptions:
    """What determines a run's outputs (besides the input files)."""

    method: str | None = None            # None: the registry's default per frame (default_method)
    method_options: dict[str, Any] = field(default_factory=dict)
    layout: str | None = None            # overrides the sidecar
    demosaic: str | None = None          # None: the demosaicing registry's default for the layout
    resolution: str = "cell"
    format: str = "exr"
    calibration: str | None = None       # path of a calibration file
    max_pixels: int | None = None        # largest frame read (None: polcam.io's default limit)


@dataclass(frozen=True)
class FrameJob:
    """One input frame and where its outputs go."""

    input: str
    target: str
    name: str


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def _jsonable(obj: Any) -> Any:
    from polcam._jsonable import jsonable

    return jsonable(obj)


def plan(inputs: Sequence[Path], out_dir: Path, *, recursive: bool = False) -> tuple[list[FrameJob], list[dict[str, str]]]:
    """The frames to process under ``inputs`` (files or folders) and their targets.

    Returns
    -------
    jobs : list of FrameJob
        Sorted by name.
    problems : list of dict
        Inputs that are neither a readable file nor a folder, and name
        collisions (``input``, ``error``).
    """
    from polcam.io.listing import raw_files_in

    jobs: dict[str, FrameJob] = {}
    problems: list[dict[str, str]] = []
    for root in inputs:
        root = Path(root)
        if root.is_dir():
            for f in raw_files_in(root, recursive=recursive):
                rel = f.relative_to(root).with_suffix("")
                name = rel.as_posix() if recursive else f.stem
                if name in jobs:
                    problems.append({"input": str(f), "error": f"output name {name!r} already used by "
                                     f"{jobs[name].input}; use --recursive or rename"})
                    continue
                jobs[name] = FrameJob(str(f), str(out_dir / name), name)
        elif root.is_file():
            name = root.stem
            if name in jobs:
                problems.append({"input": str(root), "error": f"output name {name!r} already used"})
                continue
            jobs[name] = FrameJob(str(root), str(out_dir / name), name)
        else:
            problems.append({"input": str(root), "error": "no such file or folder"})
    return [jobs[k] for k in sorted(jobs)], problems


def _is_done(job: FrameJob, opts: ProcessOptions, fingerprint: str) -> bool:
    """Outputs of ``job`` exist and were made with this fingerprint."""
    try:
        meta = json.loads((Path(job.target) / "meta.json").read_text())
    except (OSError, ValueError):
        return False
    ext = FORMATS[opts.format][0]
    if meta.get("fingerprint") != fingerprint:
        return False
    return all((Path(job.target) / f"{p}{ext}").is_file() for p in OUTPUTS)


def _prepare(job: FrameJob, opts: ProcessOptions) -> tuple[Any, str, dict[str, Any], dict[str, Any], str]:
    """Read the frame and work out everything that determines its outputs.

    Returns (frame, method, method options, fingerprint parts, fingerprint).
    """
    from polcam.io import read_frame
    from polcam.pipeline import require_layout

    input_hash = sha256_file(job.input)
    frame = require_layout(read_frame(job.input, layout=opts.layout, max_pixels=opts.max_pixels), job.input)
    calibration_hash = sha256_file(opts.calibration) if opts.calibration else None
    from polcam.separation import default_method

    method = opts.method or default_method("stack" if frame.layout.is_color else "mono-stack")
    # without --method each frame's default method gets the options it takes (check_run made sure
    # that every option is taken by some method of the run)
    method_options = (dict(opts.method_options) if opts.method else
                      {k: v for k, v in opts.method_options.items() if _takes(method, k)})
    parts = {
        "input_sha256": input_hash,
        "layout": str(frame.layout),
        "black_level": float(frame.black_level),
        "white_level": float(frame.white_level),
        "calibration_sha256": calibration_hash,
        "demosaic": opts.demosaic or default_demosaic(frame.layout),
        "resolution": opts.resolution,
        "method": method,
        "method_options": _jsonable(method_options),
        "format": opts.format,
        "polcam_version": __version__,
    }
    return frame, method, method_options, parts, hashlib.sha256(_canonical(parts).encode()).hexdigest()


def _takes(method: str, option: str) -> bool:
    from polcam.errors import MethodError
    from polcam.separation._registry import check_options

    try:
        check_options(method, {option: None}, types=False)
    except MethodError:
        return False
    return True


def layout_hint(path: str | os.PathLike[str]) -> Any:
    """The layout a frame's sidecar declares (its ``layout``, else its pixel format's), or ``None``.

    Reads the sidecar only, not the pixels; a sidecar that cannot be read gives ``None`` (the
    frame's own read reports it).
    """
    from polcam.io import read_sidecar
    from polcam.mosaic import layout_for_format, parse_layout, pixel_format

    try:
        side = read_sidecar(path) or {}
        if side.get("layout"):
            return parse_layout(side["layout"])
        if side.get("pixel_format"):
            return layout_for_format(pixel_format(side["pixel_format"], side.get("vendor")))
    except (PolcamError, OSError):
        return None
    return None


def check_run(opts: ProcessOptions, jobs: Sequence[FrameJob]) -> dict[str, str]:
    """Check the method and options against the frames before any work; the method per input form.

    Without ``opts.method`` each frame runs the registry's default for its form (colour stack
    or mono stack); the forms are known from ``opts.layout``, else from the frames' sidecars
    (both forms are assumed where no sidecar says).

    Returns
    -------
    dict
        Input form (``"stack"``, ``"mono-stack"``) -> method of the frames of that form.

    Raises
    ------
    MethodError
        An unknown method; an option the named method does not take, or (no method named)
        that no method of the run takes; an option value not of the option's type; a
        colour-only method with a mono ``--layout``.
    LayoutError
        An unknown ``opts.layout``.
    """
    from polcam.errors import MethodError
    from polcam.mosaic import parse_layout
    from polcam.separation import default_method, method_spec, methods
    from polcam.separation._registry import check_options

    if opts.layout is not None:
        lay = parse_layout(opts.layout)
        forms = {"stack" if lay.is_color else "mono-stack"}
    else:
        hints = [layout_hint(j.input) for j in jobs]
        forms = {"stack" if h.is_color else "mono-stack" for h in hints if h is not None}
        if not forms or any(h is None for h in hints):
            forms |= {"stack", "mono-stack"}
    if opts.method is not None:
        spec = method_spec(opts.method)
        check_options(opts.method, dict(opts.method_options))
        if opts.layout is not None and forms == {"mono-stack"} and not spec.mono:
            mono = ", ".join(m for m in methods() if method_spec(m).mono)
            raise MethodError(f"--method {opts.method}: it needs colour frames and --layout {opts.layout} is "
                              f"a mono layout; for mono frames use one of {mono}")
        return {f: opts.method for f in sorted(forms)}
    chosen = {f: default_method(f) for f in sorted(forms)}
    for key in opts.method_options:
        if not any(_takes(m, key) for m in chosen.values()):
            reasons = []
            for m in sorted(set(chosen.values())):
                try:
                    check_options(m, {key: None}, types=False)
                except MethodError as exc:
                    reasons.append(str(exc))
            used = ", ".join(f"{m} for {'colour' if f == 'stack' else 'mono'} frames" for f, m in chosen.items())
            raise MethodError(f"--option {key}: no method of this run ({used}) takes it: {'; '.join(reasons)}")
        for m in sorted(set(chosen.values())):
            if _takes(m, key):
                check_options(m, {key: opts.method_options[key]})
    return chosen


def _remove_stale_temps(folder: Path) -> int:
    n = 0
    if folder.is_dir():
        for f in folder.iterdir():
            if _TEMP.match(f.name):
                try:
                    f.unlink()
                    n += 1
                except OSError:
                    pass
    return n


def process_frame(job: FrameJob, opts: ProcessOptions, *, force: bool = False) -> dict[str, Any]:
    """Process one frame; never raises for bad input (the error is in the result).

    Returns
    -------
    dict
        ``status`` ("done", "skipped" or "failed"), ``input``, ``name``,
        ``seconds``, and ``error`` (failed) or ``fingerprint`` (done/skipped).
    """
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    base = {"input": job.input, "name": job.name}
    try:
        target = Path(job.target)
        _remove_stale_temps(target)
        frame, method, method_options, parts, fingerprint = _prepare(job, opts)
        if not force and _is_done(job, opts, fingerprint):
            return {**base, "status": "skipped", "fingerprint": fingerprint,
                    "seconds": time.perf_counter() - t0}
        with threadpool_limits(limits=1, user_api="blas"):
            _compute(job, opts, frame, method, method_options, parts, fingerprint, t0)
        return {**base, "status": "done", "fingerprint": fingerprint,
                "seconds": time.perf_counter() - t0}
    except Exception as exc:  # a bad frame never stops the batch: it is reported by name
        text = str(exc) if isinstance(exc, PolcamError) and exc.path else f"{job.input}: {exc}"
        if not isinstance(exc, (PolcamError, OSError)):
            text = f"{job.input}: {type(exc).__name__}: {exc}"
        return {**base, "status": "failed", "error": text, "seconds": time.perf_counter() - t0}


def _compute(job: FrameJob, opts: ProcessOptions, frame: Any, method: str, method_options: dict[str, Any],
             parts: dict[str, Any], fingerprint: str, t0: float) -> dict[str, Any]:
    from polcam.pipeline import run_frame
    from polcam.separation import method_spec
    from polcam.sinks.files import write_meta, write_products

    calibration = _calibration(opts.calibration, parts["calibration_sha256"]) if opts.calibration else None
    read_seconds = time.perf_counter() - t0
    run_options = dict(method_options)
    if _IN_POOL and "workers" in (method_spec(method).options or ()) and "workers" not in run_options:
        run_options["workers"] = 1  # the frames are the parallel part here (the answer does not change)
    result = run_frame(frame, calibration=calibration, demosaic=parts["demosaic"], resolution=opts.resolution,
                       stokes_products=("s0", "dolp", "aolp"), separate=True, method=method,
                       method_options=run_options)
    frame = result.frame
    timings: dict[str, float] = {"read": read_seconds + result.timings["calibrate"],
                                 **{k: v for k, v in result.timings.items() if k != "calibrate"}}
    t = time.perf_counter()
    file_meta = {"input": job.input, "method": method, "layout": str(frame.layout),
                 "fingerprint": fingerprint, "polcam_version": __version__}
    names = write_products(job.target, {name: result.products[name] for name in OUTPUTS}, fmt=opts.format,
                           unit=_UNIT, metadata=file_meta)
    timings["write"] = time.perf_counter() - t
    assert result.separation is not None
    info = {k: v for k, v in result.separation.info.items() if k not in ("residuals",)}
    meta = {
        "input": job.input,
        "input_sha256": parts["input_sha256"],
        "name": job.name,
        "outputs": names,
        "layout": str(frame.layout),
        "frame": _jsonable({k: v for k, v in frame.metadata.items() if k != "path"}),
        "bit_depth": frame.bit_depth,
        "black_level": frame.black_level,
        "white_level": frame.white_level,
        "calibration": opts.calibration,
        "calibration_sha256": parts["calibration_sha256"],
        "method": method,
        "method_options": _jsonable(method_options),
        "options_requested": _jsonable(asdict(opts)),
        "polcam_version": __version__,
        "shape": list(result.stack.shape),
        "timings": timings,
        "separation_info": _jsonable(info),
        "fingerprint_parts": parts,
        "fingerprint": fingerprint,
    }
    write_meta(job.target, meta)
    return meta


_CALIBRATIONS: dict[tuple[str, str], Any] = {}


def _calibration(path: str, digest: str) -> Any:
    """The calibration in ``path``, loaded once per process (its per-cell matrices are cached on it)."""
    from polcam.calibration import load_calibration

    key = (str(Path(path).resolve()), digest)
    if key not in _CALIBRATIONS:
        _CALIBRATIONS.clear()
        _CALIBRATIONS[key] = load_calibration(path)
    return _CALIBRATIONS[key]


class RunRecording:  # RERUN SINK (process --rerun): to become the shared polcam.sinks.rerun sink
    """A run as a Rerun recording (``--rerun FILE.rrd``): one time step per frame.

    Logged through :class:`polcam.sinks.rerun.RerunSink` (the entity paths and
    encodings live capture uses): for each finished frame its outputs read
    back from disk (``/polarization/*``, ``/layers/*``) and its raw frame
    (``/camera/raw``) on the ``frame`` sequence timeline, the frame's position
    in the sorted input list.
    """

    def __init__(self, path: Path, names: Sequence[str]) -> None:
        from polcam.sinks.rerun import RerunSink

        self._index = {n: i for i, n in enumerate(names)}
        self._sink = RerunSink(path, raw_every=1, view_scale=1.0)

    def log_frame(self, folder: Path, ext: str, name: str) -> None:
        """Log the outputs of one finished frame (``ext``: kept for callers; any format is read)."""
        self._sink.log_output(self._index.get(name, len(self._index)), folder)

    def close(self) -> None:
        """Flush the recording to disk."""
        self._sink.close()


#: True in the worker processes of :func:`run`: the frames run in parallel there, so a method with
#: a ``workers`` option (the tensor methods) runs with one instead of starting processes of its own.
_IN_POOL = False


def _init_worker() -> None:
    """Worker initializer: mark the process as a frame worker (its BLAS threads are limited by
    :func:`polcam.parallel.process_pool`)."""
    global _IN_POOL
    _IN_POOL = True


def run(jobs: Sequence[FrameJob], opts: ProcessOptions, *, workers: int = 1,
        scheduler: str | None = None, force: bool = False,
        on_result: Callable[[dict[str, Any]], None] | None = None,
        stop: Callable[[], bool] | None = None) -> list[dict[str, Any]]:
    """Process ``jobs``; results in completion order.

    Parameters
    ----------
    jobs
        From :func:`plan`.
    opts
        The run's options.
    workers
        Local worker processes (1: in this process).
    scheduler
        Address of a Dask distributed scheduler (``tcp://...``) or a
        ``distributed.Client``; overrides ``workers``.
    force
        Redo frames whose outputs are up to date.
    on_result
        Called with each frame's result as it completes (progress, JSON lines).
    stop
        Polled between frames; when it returns True no new frame is started
        (frames in flight finish).
    """
    results: list[dict[str, Any]] = []

    def done(r: dict[str, Any]) -> None:
        results.append(r)
        if on_result:
            on_result(r)

    stop = stop or (lambda: False)
    if scheduler is not None:
        _run_dask(jobs, opts, scheduler, force, done, stop)
    elif workers <= 1:
        for job in jobs:
            if stop():
                break
            done(process_frame(job, opts, force=force))
    else:
        with process_pool(workers, preload=("polcam.process",), initializer=_init_worker) as pool:
            pending: set[Future[dict[str, Any]]] = set()
            it = iter(jobs)
            exhausted = False
            while True:
                while not exhausted and len(pending) < 2 * workers and not stop():
                    job = next(it, None)
                    if job is None:
                        exhausted = True
                        break
                    pending.add(pool.submit(process_frame, job, opts, force=force))
                if not pending:
                    break
                finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                for fut in finished:
                    done(fut.result())
                if stop() and not pending:
                    break
    return results


def _run_dask(jobs: Sequence[FrameJob], opts: ProcessOptions, scheduler: Any, force: bool,
              done: Callable[[dict[str, Any]], None], stop: Callable[[], bool]) -> None:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise PolcamError("--scheduler needs Dask: pip install 'polcam[dask]'") from None
    own = not isinstance(scheduler, Client)
    client = Client(scheduler) if own else scheduler
    try:
        futures = [client.submit(process_frame, job, opts, force=force, pure=False, key=f"polcam-{job.name}-{i}")
                   for i, job in enumerate(jobs)]
        for fut in as_completed(futures):
            if stop():
                for f in futures:
                    f.cancel()
                break
            done(fut.result())
    finally:
        if own:
            client.close()


def summarize(results: Iterable[dict[str, Any]], problems: Sequence[dict[str, str]], *,
              opts: ProcessOptions, seconds: float, interrupted: bool) -> dict[str, Any]:
    """The run's summary.json content."""
    results = sorted(results, key=lambda r: r["name"])
    failed = [{"input": r["input"], "error": r["error"]} for r in results if r["status"] == "failed"]
    return {
        "polcam_version": __version__,
        "options": _jsonable(asdict(opts)),
        "frames": len(results) + len(problems),
        "done": sum(r["status"] == "done" for r in results),
        "skipped": sum(r["status"] == "skipped" for r in results),
        "failed": failed + list(problems),
        "interrupted": interrupted,
        "seconds": seconds,
        "results": [{k: v for k, v in r.items() if k != "error"} for r in results],
    }


def write_summary(out_dir: Path, summary: dict[str, Any]) -> Path:
    """Write OUT_DIR/summary.json atomically."""
    from polcam.io.atomic import atomic_write

    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(out_dir / "summary.json", "w") as fh:
        json.dump(summary, fh, indent=2)
    return out_dir / "summary.json"

