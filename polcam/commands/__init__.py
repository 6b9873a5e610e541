"""The ``polcam`` command line: one module per command, on top of the library.

Each module adds its parser (``add_parser``) and runs its command
(``cmd_<name>``); :mod:`polcam.commands._args` holds what they share (option
parsing, the camera arguments, exit statuses).  Nothing in the library
imports this package; the entry points ``polcam`` (:func:`main`),
``python -m polcam``, ``python -m polcam.capture`` and
``python -m polcam.calibration`` are thin shims onto it.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from polcam import DEMOSAIC_METHODS
from polcam._version import __version__
from polcam.commands import bench, calibrate, capture, demo, devices, formats, process, render, stokes, view
from polcam.commands._args import CommandParser, parse_option, run_command
from polcam.parallel import commands_own_main, hold_freed_memory

__all__ = ["build_parser", "main", "parse_option", "reference_markdown", "run_command"]


def build_parser() -> argparse.ArgumentParser:
    """The ``polcam`` parser with every command."""
    p = CommandParser(
        prog="polcam",
        description="Polarization cameras: raw frames to polarization stacks, Stokes maps and "
                    "diffuse/specular layers.",
    )
    p.add_argument("--version", action="version", version=f"polcam {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    stokes.add_parser(sub, DEMOSAIC_METHODS)
    process.add_parser(sub, DEMOSAIC_METHODS)
    capture.add_capture_parser(sub)
    view.add_parser(sub)
    calibrate.add_calibrate_parser(sub)
    demo.add_parser(sub, DEMOSAIC_METHODS)
    devices.add_parser(sub)
    formats.add_parser(sub)
    render.add_parser(sub)
    bench.add_parser(sub)
    return p


#: The pages of docs/reference/ the parsers' help is rendered into: page -> the commands it holds
#: (None: every command not named by another page).
REFERENCE_PAGES: dict[str, tuple[str, ...] | None] = {"cli": None, "cli-bench": ("bench",)}


def reference_markdown(page: str = "cli") -> str:
    """docs/reference/<page>.md: the --help of the commands on that page, rendered at 100 columns.

    ``"cli"`` holds ``polcam --help`` and every command but the benchmarks; ``"cli-bench"``
    holds ``polcam bench`` and its sub-commands (one page each keeps them readable).
    """
    import os

    if page not in REFERENCE_PAGES:
        raise ValueError(f"reference page {page!r}: expected one of {', '.join(REFERENCE_PAGES)}")
    elsewhere = {c for p, cs in REFERENCE_PAGES.items() if p != page and cs for c in cs}
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        wanted = REFERENCE_PAGES[page]
        title = "# polcam command line" if page == "cli" else f"# polcam command line: {' '.join(wanted or ())}"
        parts = [title, "",
                 f"Generated from the parsers (`python -m polcam.cli --markdown {page} > "
                 f"docs/reference/{page}.md`); `polcam COMMAND --help` prints the same."]
        if page == "cli":
            parts += ["", "```", parser.format_help().rstrip(), "```"]
            parts += ["", "The benchmarks' commands are in [cli-bench.md](cli-bench.md)."]
        for name, cmd in sub.choices.items():
            if (wanted is not None and name not in wanted) or (wanted is None and name in elsewhere):
                continue
            parts += ["", f"## polcam {name}", "", "```", cmd.format_help().rstrip(), "```"]
            nested = [a for a in cmd._actions if isinstance(a, argparse._SubParsersAction)]
            for sub_name, sub_cmd in (nested[0].choices.items() if nested else ()):
                parts += ["", f"### polcam {name} {sub_name}", "", "```", sub_cmd.format_help().rstrip(), "```"]
        return "\n".join(parts) + "\n"
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``polcam`` and ``python -m polcam``.

    The command owns ``__main__`` (and the process: its freed memory is kept for reuse,
    :func:`polcam.parallel.hold_freed_memory`), so the library's parallel work may run in
    worker processes (:func:`polcam.parallel.commands_own_main`).
    """
    hold_freed_memory()  # the command owns the process: freed frames' memory is reused, not unmapped
    with commands_own_main():
        return run_command(build_parser().parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
