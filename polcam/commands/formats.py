"""``polcam formats``: sensor layouts and the pixel formats polcam reads, by vendor."""

from __future__ import annotations

import argparse
from typing import Any

from polcam.errors import PixelFormatError
from polcam.mosaic import LAYOUTS, PIXEL_FORMATS, VENDOR_ALIASES, vendor_key

__all__ = ["add_parser", "cmd_formats"]


def cmd_formats(args: argparse.Namespace) -> int:
    key = vendor_key(args.vendor)
    known = sorted({v for v, _ in PIXEL_FORMATS if v != "*"} | set(VENDOR_ALIASES.values()))
    if key is not None and key not in known:
        raise PixelFormatError(f"--vendor {args.vendor!r}: unknown vendor; known vendors: {', '.join(known)} "
                               "(or leave --vendor out for every format)")
    print("layouts: " + ", ".join(f"{k} = {v}" for k, v in LAYOUTS.items()))
    print(f"{'vendor':<32} {'pixel format':<44} {'bits':>4} {'packing':<9} {'kind':<12} layout")
    for (vendor, name), f in sorted(PIXEL_FORMATS.items()):
        if key is not None and vendor not in ("*", key):
            continue
        print(f"{vendor:<32} {name:<44} {f.bit_depth:>4} {f.packing:<9} {f.kind:<12} {f.layout or ''}")
    return 0


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Add ``formats`` to the sub-parsers."""
    f = sub.add_parser("formats", help="list sensor layouts and supported pixel formats",
                       description="List the named layouts and every pixel format polcam reads, "
                                   "by vendor (formats are identified by name plus vendor).")
    f.add_argument("--vendor", help="only this vendor's formats (plus the GenICam standard ones)")
    f.set_defaults(func=cmd_formats)
    return f
