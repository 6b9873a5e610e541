"""``polcam capture``: record a camera (or ``replay:DIR``) losslessly with a live Rerun view.

The command line of :mod:`polcam.acquisition`: open and configure the camera
(:mod:`polcam.commands._args`), turn SIGINT / SIGTERM into a clean stop (a
second signal abandons the frames still queued for writing), run
:func:`polcam.acquisition.run_capture`, print the summary.

Exit statuses (docs/guide/faults.md): 0 the capture ran to its stop condition
(frames, duration, end of a replay, a signal); 1 it ended with an error (no
frame for ``--timeout`` seconds, live processing failed); 2 refused before
the first frame (bad options, an output folder that cannot be written, a
calibration that does not fit); 3 the camera cannot be opened; 4 the camera
disconnected during the capture; 5 writing a frame failed.  With 1, 4 and 5
the summary is written (or its counts printed) as after a clean stop.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from polcam.acquisition import SAVE_FORMATS, StopRequest, run_capture
from polcam.acquisition.run import ON_WRITE_ERROR
from polcam.acquisition.saving import check_writable
from polcam.calibration import load_calibration
from polcam.camera import open_camera
from polcam.camera.base import CameraSettingError
from polcam.commands._args import (
    CommandParser,
    add_camera_arguments,
    camera_options,
    configure_camera,
    parse_options,
    run_command,
)

__all__ = ["EXIT_DISCONNECTED", "EXIT_WRITE_FAILED", "add_capture_parser", "cmd_capture", "main"]

#: Exit status of a capture the camera's disconnection ended.
EXIT_DISCONNECTED = 4
#: Exit status of a capture in which a frame could not be written.
EXIT_WRITE_FAILED = 5


def add_capture_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``capture`` to an ``argparse`` sub-parser set; returns the new parser."""
    c = subparsers.add_parser(
        "capture",
        help="record a camera (or replay:DIR) losslessly with a live Rerun view",
        description="Capture raw frames from a GenICam camera through Aravis (`polcam devices` lists "
                    "them; Fake_1 is Aravis' simulated camera) or from a folder of raw frames "
                    "(--device replay:DIR). Every good frame is saved losslessly with its JSON sidecar, "
                    "atomically; the newest frame is processed live (S0, DoLP, AoLP, Imin at the "
                    "polarizer-cell resolution, and the chosen separation) and shown in Rerun; with "
                    "--calibration the live view is computed from the corrected mosaic while the saved "
                    "frames stay raw. Ctrl-C or SIGTERM stops cleanly and writes OUT/summary.json. "
                    "Exit status: 0 done, 1 ended with an error, 2 refused before the first frame (e.g. an "
                    "output folder that cannot be written), 3 camera unavailable, 4 camera disconnected, "
                    "5 a frame could not be written; the summary is written in every case but 2 and 3.",
    )
    c.add_argument("--device", required=True, help="camera id, serial or address, or replay:DIR")
    stop = c.add_mutually_exclusive_group()
    stop.add_argument("--frames", type=int, help="stop after N good frames")
    stop.add_argument("--duration", type=float, help="stop after S seconds")
    c.add_argument("--out", type=Path, help="output folder (default captures/<date-time>)")
    c.add_argument("--no-save", action="store_true", help="live view only: save nothing")
    c.add_argument("--format", default="raw", choices=tuple(SAVE_FORMATS),
                   help="frame files: raw (the camera's bytes, default), tiff (uncompressed), npy, "
                        "png (lossless, slow: ~90 ms a 5 MP frame)")
    c.add_argument("--append", action="store_true",
                   help="allow an --out folder that holds frames already (numbering continues; the earlier "
                        "summary.json is kept and this capture's goes to summary-2.json, summary-3.json, ...)")
    c.add_argument("--on-write-error", default="stop", choices=ON_WRITE_ERROR,
                   help="when a frame cannot be written (disk full, folder gone read-only): stop the capture "
                        "at once (default), or continue-live: stop saving and keep the live view going; "
                        "either way the folder and the reason are printed and the capture exits with 5")
    add_camera_arguments(c)
    c.add_argument("--calibration", type=Path, metavar="FILE",
                   help="calibration file (polcam calibrate) of this camera at these settings: the first "
                        "frame is checked against it, the live view (S0, DoLP, AoLP, layers) uses the "
                        "corrected mosaic; saved frames stay raw. summary.json records the file and its SHA-256")
    c.add_argument("--method", "--separate", dest="separate", default="default", metavar="METHOD",
                   help="separation method for the live layers, or none; default: the registry's default "
                        "for the sensor (polcam.separation.default_method, as process uses). imin runs on "
                        "every frame; other methods run on the newest frame whenever the last run is done")
    c.add_argument("--option", "--separate-option", dest="separate_option", action="append",
                   metavar="KEY=VALUE",
                   help="an option of the separation method, VALUE as JSON (repeatable), e.g. "
                        "--option device=cuda for the tensor method on a GPU")
    c.add_argument("--illuminant-each-frame", action="store_true",
                   help="re-estimate the illuminant on every separated frame; by default a method that "
                        "estimates it (polarized-residual, tensor) estimates it on the first one and keeps "
                        "it (summary.json: separation_illuminant_held), unless --option "
                        "illuminant=[R, G, B] gives it")
    c.add_argument("--rerun", help="live view: spawn (a viewer; needs a display), serve (web viewer), "
                                   "or FILE.rrd")
    c.add_argument("--port", type=int, default=9090,
                   help="--rerun serve: port of the web viewer (its data use port + 1; default 9090)")
    c.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                   help="--rerun serve: address to listen on (default 127.0.0.1, this machine only; "
                        "0.0.0.0: anyone on this machine's networks can watch)")
    c.add_argument("--raw-every", type=int, default=10,
                   help="log the full-resolution raw mosaic to Rerun every N processed frames (default 10)")
    c.add_argument("--view-scale", type=float, default=0.5,
                   help="size of the maps in the Rerun view relative to the polarizer-cell resolution "
                        "(default 0.5: 612x512 for a 5 MP sensor; 1 for full cell resolution)")
    c.add_argument("--live-workers", type=int, default=2, help="live processing threads (default 2)")
    c.add_argument("--save-workers", type=int, default=4,
                   help="writer threads (default 4: writes and fsync overlap)")
    c.add_argument("--quiet", action="store_true",
                   help="no progress lines (about one a second on stderr); errors and the summary still print")
    c.set_defaults(func=cmd_capture)
    return c


def _print_summary(summary: dict[str, Any]) -> None:
    keys = ("frames_good", "frames_received", "frames_incomplete", "frames_dropped", "frames_saved",
            "frames_save_failed", "frames_unsaved", "frames_processed", "frames_skipped", "separations")
    line = ", ".join(f"{k[7:] if k.startswith('frames_') else k} {summary[k]}" for k in keys)
    print(f"capture stopped ({summary['stop_reason']}) after {summary['duration_s']:.1f} s: {line}; "
          f"{summary['fps']:.1f} fps received, {summary['fps_processed']:.1f} fps processed")
    if summary.get("maps_frames") or summary.get("separation"):
        each = summary.get("separation_seconds_mean")
        layers = (f", layers {summary['layers_fps']:.2f} fps ({summary['layers_frames']} frames, "
                  f"{summary['separation']}{f', {each:.2f} s each' if each else ''})"
                  if summary.get("separation") else "")
        print(f"live rates: maps {summary['maps_fps']:.1f} fps ({summary['maps_frames']} frames){layers}")
    if summary.get("out"):
        where = summary.get("summary_file")
        if where and Path(where).parent == Path(summary["out"]):
            print(f"frames and {Path(where).name} in {summary['out']}")
        else:
            print(f"frames in {summary['out']}; {summary.get('summary_error') or 'summary not written there'}",
                  file=sys.stderr)
            print(f"summary written to {where}" if where else "summary not written anywhere: the counts are above",
                  file=sys.stderr)
    if summary.get("error"):
        print(f"error: {summary['error']}", file=sys.stderr)


def exit_status(summary: dict[str, Any]) -> int:
    """The exit status of a capture that ran (see the module docstring)."""
    if str(summary.get("stop_reason", "")).startswith("camera disconnected"):
        return EXIT_DISCONNECTED
    if summary.get("write_error") or summary.get("frames_save_failed"):
        return EXIT_WRITE_FAILED
    return 1 if summary.get("error") else 0


def cmd_capture(args: argparse.Namespace) -> int:
    """``polcam capture``: open, configure, capture, summarise.  Returns the exit status."""
    if args.frames is not None and args.frames <= 0:
        raise CameraSettingError(f"--frames {args.frames}: expected a positive number")
    if args.duration is not None and args.duration <= 0:
        raise CameraSettingError(f"--duration {args.duration}: expected a positive number of seconds")
    separate = None if str(args.separate).lower() == "none" else args.separate
    separate_options = parse_options(args.separate_option, flag="--option")
    out: Path | None = None
    if not args.no_save:
        out = args.out or Path("captures") / time.strftime("%Y%m%d-%H%M%S")
    trigger = args.trigger
    stop = StopRequest()
    abort = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        if stop.is_set():
            abort.set()  # a second signal: do not wait for the frames still queued for writing
        stop.request(f"signal {signal.Signals(signum).name}")

    calibration = None
    if args.calibration is not None:  # loaded once, before the camera is touched

        calibration = load_calibration(args.calibration)
    created = out is not None and not out.exists()
    if out is not None:  # before the camera is touched: a folder that cannot take frames is refused now

        check_writable(out)
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with open_camera(args.device, **camera_options(args)) as cam:
            settings = configure_camera(cam, args, quiet=args.quiet)
            if not args.quiet:
                fmt = settings.get("pixel_format") or "pixel format of the files"
                lay = settings.get("layout") or "unknown (give --layout for the live view)"
                print(f"capturing from {cam.camera_id}: {fmt}, layout {lay} -> {out if out else '(not saved)'}")
                if calibration is not None:
                    print(f"live view calibrated with {args.calibration} "
                          f"({', '.join(calibration.applied_stages) or 'no stages'}); frames saved raw")

            def progress(p: dict[str, Any]) -> None:
                if "message" in p:  # errors and notices print even with --quiet
                    print(p["message"], file=sys.stderr, flush=True)
                    return
                if args.quiet:
                    return
                print(f"  {p['received']} frames, {p['fps']:.0f} fps, saved {p['saved']}, "
                      f"processed {p['processed']}, dropped {p['dropped']}, incomplete {p['incomplete']}",
                      file=sys.stderr, flush=True)

            summary = run_capture(
                cam, out=out, frames=args.frames, duration=args.duration, save_format=args.format,
                separate=separate, separate_options=separate_options, rerun=args.rerun, stop=stop,
                abort=abort, idle_timeout=args.timeout,
                software_trigger=trigger == "software", append=args.append,
                save_workers=args.save_workers, raw_every=args.raw_every, view_scale=args.view_scale,
                live_workers=args.live_workers,
                progress=progress, calibration=calibration, on_write_error=args.on_write_error,
                rerun_bind=args.bind, rerun_port=args.port,
                hold_illuminant=not args.illuminant_each_frame,
            )
    except BaseException:
        if created and out is not None:
            with contextlib.suppress(OSError):
                out.rmdir()  # refused before any frame: the empty folder made for it goes again
        raise
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    _print_summary(summary)
    return exit_status(summary)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m polcam.capture ...``: the capture command on its own."""
    parser = CommandParser(prog="polcam")
    sub = parser.add_subparsers(dest="command", required=True)
    add_capture_parser(sub)
    args = parser.parse_args(["capture", *(sys.argv[1:] if argv is None else argv)])

    return run_command(args)
