"""``polcam render``: the synthetic scenes with ground truth (:mod:`polcam.synth`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from polcam.synth.render import render, write_scene
from polcam.synth.scenes import scene, scene_names

__all__ = ["add_parser", "cmd_render"]


def cmd_render(args: argparse.Namespace) -> int:
    names = args.scenes or list(scene_names())
    for name in names:
        r = render(scene(name), size=args.size, seed=args.seed)
        written = write_scene(r, args.out / name, bit_depth=args.bit_depth)
        print(f"{name}: {len(written)} files in {args.out / name}")
    return 0


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Add ``render`` to the sub-parsers."""
    r = sub.add_parser("render", help="render the synthetic scenes with ground truth",
                       description="Render the paper's synthetic scene set (Bunny1-7, Dragon1-2, "
                                   "Armadillo; docs/synthetic.md) into OUT_DIR/<scene>/: the four angle "
                                   "images, ground-truth diffuse and specular, the object mask, and raw "
                                   "mosaics (imx250mzr, imx250myr) with their sidecars.")
    r.add_argument("out", type=Path, help="output folder")
    r.add_argument("--scenes", nargs="+", help="scene names (default: all)")
    r.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    r.add_argument("--seed", type=int, default=0, help="noise and texture seed (default 0)")
    r.add_argument("--bit-depth", type=int, default=12, choices=(8, 12), help="raw mosaic bit depth")
    r.set_defaults(func=cmd_render)
    return r
