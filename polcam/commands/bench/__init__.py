"""``polcam bench``: the benchmarks behind docs/benchmarks.md (:mod:`polcam.bench`).

One module per family of benchmarks; each adds its sub-commands (``add_parsers``)
and sets ``bench_run``, the function that runs a parsed sub-command.
"""

from __future__ import annotations

import argparse
from typing import Any

from polcam.commands.bench import calibration, demosaicing, separation

__all__ = ["add_parser", "cmd_bench"]


def cmd_bench(args: argparse.Namespace) -> int:
    """Run the parsed ``polcam bench BENCH``."""
    return args.bench_run(args)


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Add ``bench`` and its benchmarks to the sub-parsers."""
    b = sub.add_parser("bench", help="benchmarks and the tooling behind the shipped choices",
                       description="Benchmarks that reproduce the tables of docs/benchmarks.md. demosaic: "
                                   "demosaicing quality and speed against ground truth, beside polanalyser. "
                                   "sihr: the single-image highlight-removal methods on the Shen 2013 images "
                                   "against the published PSNR/SSIM table. quality: every separation method on "
                                   "the synthetic scenes. speed: a separation method's time (by default the "
                                   "tensor method's exact and fast solvers). "
                                   "calibration: dark, flat and polarizer calibration on a synthetic imperfect "
                                   "sensor. real: every colour method on real colour-polarization stacks, "
                                   "judged by physics. stability: how much a method's layer moves when its "
                                   "input barely does (continuity, frame-to-frame flicker). "
                                   "And the tooling behind what polcam ships: train-lmmse (the lmmse weights), "
                                   "demosaic-validation (their settings), train-residual (the weights of "
                                   "polarized-residual's learned stage), default-rule (the default separation "
                                   "method per input form), scenes (the synthetic scenes' statistics).")
    bsub = b.add_subparsers(dest="bench", required=True, metavar="BENCH")
    demosaicing.add_parsers(bsub)
    separation.add_parsers(bsub)
    calibration.add_parsers(bsub)
    b.set_defaults(func=cmd_bench)
    return b
