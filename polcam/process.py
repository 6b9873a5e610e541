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
* A frame's products and its ``meta.json`` never disagree: before a frame
  writes anything its old ``meta.json`` is removed (so an interrupted frame
  has none), every file is written atomically (temporary file + rename), and
  ``meta.json`` is written last with the byte size and SHA-256 of each product
  file.  A rerun skips a frame only when its ``meta.json`` has the same
  fingerprint *and* every product file it lists has that size and hash
  (``force=True`` redoes it); anything else is redone.  An interrupted run
  (kill -9, full disk, power cut) loses at most the frames in flight, and the
  temporary files a killed run left behind are removed.
* A bad input (unreadable, truncated, wrong size, no layout, ...) or a failed
  write (read-only folder, full disk) is reported by name with the reason; the
  other frames go on; ``summary.json`` lists the failures and the exit status
  is non-zero.

Parallel: ``workers`` local processes (one BLAS thread each, so the machine is
not oversubscribed and the results do not depend on the thread count), or a
Dask distributed cluster (``scheduler="tcp://host:8786"``, the ``dask`` extra).
Local workers are supervised (:mod:`polcam.workpool`): a worker that dies
(out-of-memory killer, kill -9) costs only the frame it held, reported failed
with the reason; the workers die with the run.  docs/guide/faults.md lists
every fault and what the run does.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import signal
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from polcam._hashing import sha256_file
from polcam._jsonable import jsonable
from polcam._memory import peak_rss_mb, reset_peak
from polcam._version import __version__
from polcam.calibration import load_calibration
from polcam.demosaicing import resolve_demosaic
from polcam.errors import FrameWriteError, PolcamError
from polcam.footprint import frame_memory
from polcam.io import read_frame
from polcam.io.atomic import fsync_dir
from polcam.io.listing import raw_files_in
from polcam.io.readers import declared_size
from polcam.mosaic import parse_layout
from polcam.pipeline import require_layout, run_frame
from polcam.process_checks import check_run, layout_hint, separation_for
from polcam.separation import layout_form
from polcam.sinks.base import FanOut, Record, Sink
from polcam.sinks.files import FORMATS, ProductFiles
from polcam.workpool import orphaned, run_jobs

if TYPE_CHECKING:
    from polcam.demosaicing import ResolvedDemosaic
    from polcam.separation import ResolvedSeparation

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
    max_memory: int | None = None        # largest estimated memory of one frame, bytes (None/0: no limit)


@dataclass(frozen=True)
class FrameJob:
    """One input frame and where its outputs go."""

    input: str
    target: str
    name: str


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def _jsonable(obj: Any) -> Any:
    return jsonable(obj)


def plan(inputs: Sequence[Path], out_dir: Path, *, recursive: bool = False,
         skipped: list[tuple[Path, str]] | None = None) -> tuple[list[FrameJob], list[dict[str, str]]]:
    """The frames to process under ``inputs`` (files or folders) and their targets.

    ``skipped``: where given, paths left out of a recursive listing (symbolic
    link loops, dangling links, unreadable folders) are appended as ``(path, reason)``.

    Returns
    -------
    jobs : list of FrameJob
        Sorted by name.
    problems : list of dict
        Inputs that are neither a readable file nor a folder, and name
        collisions (``input``, ``error``).
    """
    jobs: dict[str, FrameJob] = {}
    problems: list[dict[str, str]] = []
    for root in inputs:
        root = Path(root)
        if root.is_dir():
            for f in raw_files_in(root, recursive=recursive, skipped=skipped):
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
    """Outputs of ``job`` were made with this fingerprint and are the files its meta.json describes.

    Every product file must exist with the byte size and SHA-256 recorded in
    meta.json: a frame interrupted while replacing its outputs, or a file
    changed since, is not up to date.
    """
    try:
        meta = json.loads((Path(job.target) / "meta.json").read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(meta, dict) or meta.get("fingerprint") != fingerprint:
        return False
    ext = FORMATS[opts.format][0]
    files = meta.get("files")
    if not isinstance(files, dict) or set(files) != {f"{p}{ext}" for p in OUTPUTS}:
        return False
    for name, rec in files.items():
        path = Path(job.target) / name
        try:
            if not isinstance(rec, dict) or path.stat().st_size != rec.get("bytes"):
                return False
            if sha256_file(path) != rec.get("sha256"):
                return False
        except OSError:
            return False
    return True


def _prepare(job: FrameJob, opts: ProcessOptions, separations: Mapping[str, ResolvedSeparation]
             ) -> tuple[Any, ResolvedSeparation, ResolvedDemosaic, dict[str, Any], str]:
    """Read the frame and work out everything that determines its outputs.

    ``separations``: the run's resolved separation per input form (:func:`check_run`); a form
    it lacks is resolved here.  Returns (frame, separation, demosaicing, fingerprint parts,
    fingerprint).
    """
    input_hash = sha256_file(job.input)
    if opts.max_memory:
        _check_memory(job, opts, separations)
    frame = require_layout(read_frame(job.input, layout=opts.layout, max_pixels=opts.max_pixels), job.input)
    calibration_hash = sha256_file(opts.calibration) if opts.calibration else None
    form = layout_form(frame.layout)
    sep = separations.get(form) or separation_for(opts, form, got=f"a frame of the mono layout {frame.layout}")
    dem = resolve_demosaic(opts.demosaic, frame.layout)
    parts = {
        "input_sha256": input_hash,
        "layout": str(frame.layout),
        "black_level": float(frame.black_level),
        "white_level": float(frame.white_level),
        "calibration_sha256": calibration_hash,
        "demosaic": dem.method,
        "resolution": opts.resolution,
        "method": sep.method,
        "method_options": _jsonable(dict(sep.options)),
        "format": opts.format,
        "polcam_version": __version__,
    }
    return frame, sep, dem, parts, hashlib.sha256(_canonical(parts).encode()).hexdigest()


def _check_memory(job: FrameJob, opts: ProcessOptions, separations: Mapping[str, ResolvedSeparation]) -> None:
    """Refuse a frame whose declared size needs more memory than ``opts.max_memory`` (before reading it)."""
    size = declared_size(job.input)
    if size is None or opts.max_memory is None:
        return
    lay = parse_layout(opts.layout) if opts.layout else layout_hint(job.input)
    colour = lay is None or lay.is_color          # unknown: the larger (colour) estimate
    form = "stack" if lay is None else layout_form(lay)
    method = (separations.get(form) or separation_for(opts, form, got=f"a frame of the mono layout {lay}")).method
    need = frame_memory(*size, colour=colour, resolution=opts.resolution, method=method)
    if need > opts.max_memory:
        raise FrameTooLarge(
            f"the frame is {size[0]}x{size[1]}: it needs about {need / 2**30:.1f} GiB of memory ({method}, "
            f"{opts.resolution} resolution), more than the limit of {opts.max_memory / 2**30:.1f} GiB; "
            "raise it with --max-memory SIZE (max_memory=, 0: no limit) if the machine has the memory",
            path=job.input)


class FrameTooLarge(PolcamError):
    """A frame whose estimated memory exceeds the run's limit (:attr:`ProcessOptions.max_memory`)."""


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


def process_frame(job: FrameJob, opts: ProcessOptions, *, force: bool = False,
                  separations: Mapping[str, ResolvedSeparation] | None = None) -> dict[str, Any]:
    """Process one frame; never raises for bad input (the error is in the result).

    ``separations``: the run's separation per input form, as :func:`check_run` resolved it
    (None or a form it lacks: resolved for this frame).

    Returns
    -------
    dict
        ``status`` ("done", "skipped" or "failed"), ``input``, ``name``,
        ``seconds``, and ``error`` (failed) or ``fingerprint`` (done/skipped);
        a done frame adds ``peak_rss_mb``, the largest resident memory of the
        process while it computed the frame (:mod:`polcam._memory`).
    """
    return _process_frame(job, opts, force=force, separations=separations or {}, in_pool=False)


def _process_frame(job: FrameJob, opts: ProcessOptions, *, force: bool,
                   separations: Mapping[str, ResolvedSeparation], in_pool: bool) -> dict[str, Any]:
    """:func:`process_frame`; ``in_pool``: in a worker of :func:`run`'s local pool, where the frames are
    the parallel part, so a method with a ``workers`` option (the tensor methods) runs with one
    instead of starting processes of its own (the answer does not change)."""
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    base = {"input": job.input, "name": job.name}
    try:
        target = Path(job.target)
        _remove_stale_temps(target)
        frame, sep, dem, parts, fingerprint = _prepare(job, opts, separations)
        if not force and _is_done(job, opts, fingerprint):
            return {**base, "status": "skipped", "fingerprint": fingerprint,
                    "seconds": time.perf_counter() - t0}
        _unmark_finished(target)
        reset_peak()  # the frame's own peak memory (polcam._memory)
        with threadpool_limits(limits=1, user_api="blas"):
            if in_pool and sep.takes("workers") and "workers" not in sep.options:
                sep = sep.with_options(workers=1)
            _compute(job, opts, frame, sep, dem, parts, fingerprint, t0)
        return {**base, "status": "done", "fingerprint": fingerprint,
                "seconds": time.perf_counter() - t0, "peak_rss_mb": round(peak_rss_mb(), 1)}
    except Exception as exc:  # a bad frame never stops the batch: it is reported by name
        return {**base, "status": "failed", "error": _one_line(exc, job.input), "seconds": time.perf_counter() - t0}


def _one_line(exc: BaseException, input_path: str, limit: int = 500) -> str:
    """The error of a failed frame as one line naming the input (at most ``limit`` characters)."""
    text = str(exc) if isinstance(exc, PolcamError) and exc.path else f"{input_path}: {exc}"
    if isinstance(exc, PolcamError) and exc.path and str(exc.path) != str(input_path):
        text = f"{input_path}: {exc}"              # e.g. an output file: name the frame too
    if not isinstance(exc, (PolcamError, OSError)):
        text = f"{input_path}: {type(exc).__name__}: {exc}"
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _unmark_finished(target: Path) -> None:
    """Remove ``target/meta.json`` before any product is replaced: a frame cut short has none."""
    meta = target / "meta.json"
    try:
        meta.unlink()
    except FileNotFoundError:
        return
    except OSError as exc:
        raise FrameWriteError(f"cannot replace the outputs: {exc.strerror or exc}", path=meta) from exc
    fsync_dir(target)


def _compute(job: FrameJob, opts: ProcessOptions, frame: Any, sep: ResolvedSeparation, dem: ResolvedDemosaic,
             parts: dict[str, Any], fingerprint: str, t0: float) -> dict[str, Any]:
    calibration = _calibration(opts.calibration, parts["calibration_sha256"]) if opts.calibration else None
    read_seconds = time.perf_counter() - t0
    result = run_frame(frame, calibration=calibration, demosaic=dem, resolution=opts.resolution,
                       stokes_products=("s0", "dolp", "aolp"), separate=True, method=sep)
    frame = result.frame
    timings: dict[str, float] = {"read": read_seconds + result.timings["calibrate"],
                                 **{k: v for k, v in result.timings.items() if k != "calibrate"}}
    source = os.path.abspath(job.input)  # meta.json names the raw frame from wherever it is read
    file_meta = {"input": source, "method": parts["method"], "layout": str(frame.layout),
                 "fingerprint": fingerprint, "polcam_version": __version__}
    assert result.separation is not None
    info = {k: v for k, v in result.separation.info.items() if k not in ("residuals",)}
    meta = {
        "input": source,
        "input_sha256": parts["input_sha256"],
        "name": job.name,
        "outputs": [],                   # the file sink sets outputs, files and timings["write"]
        "files": {},
        "resolution": opts.resolution,
        "layout": str(frame.layout),
        "frame": _jsonable({k: v for k, v in frame.metadata.items() if k != "path"}),
        "bit_depth": frame.bit_depth,
        "black_level": frame.black_level,
        "white_level": frame.white_level,
        "calibration": opts.calibration,
        "calibration_sha256": parts["calibration_sha256"],
        "method": parts["method"],
        "method_options": parts["method_options"],
        "options_requested": _jsonable(asdict(opts)),
        "polcam_version": __version__,
        "shape": list(result.stack.shape),
        "product_shapes": {n: list(np.shape(result.products[n])) for n in OUTPUTS},
        "timings": timings,
        "separation_info": _jsonable(info),
        "fingerprint_parts": parts,
        "fingerprint": fingerprint,
    }
    products = {name: result.products[name] for name in OUTPUTS}
    files = ProductFiles(fmt=opts.format, unit=_UNIT, metadata=file_meta, guard=_exit_if_orphaned)
    files.log(0, Record(frame=frame, products=products, folder=Path(job.target), name=job.name, meta=meta))
    return meta


def _exit_if_orphaned() -> None:
    """In a worker whose run is gone (a rerun may own the folder now): end before writing anything."""
    if orphaned():
        os._exit(1)


_CALIBRATIONS: dict[tuple[str, str], Any] = {}


def _calibration(path: str, digest: str) -> Any:
    """The calibration in ``path``, loaded once per process (its per-cell matrices are cached on it)."""
    key = (str(Path(path).resolve()), digest)
    if key not in _CALIBRATIONS:
        _CALIBRATIONS.clear()
        _CALIBRATIONS[key] = load_calibration(path)
    return _CALIBRATIONS[key]




def run(jobs: Sequence[FrameJob], opts: ProcessOptions, *, workers: int = 1,
        scheduler: str | None = None, force: bool = False,
        on_result: Callable[[dict[str, Any]], None] | None = None,
        stop: Callable[[], bool] | None = None, abort: Callable[[], Any] | None = None,
        scheduler_timeout: float = 10.0, sinks: Sequence[Sink] = (),
        separations: Mapping[str, ResolvedSeparation] | None = None) -> list[dict[str, Any]]:
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
    abort
        Polled while frames run; when it returns true the frames in flight
        are cancelled (status ``"cancelled"``: their workers are killed, and
        they leave no ``meta.json``).  A string it returns is the cancelled
        frames' reason (``"stopped by SIGTERM"``).  In this process
        (``workers=1``) a :class:`KeyboardInterrupt` during a frame reports
        that frame cancelled to ``on_result`` and propagates.
    scheduler_timeout
        Seconds to wait for a Dask scheduler given by address.
    sinks
        Each finished frame (status "done" or "skipped") is logged to these
        (:class:`polcam.sinks.base.Sink`, e.g.
        :class:`polcam.sinks.recording.RecordingSink`) as a
        :class:`polcam.sinks.base.Record` with its ``folder`` and ``name``, at
        its index in ``jobs``, in completion order, after ``on_result``.  They are closed when the run ends, however
        it ends.
    separations
        The run's separation per input form, from :func:`check_run`; None: resolved here (a
        method or options :func:`check_run` refuses then fail each frame, with the reason).

    Returns
    -------
    list of dict
        One per frame started: ``status`` "done", "skipped", "failed" (with
        ``error``) or "cancelled" (with ``error``: why).  Frames never started
        (after ``stop``) have none.

    Raises
    ------
    PolcamError
        The Dask scheduler cannot be reached within ``scheduler_timeout``.
    """
    results: list[dict[str, Any]] = []
    fan = FanOut(sinks)
    where = {job.name: (i, Path(job.target)) for i, job in enumerate(jobs)}

    def done(r: dict[str, Any]) -> None:
        results.append(r)
        if on_result:
            on_result(r)
        if fan.sinks and r["status"] in ("done", "skipped"):
            index, folder = where[r["name"]]
            fan.log(index, Record(folder=folder, name=r["name"]))

    with fan:
        _run(jobs, opts, workers, scheduler, force, done, stop, abort, scheduler_timeout, separations)
    return results


def _run(jobs: Sequence[FrameJob], opts: ProcessOptions, workers: int, scheduler: Any, force: bool,
         done: Callable[[dict[str, Any]], None], stop: Callable[[], bool] | None,
         abort: Callable[[], Any] | None, scheduler_timeout: float,
         separations: Mapping[str, ResolvedSeparation] | None) -> None:
    stop = stop or (lambda: False)
    abort = abort or (lambda: False)
    seps = dict(separations) if separations is not None else _separations(opts, jobs)
    if scheduler is not None:
        _run_dask(jobs, opts, scheduler, force, done, stop, abort, scheduler_timeout, seps)
    elif workers <= 1:
        for job in jobs:
            if stop() or abort():
                break
            try:
                r = _process_frame(job, opts, force=force, separations=seps, in_pool=False)
            except KeyboardInterrupt:  # reported, then passed on: the caller decides what it means
                done(_cancelled(job, _stopped(abort)))
                raise
            done(r)
    else:
        def lost(job: FrameJob, why: Any) -> None:
            if abort():
                done(_cancelled(job, _stopped(abort)))
            elif why.signal in (signal.SIGTERM, signal.SIGINT):   # the signal reached the worker first
                done(_cancelled(job, f"cancelled: {why.reason}"))
            else:
                done({"input": job.input, "name": job.name, "status": "failed", "seconds": None,
                      "error": f"{job.input}: {why.reason}"})

        run_jobs(functools.partial(_frame_task, opts=opts, force=force, separations=seps), jobs, workers,
                 on_result=lambda job, r: done(r), on_lost=lost, stop=stop, abort=abort,
                 on_cancel=lambda job: done(_cancelled(job, _stopped(abort))),
                 preload=("polcam.process",))


def _separations(opts: ProcessOptions, jobs: Sequence[FrameJob]) -> dict[str, ResolvedSeparation]:
    """:func:`check_run`'s separations, or none where it refuses the run (each frame then fails with the reason)."""
    try:
        return check_run(opts, jobs)
    except (PolcamError, ValueError):
        return {}


def _frame_task(job: FrameJob, *, opts: ProcessOptions, force: bool,
                separations: Mapping[str, ResolvedSeparation]) -> dict[str, Any]:
    """One frame in a worker of the local pool."""
    return _process_frame(job, opts, force=force, separations=separations, in_pool=True)


def _stopped(abort: Callable[[], Any]) -> str:
    """Why frames in progress were cancelled: what ``abort()`` returned, when it is a string."""
    why = abort()
    return f"cancelled: {why}" if isinstance(why, str) and why else "cancelled: the run was stopped"


def _cancelled(job: FrameJob, why: str) -> dict[str, Any]:
    return {"input": job.input, "name": job.name, "status": "cancelled", "seconds": None, "error": why}


def connect_scheduler(address: str, *, timeout: float = 10.0) -> Any:
    """A ``distributed.Client`` of the Dask scheduler at ``address``.

    Raises
    ------
    PolcamError
        Dask is not installed, or the scheduler does not answer within ``timeout`` seconds (one
        line naming the address and the reason).
    """
    try:
        from distributed import Client
    except ImportError:
        raise PolcamError("--scheduler needs Dask: pip install 'polcam[dask]'") from None
    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise PolcamError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s "
                          f"({reason[:200]})") from None


def _run_dask(jobs: Sequence[FrameJob], opts: ProcessOptions, scheduler: Any, force: bool,
              done: Callable[[dict[str, Any]], None], stop: Callable[[], bool], abort: Callable[[], Any],
              timeout: float, separations: Mapping[str, ResolvedSeparation]) -> None:
    from distributed import Client, as_completed

    own = not isinstance(scheduler, Client)
    client = connect_scheduler(scheduler, timeout=timeout) if own else scheduler
    try:
        futures = {client.submit(process_frame, job, opts, force=force, separations=separations, pure=False,
                                 key=f"polcam-{job.name}-{i}"): job for i, job in enumerate(jobs)}
        pending = set(futures)
        for fut in as_completed(list(futures)):
            pending.discard(fut)
            if fut.status == "finished":
                done(fut.result())
            elif fut.status != "cancelled":
                job = futures[fut]
                exc = fut.exception() or RuntimeError(f"the Dask task ended as {fut.status}")
                done({"input": job.input, "name": job.name, "status": "failed", "seconds": None,
                      "error": _one_line(exc, job.input)})
            if stop() or abort():
                for f in pending:
                    f.cancel()
                    done(_cancelled(futures[f], _stopped(abort)))
                break
    finally:
        if own:
            client.close()
