"""``polcam devices``: the cameras Aravis sees."""

from __future__ import annotations

import argparse
import json
from typing import Any

from polcam.camera import list_devices

__all__ = ["add_parser", "cmd_devices"]


def cmd_devices(args: argparse.Namespace) -> int:
    devices = list_devices(fake=args.fake)
    if args.json:
        print(json.dumps([d.as_dict() for d in devices], indent=2))
        return 0
    if not devices:
        print("no camera found (check cabling/network; see drivers/README.md; "
              "`polcam devices --fake` shows Aravis' simulated camera)")
        return 0
    print(f"{'id':<32} {'vendor':<24} {'model':<24} {'serial':<14} {'protocol':<10} address")
    for d in devices:
        print(f"{d.id:<32} {d.vendor:<24} {d.model:<24} {d.serial:<14} {d.protocol:<10} {d.address}")
    return 0


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Add ``devices`` to the sub-parsers."""
    v = sub.add_parser("devices", help="list the cameras Aravis sees",
                       description="List GenICam cameras (GigE Vision, USB3 Vision) through Aravis: "
                                   "id, vendor, model, serial, protocol, address.")
    v.add_argument("--fake", action="store_true", help="also show Aravis' simulated camera Fake_1")
    v.add_argument("--json", action="store_true", help="print JSON")
    v.set_defaults(func=cmd_devices)
    return v
