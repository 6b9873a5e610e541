"""``polcam bench``: the benchmarks behind docs/benchmarks.md (:mod:`polcam.bench`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

__all__ = ["add_parser", "cmd_bench"]


def cmd_bench(args: argparse.Namespace) -> int:
    if args.bench == "demosaic":
        from polcam.bench import demosaic as bench

        return bench.run_args(args)
    if args.bench == "quality":
        from polcam.bench import quality

        if args.set == "random":
            return _quality_family(args)
        scenes = args.scenes or quality.scene_set(args.set)
        scores, stats = quality.run(scenes=scenes, methods=args.methods, size=args.size,
                                    seed=0 if args.seed is None else args.seed, mono=args.mono)
        print(quality.format_object_psnr(scores))
        for f in quality.write_outputs(scores, stats, args.out or Path("bench-output") / "quality"):
            print(f"wrote {f}")
        return 0
    if args.bench == "sihr":
        from polcam.bench import sihr

        if not args.data.is_dir():
            print(f"error: --data {args.data}: not a folder (expected the shen2013 images and their *_gt.png)",
                  file=sys.stderr)
            return 2
        rows = sihr.run(args.data, methods=args.methods)
        print(sihr.format_table(rows))
        return 0
    if args.bench == "speed":
        from polcam.bench import speed

        return speed.run_args(args)
    if args.bench == "real":
        if args.relit:
            from polcam.bench import relit

            return relit.run_args(args)
        from polcam.bench import real

        return real.run_args(args)
    if args.bench == "stability":
        from polcam.bench import stability

        return stability.run_args(args)
    if args.bench == "calibration":
        from polcam.calibration import bench as cal_bench

        return cal_bench.run_args(args)
    raise AssertionError(args.bench)


def _quality_family(args: argparse.Namespace) -> int:
    """``polcam bench quality --set random``: a split of the randomized scene family."""
    from polcam.bench import quality
    from polcam.errors import PolcamError
    from polcam.synth.family import scene_name, split_seeds

    try:
        seeds, master = split_seeds(args.split, args.n, seed=args.seed)
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if master is not None:
        print(f"test split: master seed {master} (reproduce this run with --split test --seed {master})")
    print("scenes: " + " ".join(scene_name(s) for s in seeds), flush=True)
    try:
        scores, stats, _, _ = quality.run_family(args.split, args.n, seed=master, size=args.size,
                                                 methods=args.methods, mono=args.mono)
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(quality.family_summary(scores))
    out = args.out or Path("bench-output") / f"quality-{args.split}{'-mono' if args.mono else ''}"
    for f in quality.write_outputs(scores, stats, out):
        print(f"wrote {f}")
    return 0


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Add ``bench`` and its benchmarks to the sub-parsers."""
    b = sub.add_parser("bench", help="benchmarks (demosaic, sihr, quality, speed, calibration, real, stability)",
                       description="Benchmarks that reproduce the tables of docs/benchmarks.md. demosaic: "
                                   "demosaicing quality and speed against ground truth, beside polanalyser. "
                                   "sihr: the single-image highlight-removal methods on the Shen 2013 images "
                                   "against the published PSNR/SSIM table. quality: every separation method on "
                                   "the synthetic scenes. speed: a separation method's time (by default the tensor method's "
                                   "exact and fast solvers). "
                                   "calibration: dark, flat and polarizer calibration on a synthetic imperfect "
                                   "sensor. real: every colour method on real colour-polarization stacks, "
                                   "judged by physics. stability: how much a method's layer moves when its "
                                   "input barely does (continuity, frame-to-frame flicker).")
    bsub = b.add_subparsers(dest="bench", required=True, metavar="BENCH")
    from polcam.bench import demosaic as _demosaic

    bd = bsub.add_parser("demosaic", help="demosaicing quality and speed",
                         description="Demosaicing quality (PSNR of S0 and DoLP, AoLP error) and speed against "
                                     "ground truth on synthetic scenes and the real colour stacks (colour, and "
                                     "their luminance as mono), per scene and method.")
    _demosaic.add_arguments(bd)
    bs = bsub.add_parser("sihr", help="single-image highlight removal on the Shen 2013 images",
                         description="PSNR/SSIM and seconds of the single-image methods on the Shen 2013 "
                                     "images, beside the published table.")
    bs.add_argument("--data", type=Path, required=True, help="the shen2013 folder (images and *_gt.png)")
    bs.add_argument("--methods", nargs="+", help="only these methods")
    bq = bsub.add_parser("quality", help="every separation method on the synthetic scenes",
                         description="Every separation method on the synthetic scenes (PSNR, SSIM, whole image "
                                     "and object mask; CSV, Markdown, plot), beside the paper's tables.")
    bq.add_argument("--methods", nargs="+", help="only these methods")
    bq.add_argument("--scenes", nargs="+", help="only these scenes (default: those of --set)")
    bq.add_argument("--set", choices=("paper", "stress", "all", "random"), default="paper",
                    help="scene set: the paper's, polcam's stress scenes, both, or the randomized family "
                         "(polcam.synth.family; default paper)")
    bq.add_argument("--split", choices=("validation", "test"), default="validation",
                    help="with --set random: validation (fixed seeds, for choices) or test (fresh seeds at "
                         "every run, printed; default validation)")
    bq.add_argument("--n", type=int, default=40, help="with --set random: number of scenes (default 40)")
    bq.add_argument("--mono", action="store_true",
                    help="score the scenes' luminance with the methods that take mono stacks")
    bq.add_argument("--size", type=int, default=128, help="scene side in pixels (default 128)")
    bq.add_argument("--seed", type=int, help="noise seed of the named scenes (default 0); with --set random "
                                             "--split test: the master seed of the scene seeds (default fresh)")
    bq.add_argument("--out", type=Path, help="output folder (default bench-output/quality)")
    from polcam.bench import speed as _speed
    from polcam.calibration import bench as _cal_bench

    bp = bsub.add_parser("speed", help="speed targets; the tensor method's solvers (--sizes), other methods "
                                       "(--method), the maps (--maps)",
                         description="Without --sizes, --method or --maps: every speed target's figure in one "
                                     "run (the maps against polanalyser, wen21 and the colour default at cell "
                                     "resolution, a raw 5 MP colour frame to layers), each beside its target. "
                                     "With --sizes or --method: the tensor method's exact and fast solvers on "
                                     "the same inputs (or that method alone): seconds, "
                                     "speed ratio, PSNR difference, iterations and peak memory on synthetic "
                                     "scenes, and the fast solver on a full 2448 x 2048 sensor frame from raw "
                                     "to diffuse and specular (docs/benchmarks.md), each case in a fresh "
                                     "process. --device names the device first and fails when it is missing.")
    _speed.add_arguments(bp)
    bc = bsub.add_parser("calibration", help="calibration on a synthetic imperfect sensor",
                         description="Dark, flat and polarizer calibration of a synthetic imperfect sensor: "
                                     "recovered maps, Stokes errors before and after, separation with and "
                                     "without calibration (docs/benchmarks.md).")
    _cal_bench.add_arguments(bc)
    from polcam.bench import real as _real

    _real.add_parser(bsub)
    from polcam.bench import stability as _stability

    bst = bsub.add_parser("stability", help="how much a method's layer moves when its input barely does",
                          description="Per synthetic scene and method: the largest change of the diffuse layer "
                                      "under a perturbation of the input far below any noise (continuity), and "
                                      "the per-pixel deviation of the layer over noise seeds of a static scene "
                                      "(flicker), with the mean PSNR (docs/methods/polarized-residual.md).")
    _stability.add_arguments(bst)
    b.set_defaults(func=cmd_bench)
    return b
