"""``polcam process``: diffuse/specular layers and Stokes maps of folders of raw frames (:mod:`polcam.process`)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from polcam.commands._args import add_max_pixels_argument, default_methods_text, parse_options, positive_int
from polcam.commands._checks import check_run_options
from polcam.errors import PolcamError
from polcam.sinks.files import FORMATS

__all__ = ["add_parser", "cmd_process"]


def cmd_process(args: argparse.Namespace) -> int:
    import signal

    from polcam import process as proc
    from polcam.parallel import default_workers

    opts = proc.ProcessOptions(
        method=args.method, method_options=parse_options(args.option),
        layout=args.layout, demosaic=args.demosaic, resolution=args.resolution, format=args.format,
        calibration=str(args.calibration) if args.calibration else None, max_pixels=args.max_pixels)
    # before any work (exit 2, nothing created): a bad value would fail every frame
    check_run_options(layout=args.layout, demosaic=args.demosaic, resolution=args.resolution, fmt=args.format)
    if args.calibration is not None and not args.calibration.is_file():
        print(f"error: calibration file {args.calibration} not found", file=sys.stderr)
        return 2
    jobs, problems = proc.plan(args.inputs, args.out, recursive=args.recursive)
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
    proc.check_run(opts, jobs)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"error: cannot create {args.out}: {exc.strerror}", file=sys.stderr)
        return 2
    interrupted = False

    def on_signal(signum: int, _frame: Any) -> None:
        nonlocal interrupted
        interrupted = True

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    sink = None
    if args.rerun is not None:  # RERUN SINK call site (process --rerun)
        sink = proc.RunRecording(args.rerun, [j.name for j in jobs])
    t0 = time.perf_counter()
    progress = None
    task = None
    if not (args.quiet or args.json):
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        progress = Progress(TextColumn("[bold]process"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("{task.fields[rate]}"), TimeElapsedColumn(),
                            TextColumn("left"), TimeRemainingColumn(), transient=False,
                            console=__import__("rich.console", fromlist=["Console"]).Console(stderr=True))
        task = progress.add_task("frames", total=len(jobs), rate="")
        progress.start()
    counter = {"n": 0}

    def on_result(r: dict[str, Any]) -> None:
        counter["n"] += 1
        if r["status"] == "failed":
            msg = f"error: {r['error']}"
            if progress is not None:
                progress.console.print(msg)
            elif not args.json:
                print(msg, file=sys.stderr)
        if args.json:
            print(json.dumps({"event": "frame", **r}), flush=True)
        if sink is not None and r["status"] in ("done", "skipped"):  # RERUN SINK call site
            sink.log_frame(Path(args.out) / r["name"], FORMATS[opts.format][0], r["name"])
        if progress is not None and task is not None:
            elapsed = time.perf_counter() - t0
            progress.update(task, advance=1, rate=f"{counter['n'] / max(elapsed, 1e-9) * 60:.1f} frames/min")

    try:
        workers = max(1, min(args.workers or default_workers(), len(jobs)))
        results = proc.run(jobs, opts, workers=workers,
                           scheduler=args.scheduler, force=args.force, on_result=on_result,
                           stop=lambda: interrupted)
    finally:
        if progress is not None:
            progress.stop()
        for sig, handler in old.items():
            signal.signal(sig, handler)
        if sink is not None:
            sink.close()
    summary = proc.summarize(results, problems, opts=opts, seconds=time.perf_counter() - t0,
                             interrupted=interrupted)
    try:
        path: Path | str = proc.write_summary(args.out, summary)
    except PolcamError as exc:  # e.g. the disk filled up: the frames written so far are whole
        print(f"error: {exc}", file=sys.stderr)
        path = "(summary.json not written)"
        summary["failed"].append({"input": str(args.out / "summary.json"), "error": str(exc)})
    line = (f"{summary['done']} done, {summary['skipped']} up to date, {len(summary['failed'])} failed"
            f"{', interrupted' if interrupted else ''} in {summary['seconds']:.1f} s -> {path}")
    if args.json:
        print(json.dumps({"event": "summary", **{k: v for k, v in summary.items() if k != "results"}}))
    elif not args.quiet or summary["failed"]:
        print(line)
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
                    "status is then 1.")
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
    pr.add_argument("--workers", type=positive_int, help="local worker processes (default: the number of cores; "
                                                 "one BLAS thread each)")
    pr.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask distributed cluster "
                                                           "(tcp://host:8786; needs polcam[dask])")
    pr.add_argument("--recursive", action="store_true", help="descend into sub-folders (output names "
                                                            "keep the relative path)")
    pr.add_argument("--force", action="store_true", help="redo frames whose outputs are up to date")
    add_max_pixels_argument(pr)
    pr.add_argument("--quiet", action="store_true", help="no progress bar; only errors and failures")
    pr.add_argument("--json", action="store_true", help="machine-readable JSON lines on stdout "
                                                        "(one per frame, then a summary)")
    pr.set_defaults(func=cmd_process)
    return pr
