"""``polcam view PATH [--web] [--port N] [--bind ADDR]``: an .rrd, a process output folder or a raw
folder in the Rerun viewer (:mod:`polcam.viewer`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from polcam.viewer import view

__all__ = ["add_parser", "cmd_view"]


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``view`` to an ``argparse`` sub-parser set; returns the new parser."""
    v = subparsers.add_parser(
        "view", help="show an .rrd, a process output folder or a raw folder in the Rerun viewer",
        description="Show PATH in Rerun with polcam's layout (raw, S0, DoLP, AoLP, diffuse, specular, "
                    "statistics for a live capture): an .rrd recording, a `polcam process` output folder (its layers "
                    "and maps read from disk), a `polcam demo` output folder (its demo.rrd) or a folder of raw frames (demosaiced and separated on the fly with the "
                    "default methods). Without --web the native viewer opens (needs a display); with --web "
                    "Rerun's web viewer is served and its URL printed, until Ctrl-C or SIGTERM.")
    v.add_argument("path", type=Path, help=".rrd file, process or demo output folder, or raw folder")
    v.add_argument("--web", action="store_true", help="serve the web viewer instead of opening the native one")
    v.add_argument("--port", type=int, default=9090,
                   help="--web: port of the web viewer (its data use port + 1; default 9090; 0: any free port)")
    v.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                   help="address the viewer's servers listen on (default 127.0.0.1, this machine only; 0.0.0.0: "
                        "anyone on this machine's networks can watch)")
    v.add_argument("--memory-limit", default="1GiB",
                   help="--web: data the server keeps for viewers that connect later (default 1GiB)")
    v.set_defaults(func=cmd_view)
    return v


def cmd_view(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam view``."""
    return view(args.path, web=args.web, port=args.port, bind=args.bind, memory_limit=args.memory_limit,
                out=lambda text: print(text, flush=True))
