"""``polcam bench calibration`` and ``polcam bench scenes``: calibration on a synthetic imperfect sensor,
and the measured statistics of the synthetic scenes."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from polcam.bench import calibration
from polcam.io.atomic import atomic_write
from polcam.synth.scenes import statistics_table

__all__ = ["add_parsers"]


def add_parsers(bsub: Any) -> None:
    """Add ``calibration`` and ``scenes`` to ``polcam bench``."""
    p = bsub.add_parser("calibration", help="calibration on a synthetic imperfect sensor",
                        description="Dark, flat and polarizer calibration of a synthetic imperfect sensor: "
                                    "recovered maps, Stokes errors before and after, separation with and "
                                    "without calibration (docs/benchmarks.md; polcam/bench/calibration.py "
                                    "explains every number).")
    p.add_argument("--layouts", nargs="+", default=["imx250mzr", "imx250myr"], help="sensor layouts")
    p.add_argument("--size", type=int, default=128, help="sensor side in pixels (default 128)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--dark-frames", type=int, default=128,
                   help="dark frames averaged into the dark map (default 128)")
    p.add_argument("--flat-frames", type=int, default=512,
                   help="flat-field frames averaged into the gain map (default 512)")
    p.add_argument("--angles", type=int, default=16, help="polarizer angles (default 16)")
    p.add_argument("--per-angle", type=int, default=32, help="frames per polarizer angle (default 32)")
    p.add_argument("--scene-frames", type=int, default=16, help="frames averaged for the scene (default 16)")
    p.add_argument("--separation", nargs="*", default=["imin", "tensor"], metavar="METHOD",
                   help="separation methods to score on a rendered scene (default: imin tensor; tensor runs "
                        "on colour layouts only; give the flag alone to skip)")
    p.add_argument("--json", type=Path, help="also write the raw figures to this JSON file")
    p.set_defaults(bench_run=run_calibration)
    s = bsub.add_parser("scenes", help="measured statistics of the synthetic scenes",
                        description="Render the paper's synthetic scenes and print their measured statistics "
                                    "(saturated fraction, specular / diffuse, object pixels) as a Markdown "
                                    "table (docs/synthetic.md).")
    s.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    s.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    s.set_defaults(bench_run=run_scenes)


def run_calibration(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench calibration``; print the tables."""
    t0 = time.perf_counter()
    result = calibration.run(layouts=args.layouts, size=args.size, seed=args.seed, dark_frames=args.dark_frames,
                             flat_frames=args.flat_frames, angles=args.angles, per_angle=args.per_angle,
                             scene_frames=args.scene_frames, separation=args.separation)
    print(calibration.format_markdown(result))
    print(f"\n({time.perf_counter() - t0:.1f} s)")
    if args.json:
        with atomic_write(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
    return 0


def run_scenes(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench scenes``: the statistics table on stdout."""
    print(statistics_table(size=args.size, seed=args.seed))
    return 0
