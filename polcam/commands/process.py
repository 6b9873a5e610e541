"""``polcam process``: diffuse/specular layers and Stokes maps of folders of raw frames (:mod:`polcam.process`)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from polcam import process as proc
from polcam._memory import auto_workers
from polcam.calibration import load_calibration
from polcam.commands._args import add_max_pixels_argument, default_methods_text, parse_options, positive_int
from polcam.commands._checks import check_run_options
from polcam.errors import PolcamError
from polcam.footprint import default_max_memory, output_bytes, parse_size
from polcam.io.readers import declared_size
from polcam.mosaic import parse_layout
from polcam.outdir import OutputLock, SummaryReserve, check_output, summarize, write_summary
from polcam.parallel import default_workers
from polcam.process import layout_hint
from polcam.sinks.files import FORMATS
from polcam.sinks.recording import RecordingSink

__all__ = ["add_parser", "cmd_process"]


def cmd_process(args: argparse.Namespace) -> int:
    try:
        max_memory = default_max_memory() if args.max_memory is None else parse_size(args.max_memory)
    except ValueError as exc:
        raise PolcamError(f"--max-memory: {exc}") from None
    opts = proc.ProcessOptions(
        method=args.method, method_options=parse_options(args.option),
        layout=args.layout, demosaic=args.demosaic, resolution=args.resolution, format=args.format,
        calibration=str(args.calibration) if args.calibration else None, max_pixels=args.max_pixels,
        max_memory=max_memory or None)
    # before any work (exit 2, nothing created): a bad value would fail every frame
    check_run_options(layout=args.layout, demosaic=args.demosaic, resolution=args.resolution, fmt=args.format)
    if args.calibration is not None and not args.calibration.is_file():
        print(f"error: calibration file {args.calibration} not found", file=sys.stderr)
        return 2
    skipped: list[tuple[Path, str]] = []
    jobs, problems = proc.plan(args.inputs, args.out, recursive=args.recursive, skipped=skipped)
    for path, why in skipped:
        print(f"note: {path}: {why}; skipped", file=sys.stderr)
    missing = [p for p in problems if p["error"] == "no such file or folder"]
    if missing:
        for p in missing:
            print(f"error: {p['input']}: no such file or folder", file=sys.stderr)
        return 2
    for p in problems:
        print(f"error: {p['input']}: {p['error']}", file=sys.stderr)
    if not jobs and not problems:
        print(f"error: no raw frames found in {', '.join(map(str, args.inputs))}", file=sys.stderr)
        return 2
    separations = proc.check_run(opts, jobs)     # the run's separation per input form, resolved once
    sizes = _declared_sizes(jobs)
    if args.calibration is not None:
        _check_calibration(args.calibration, sizes)
    client = None
    if args.scheduler is not None:  # before anything is created: an unreachable one is exit 2 at once
        client = proc.connect_scheduler(args.scheduler, timeout=args.scheduler_timeout)
    try:
        check_output(args.out, frame_bytes=_output_bytes(opts, jobs, sizes))
        return _locked(args, opts, separations, jobs, problems, client, default_workers)
    finally:
        if client is not None:
            client.close()


def _locked(args: argparse.Namespace, opts: Any, separations: dict[str, Any], jobs: list[Any],
            problems: list[dict[str, str]], client: Any, default_workers: Any) -> int:
    with OutputLock(args.out) as lock:
        if lock.taken_over:
            print(f"note: {args.out}: took over the lock left by PID {lock.taken_over.get('pid')} on "
                  f"{lock.taken_over.get('host')} (no longer running)", file=sys.stderr)
        reserve = SummaryReserve(args.out, len(jobs) + len(problems))
        try:
            return _run(args, opts, separations, jobs, problems, reserve, client, default_workers)
        finally:
            reserve.release()


def _declared_sizes(jobs: Sequence[Any], limit: int = 64) -> dict[str, tuple[int, int]]:
    """Sizes the first ``limit`` frames declare (headers and sidecars only), by input path."""
    out = {}
    for job in jobs[:limit]:
        size = declared_size(job.input)
        if size is not None:
            out[job.input] = size
    return out


def _check_calibration(path: Path, sizes: dict[str, tuple[int, int]]) -> None:
    """Load the calibration once; refuse it (exit 2) when it is corrupt or fits none of the frames."""
    cal = load_calibration(path)          # CalibrationError (a PolcamError): exit 2, before any work
    if sizes and all((h, w) != tuple(cal.shape) for w, h in sizes.values()):
        seen = sorted({f"{w}x{h}" for w, h in sizes.values()})
        raise PolcamError(f"calibration {path} is for {cal.width}x{cal.height} frames (width x height); "
                          f"the frames are {', '.join(seen[:5])}: calibrate at the frames' size and ROI")


def _output_bytes(opts: Any, jobs: Sequence[Any], sizes: dict[str, tuple[int, int]]) -> int:
    for job in jobs:
        if job.input in sizes:
            lay = parse_layout(opts.layout) if opts.layout else layout_hint(job.input)
            return output_bytes(*sizes[job.input], colour=lay is None or lay.is_color, resolution=opts.resolution)
    return 0


def _run(args: argparse.Namespace, opts: Any, separations: dict[str, Any], jobs: list[Any],
         problems: list[dict[str, str]], reserve: SummaryReserve, client: Any, default_workers: Any) -> int:
    import signal

    workers = max(1, min(args.workers or auto_workers(opts.method, opts.resolution, default_workers()), len(jobs)))
    in_process = workers == 1 and args.scheduler is None
    state: dict[str, Any] = {"stop": False, "abort": "", "signals": [], "computing": False}

    def on_signal(signum: int, _frame: Any) -> None:
        state["signals"].append(signum)
        if state["signals"] == [signal.SIGINT]:   # first Ctrl-C: finish what runs, start nothing new
            state["stop"] = True
            print("\nstopping after the frames in progress (Ctrl-C again to stop now)", file=sys.stderr, flush=True)
            return
        state["stop"] = True                      # a second Ctrl-C, or SIGTERM: stop now
        state["abort"] = "stopped by SIGTERM" if signum == signal.SIGTERM else "stopped by a second Ctrl-C"
        if in_process and state["computing"]:
            state["computing"] = False
            raise KeyboardInterrupt

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    sinks: list[Any] = []
    t0 = time.perf_counter()
    progress = None
    task = None
    results: list[dict[str, Any]] = []
    try:
        if not (args.quiet or args.json):
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            progress = Progress(TextColumn("[bold]process"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("{task.fields[rate]}"), TimeElapsedColumn(),
                                TextColumn("left"), TimeRemainingColumn(), transient=False,
                                console=Console(stderr=True))
            task = progress.add_task("frames", total=len(jobs), rate="")
            progress.start()

        def on_result(r: dict[str, Any]) -> None:
            state["computing"] = False
            results.append(r)
            if r["status"] == "failed":
                msg = f"error: {r['error']}"
                if progress is not None:
                    progress.console.print(msg, markup=False, highlight=False)
                elif not args.json:
                    print(msg, file=sys.stderr)
            if args.json:
                print(json.dumps({"event": "frame", **r}), flush=True)
            if progress is not None and task is not None:
                elapsed = time.perf_counter() - t0
                progress.update(task, advance=1,
                                rate=f"{len(results) / max(elapsed, 1e-9) * 60:.1f} frames/min")
            state["computing"] = in_process and not state["stop"]

        if args.rerun is not None:
            sinks.append(RecordingSink(args.rerun))
        state["computing"] = in_process
        try:  # run() closes the sinks
            proc.run(jobs, opts, workers=workers, scheduler=client, force=args.force, on_result=on_result,
                     stop=lambda: state["stop"], abort=lambda: state["abort"], sinks=sinks,
                     separations=separations)
        except KeyboardInterrupt:  # raised by on_signal to stop now (run() reported the frame cancelled)
            pass
    finally:
        state["computing"] = False
        if progress is not None:
            progress.stop()
        interrupted = bool(state["signals"])
        summary = summarize(results, problems, opts=opts, seconds=time.perf_counter() - t0,
                                 interrupted=interrupted, planned=jobs)
        reserve.release()
        try:
            path: Path | str = write_summary(args.out, summary)
        except PolcamError as exc:  # the counts go to stderr instead
            print(f"error: {exc}", file=sys.stderr)
            path = "(summary.json not written: " + json.dumps(
                {k: summary[k] if not isinstance(summary[k], list) else len(summary[k])
                 for k in ("frames", "done", "skipped", "failed", "cancelled", "not_started")}) + ")"
            summary["failed"].append({"input": str(args.out / "summary.json"), "error": str(exc)})
        for sig, handler in old.items():
            signal.signal(sig, handler)
    stopped = ""
    if interrupted:
        name = "SIGTERM" if signal.SIGTERM in state["signals"] else "Ctrl-C"
        stopped = (f", stopped by {name}: {len(summary['cancelled'])} cancelled, "
                   f"{len(summary['not_started'])} not started")
    line = (f"{summary['done']} done, {summary['skipped']} up to date, {len(summary['failed'])} failed"
            f"{stopped} in {summary['seconds']:.1f} s -> {path}")
    if args.json:
        print(json.dumps({"event": "summary", **{k: v for k, v in summary.items() if k != "results"}}))
    elif not args.quiet or summary["failed"] or interrupted:
        print(line)
    if signal.SIGTERM in state["signals"]:
        return 143
    if interrupted:
        return 130
    return 1 if summary["failed"] else 0


def add_parser(sub: Any, demosaic_methods: Sequence[str]) -> argparse.ArgumentParser:
    """Add ``process`` to the sub-parsers."""
    pr = sub.add_parser(
        "process", help="diffuse/specular layers and Stokes maps of folders of raw frames",
        description="Process raw frames (files or folders; every format polcam reads): per frame "
                    "OUT/<stem>/ with diffuse, specular, s0, dolp (0..1), aolp (radians, [0, pi), from "
                    "the image x axis) and meta.json (input SHA-256, layout, calibration and its hash, "
                    "method and options, version, timings, solver info, fingerprint); OUT/summary.json "
                    "for the run. Resumable: frames whose outputs match their input and options are "
                    "skipped (--force redoes them). Bad inputs are reported and skipped; the exit "
                    "status is then 1. Exit 2: refused before any work (output folder locked by another "
                    "run, not writable or full, bad calibration, unreachable scheduler); 130: stopped by "
                    "Ctrl-C (the first lets the frames in progress finish, a second stops now); 143: "
                    "stopped by SIGTERM. docs/guide/faults.md lists every fault.")
    pr.add_argument("inputs", nargs="+", type=Path, help="raw frame files or folders")
    pr.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    pr.add_argument("--layout", help="sensor layout; overrides the sidecar (imx250mzr, imx250myr, "
                                     "mono:A,B,C,D, color:A,B,C,D:BAYER)")
    pr.add_argument("--method", help=f"separation method (default: {default_methods_text()}); one of "
                                     "polcam.METHODS")
    pr.add_argument("--option", action="append", metavar="KEY=VALUE",
                    help="a separation option, VALUE as JSON (repeatable), e.g. --option max_iter=50")
    pr.add_argument("--demosaic", choices=demosaic_methods,
                    help="demosaicing method (default: the best for the frame's layout, "
                         "polcam.demosaicing.default_method)")
    pr.add_argument("--resolution", default="cell", choices=("cell", "full"),
                    help="cell: one pixel per 2x2 polarizer cell (default; 1224x1024 for a 5 MP sensor); "
                         "full: one per sensor pixel")
    pr.add_argument("--format", default="exr", choices=tuple(FORMATS),
                    help="exr (float32, default), tiff (float32) or tiff16 (uint16 for the [0, 1] "
                         "products; s0 and aolp stay float32)")
    pr.add_argument("--calibration", type=Path, help="calibration file (polcam calibrate)")
    pr.add_argument("--rerun", type=Path, metavar="FILE.rrd", help="also write the run as a Rerun "
                                                                    "recording, one time step per frame")
    pr.add_argument("--workers", type=positive_int, help="local worker processes (default: the number of cores, "
                                                 "fewer where the available memory holds fewer workers "
                                                 "of the method's measured peak; one BLAS thread each)")
    pr.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask distributed cluster "
                                                           "(tcp://host:8786; needs polcam[dask])")
    pr.add_argument("--scheduler-timeout", type=float, default=5.0, metavar="S",
                    help="seconds to wait for the Dask scheduler before giving up (default 5)")
    pr.add_argument("--recursive", action="store_true", help="descend into sub-folders (output names "
                                                            "keep the relative path)")
    pr.add_argument("--force", action="store_true", help="redo frames whose outputs are up to date")
    add_max_pixels_argument(pr)
    pr.add_argument("--max-memory", metavar="SIZE",
                    help="largest estimated memory of one frame (e.g. 8G; default three quarters of the "
                         "physical memory; 0: no limit): a frame whose declared size needs more is refused "
                         "unread (docs/guide/faults.md)")
    pr.add_argument("--quiet", action="store_true", help="no progress bar; only errors and failures")
    pr.add_argument("--json", action="store_true", help="machine-readable JSON lines on stdout "
                                                        "(one per frame, then a summary)")
    pr.set_defaults(func=cmd_process)
    return pr
