"""``polcam calibrate``'s command line lives in :mod:`polcam.commands.calibrate` (this is a shim for it)."""

from __future__ import annotations

from polcam.commands.calibrate import add_calibrate_parser, cmd_calibrate, main

__all__ = ["add_calibrate_parser", "cmd_calibrate", "main"]
