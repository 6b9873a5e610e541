"""``polcam demo``: the main job on the bundled fixtures (replay capture, Stokes maps, separation, Rerun)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from polcam import DEMOSAIC_METHODS
from polcam._version import __version__
from polcam.commands import capture, process
from polcam.commands._args import default_methods_text, run_command
from polcam.commands.stokes import run_stokes
from polcam.io.listing import raw_files_in

__all__ = ["FIXTURES", "add_parser", "cmd_demo"]

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"


def cmd_demo(args: argparse.Namespace) -> int:
    """Replay capture of the fixtures, Stokes maps, separation, and a Rerun recording."""
    src = args.input or FIXTURES / "raw"
    if not src.is_dir():
        print(f"error: fixture folder {src} not found (give --input DIR)", file=sys.stderr)
        return 2

    out: Path = args.out
    demosaic = args.demosaic  # None: the demosaicing registry's default for each frame's layout
    print(f"polcam {__version__} demo: raw frames in {src} -> {out}")
    n = len(raw_files_in(src))
    capture_dir = out / "capture"
    earlier = raw_files_in(capture_dir) if capture_dir.is_dir() else []
    if earlier:  # a demo run before: reuse its capture (the replay would give the same frames)
        print(f"1/3 capture: reusing the {len(earlier)} frame(s) an earlier demo captured into {capture_dir}")
    else:
        print(f"1/3 capture: the replay camera plays the {n} frame(s) of {src} into {capture_dir}")
        code = _run("capture", ["--device", f"replay:{src}", "--frames", str(n), "--out", str(capture_dir),
                     "--method", "none", "--quiet"])
        if code:
            return code
    captured = raw_files_in(capture_dir)
    print(f"2/3 demosaic ({demosaic or 'the default method for each layout'}) and Stokes maps at full resolution -> {out / 'stokes'}")
    summary = run_stokes(captured, out / "stokes", layout=None, demosaic=demosaic, resolution="full", fmt="exr")
    if summary["failed"]:
        return 1
    print(f"3/3 separation at the polarizer-cell resolution ({default_methods_text()}) -> "
          f"{out / 'layers'}; Rerun recording {out / 'demo.rrd'}")
    sep = ["--method", args.separate] if args.separate else []
    dem = ["--demosaic", demosaic] if demosaic else []
    code = _run("process", [str(out / "capture"), "-o", str(out / "layers"), *dem,
                 "--rerun", str(out / "demo.rrd"), "--quiet", *sep])
    print(f"demo done: {len(captured)} frame(s) in {out.resolve()}: capture/ (raw frames + sidecars), "
          f"stokes/<frame>/ (i000..i135, s0, s1, s2, dolp, aolp, residual), layers/<frame>/ "
          f"(diffuse, specular, s0, dolp, aolp, meta.json), demo.rrd (view it with `{_polcam_command()} view {out / 'demo.rrd'}`, "
          f"or `... view --web` on a machine without a display)")
    return code


def _run(command: str, argv: list[str]) -> int:
    """Run ``polcam COMMAND ARGV`` (capture or process) as the command line would, in this process."""
    parser = argparse.ArgumentParser(prog="polcam")
    sub = parser.add_subparsers(dest="command", required=True)
    if command == "capture":
        capture.add_capture_parser(sub)
    else:
        process.add_parser(sub, DEMOSAIC_METHODS)
    return run_command(parser.parse_args([command, *argv]))


def _polcam_command() -> str:
    """How to run polcam from here: ``polcam`` if it is on PATH, else its path beside this Python."""
    import shutil

    if shutil.which("polcam"):
        return "polcam"
    beside = Path(sys.executable).parent / "polcam"
    return str(beside) if beside.exists() else "polcam"


def add_parser(sub: Any, demosaic_methods: Sequence[str]) -> argparse.ArgumentParser:
    """Add ``demo`` to the sub-parsers."""
    d = sub.add_parser("demo", help="run the main job on the bundled fixtures",
                       description="Run polcam on the raw frames bundled in fixtures/raw: capture them "
                                   "with the replay camera, write full-resolution Stokes maps, separate "
                                   "diffuse and specular layers (polcam process) and record the run "
                                   "for the Rerun viewer, all under --out.")
    d.add_argument("--out", type=Path, default=Path("demo-output"), help="output folder (default demo-output)")
    d.add_argument("--input", type=Path, help="folder of raw frames (default: the bundled fixtures)")
    d.add_argument("--demosaic", choices=demosaic_methods, help="demosaicing method (default: the one process and stokes use)")
    d.add_argument("--method", "--separate", dest="separate", metavar="METHOD",
                   help=f"separation method (default: {default_methods_text()})")
    d.set_defaults(func=cmd_demo)
    return d
