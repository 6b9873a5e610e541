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
import multiprocessing
import os
import re
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polcam import __version__
from polcam.errors import PolcamError

__all__ = ["ProcessOptions", "FrameJob", "OUTPUTS", "plan", "process_frame", "run", "sha256_file"]

#: Products written per frame (plus meta.json).
OUTPUTS: tuple[str, ...] = ("diffuse", "specular", "s0", "dolp", "aolp")
FORMATS = {"exr": (".exr", None), "tiff": (".tif", "float32"), "tiff16": (".tif", "uint16")}
_UNIT = ("diffuse", "specular", "dolp")          # products in [0, 1]: uint16 in tiff16
_TEMP = re.compile(r"^\..+\.tmp(\.[A-Za-z0-9]+)?$")


@dataclass(frozen=True)
class ProcessOptions:
    """What determines a run's outputs (besides the input files)."""

    method: str | None = None            # None: tensor for colour, imin for mono
    method_options: dict[str, Any] = field(default_factory=dict)
    layout: str | None = None            # overrides the sidecar
    demosaic: str = "bilinear"
    resolution: str = "cell"
    format: str = "exr"
    calibration: str | None = None       # path of a calibration file


@dataclass(frozen=True)
class FrameJob:
    """One input frame and where its outputs go."""

    input: str
    target: str
    name: str


def sha256_file(path: str | os.PathLike[str]) -> str:
    """SHA-256 hex digest of a file, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


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
    from polcam.io import RAW_EXTENSIONS

    jobs: dict[str, FrameJob] = {}
    problems: list[dict[str, str]] = []
    for root in inputs:
        root = Path(root)
        if root.is_dir():
            it = root.rglob("*") if recursive else root.iterdir()
            files = sorted(f for f in it if f.is_file() and f.suffix.lower() in RAW_EXTENSIONS
                           and not f.name.startswith("."))
            for f in files:
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
    from polcam.errors import LayoutError
    from polcam.io import read_frame

    input_hash = sha256_file(job.input)
    frame = read_frame(job.input, layout=opts.layout)
    if frame.layout is None:
        raise LayoutError("no layout: the file has no sidecar saying it; give --layout "
                          "(imx250mzr, imx250myr, mono:A,B,C,D or color:A,B,C,D:BAYER)", path=job.input)
    calibration_hash = sha256_file(opts.calibration) if opts.calibration else None
    from polcam.separation import default_method

    method = opts.method or default_method("stack" if frame.layout.is_color else "mono-stack")
    # without --method, the options are the colour default's (tensor): imin takes none
    method_options = dict(opts.method_options) if (opts.method or frame.layout.is_color) else {}
    parts = {
        "input_sha256": input_hash,
        "layout": str(frame.layout),
        "black_level": float(frame.black_level),
        "white_level": float(frame.white_level),
        "calibration_sha256": calibration_hash,
        "demosaic": opts.demosaic,
        "resolution": opts.resolution,
        "method": method,
        "method_options": _jsonable(method_options),
        "format": opts.format,
        "polcam_version": __version__,
    }
    return frame, method, method_options, parts, hashlib.sha256(_canonical(parts).encode()).hexdigest()


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
    from polcam import stokes as st
    from polcam.demosaicing import demosaic
    from polcam.errors import FrameWriteError
    from polcam.io import write_image
    from polcam.io.atomic import atomic_write
    from polcam.separation import method_spec, separate

    timings: dict[str, float] = {}
    if opts.calibration:
        frame = _apply_calibration(frame, opts.calibration, parts["calibration_sha256"])
    timings["read"] = time.perf_counter() - t0
    t = time.perf_counter()
    stack = demosaic(frame, method=opts.demosaic, resolution=opts.resolution)
    timings["demosaic"] = time.perf_counter() - t
    t = time.perf_counter()
    s = st.stokes(stack)
    products: dict[str, np.ndarray] = {"s0": s.s0, "dolp": st.dolp(s), "aolp": st.aolp(s)}
    timings["stokes"] = time.perf_counter() - t
    t = time.perf_counter()
    run_options = dict(method_options)
    if _IN_POOL and "workers" in (method_spec(method).options or ()) and "workers" not in run_options:
        run_options["workers"] = 1  # the frames are the parallel part here (the answer does not change)
    res = separate(np.clip(stack, 0.0, 1.0), method=method, **run_options)
    timings["separate"] = time.perf_counter() - t
    products["diffuse"], products["specular"] = res.diffuse, res.specular

    target = Path(job.target)
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FrameWriteError(f"cannot create the output folder: {exc.strerror}", path=target) from exc
    ext, dtype = FORMATS[opts.format]
    t = time.perf_counter()
    file_meta = {"input": job.input, "method": method, "layout": str(frame.layout),
                 "fingerprint": fingerprint, "polcam_version": __version__}
    for name in OUTPUTS:
        arr = products[name]
        d = ("uint16" if name in _UNIT else "float32") if dtype == "uint16" else dtype
        if d == "uint16" and name == "specular":
            arr = np.clip(arr, 0.0, 1.0)
        write_image(target / f"{name}{ext}", arr, metadata={**file_meta, "product": name}, dtype=d)
    timings["write"] = time.perf_counter() - t
    info = {k: v for k, v in res.info.items() if k not in ("residuals",)}
    meta = {
        "input": job.input,
        "input_sha256": parts["input_sha256"],
        "name": job.name,
        "outputs": [f"{p}{ext}" for p in OUTPUTS],
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
        "shape": list(stack.shape),
        "timings": timings,
        "separation_info": _jsonable(info),
        "fingerprint_parts": parts,
        "fingerprint": fingerprint,
    }
    with atomic_write(target / "meta.json", "w") as fh:
        json.dump(meta, fh, indent=2)
    return meta


_CALIBRATIONS: dict[tuple[str, str], Any] = {}


def _apply_calibration(frame: Any, path: str, digest: str) -> Any:
    """Dark, flat, defects and the polarimetric correction on the mosaic (polcam.calibration).

    The calibration is loaded once per process (its per-cell matrices are cached on it).
    """
    from polcam.calibration import apply_calibration, load_calibration

    key = (str(Path(path).resolve()), digest)
    if key not in _CALIBRATIONS:
        _CALIBRATIONS.clear()
        _CALIBRATIONS[key] = load_calibration(path)
    return apply_calibration(frame, _CALIBRATIONS[key])


class RunRecording:
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
    global _IN_POOL
    _IN_POOL = True
    # one BLAS/OpenMP thread per worker process: no oversubscription, thread-count-independent results
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"


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
        # spawn, not fork: forking a process whose libraries run threads (BLAS, OpenImageIO)
        # can deadlock the children
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker) as pool:
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


def default_workers() -> int:
    """Number of cores available to this process."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


if __name__ == "__main__":  # pragma: no cover
    from polcam.cli import main

    sys.exit(main(["process", *sys.argv[1:]]))
