"""``polcam bench demosaic``, ``train-lmmse`` and ``demosaic-validation``: demosaicing's benchmark and the
tooling that made and chose the shipped ``lmmse`` weights."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from polcam.bench import demosaic as bench_demosaic
from polcam.bench import demosaic_validation as validation
from polcam.bench import lmmse_training as training
from polcam.commands._args import reproducing_command
from polcam.demosaicing.lmmse import BLOCK, WEIGHTS_FILE
from polcam.synth.photos import TRAINING_PHOTOS

__all__ = ["add_parsers"]


def add_parsers(bsub: Any) -> None:
    """Add the demosaicing sub-commands to ``polcam bench``."""
    _add_demosaic(bsub)
    _add_training(bsub)
    _add_validation(bsub)


def _add_demosaic(bsub: Any) -> None:
    ap = bsub.add_parser("demosaic", help="demosaicing quality and speed",
                         description="Demosaicing quality (PSNR of S0 and DoLP, AoLP error) and speed against "
                                     "ground truth on synthetic scenes and the real colour stacks (colour, and "
                                     "their luminance as mono), per scene and method.")
    methods, layouts = bench_demosaic.DEFAULT_METHODS, bench_demosaic.DEFAULT_LAYOUTS
    ap.add_argument("--data", "--data-dir", dest="data", type=Path, default=None,
                    help="shared data folder with the real stacks (real-color-stack/, real-color-stacks/; "
                         "default: synthetic scenes only)")
    ap.add_argument("--size", type=int, default=None,
                    help="scene side in pixels (default: whole real stack, 512 for synthetic)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the synthetic scenes (default 0)")
    ap.add_argument("--methods", nargs="+", default=list(methods), help=f"methods (default: {' '.join(methods)})")
    ap.add_argument("--layouts", nargs="+", default=list(layouts), help="layouts")
    ap.add_argument("--no-speed", action="store_true", help="skip the timing")
    ap.add_argument("--no-quality", action="store_true", help="skip the quality measurements")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per method (default 5)")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows to this JSON file")
    ap.set_defaults(bench_run=run_demosaic)


def run_demosaic(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench demosaic``: Markdown on stdout, optionally the rows as JSON."""
    if args.data is not None and not args.data.is_dir():
        print(f"error: --data {args.data}: not a folder (expected the folder holding real-color-stack/)",
              file=sys.stderr)
        return 2
    rows = bench_demosaic.run(data_dir=args.data, size=args.size, seed=args.seed, methods=args.methods,
                              layouts=args.layouts, measure_quality=not args.no_quality,
                              speed=not args.no_speed, repeats=args.repeats)
    sys.stdout.write(bench_demosaic.format_markdown(rows) + "\n")
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


def _add_training(bsub: Any) -> None:
    ap = bsub.add_parser("train-lmmse", help="train the lmmse demosaicing weights",
                         description="Train the lmmse demosaicing filter bank on rendered scenes "
                                     "(polcam.bench.lmmse_training) and write the weights atomically.")
    ap.add_argument("--scenes", type=int, default=150, help="number of rendered scenes (default 150)")
    ap.add_argument("--size", type=int, default=160, help="scene side in pixels (default 160)")
    ap.add_argument("--seed", type=int, default=2024, help="random seed (default 2024)")
    ap.add_argument("--ridge", type=float, default=training.DEFAULT_RIDGE,
                    help=f"ridge, relative to the mean Gram diagonal (default {training.DEFAULT_RIDGE:g})")
    ap.add_argument("--patterns", type=int, default=training.DEFAULT_PATTERNS,
                    help=f"pattern scenes added (default {training.DEFAULT_PATTERNS})")
    ap.add_argument("--photos", type=int, default=training.DEFAULT_PHOTOS,
                    help=f"crops of the training photographs added (default {training.DEFAULT_PHOTOS})")
    ap.add_argument("--moments", type=int, default=training.DEFAULT_MOMENTS, choices=(0, 1, 2),
                    help=f"order of the vanishing moments (default {training.DEFAULT_MOMENTS})")
    ap.add_argument("--out", type=Path, default=WEIGHTS_FILE, help="output .npz (default: the shipped weights)")
    ap.set_defaults(bench_run=run_training, bench_parser=ap)


def run_training(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench train-lmmse``: train, then write the weights and how they were made."""
    if args.size % BLOCK or args.size < 4 * BLOCK:
        args.bench_parser.error(f"--size {args.size}: expected a multiple of {BLOCK}, at least {4 * BLOCK}")
    t0 = time.perf_counter()
    weights = training.train(scenes=args.scenes, size=args.size, seed=args.seed, ridge=args.ridge,
                             moments=args.moments, patterns=args.patterns, photos=args.photos)
    info = {"scenes": args.scenes, "size": args.size, "seed": args.seed, "ridge": args.ridge,
            "patterns": args.patterns, "photos": args.photos, "moments": args.moments,
            "command": reproducing_command("polcam bench train-lmmse", args, ("scenes", "size", "seed", "ridge",
                                                                              "patterns", "photos", "moments")),
            "data": "polcam's own rendered scenes (polcam.bench.lmmse_training.training_stack)"
                    + (f" and crops of the public-domain / CC0 photographs {', '.join(TRAINING_PHOTOS)} of "
                       "scikit-image with simulated polarization (polcam.synth.photos)" if args.photos
                       else "; no third-party images")}
    training.save_weights(weights, args.out, info=info)
    sys.stderr.write(f"wrote {args.out} in {time.perf_counter() - t0:.0f} s\n")
    return 0


def _add_validation(bsub: Any) -> None:
    v = validation
    ap = bsub.add_parser("demosaic-validation", help="model selection of the lmmse demosaicing",
                         description="Model selection of the lmmse demosaicing on polcam's own validation "
                                     "scenes (polcam.bench.demosaic_validation): one table row per variant "
                                     "and the variant picked.")
    ap.add_argument("--scenes", type=int, default=150, help="training scenes (default 150)")
    ap.add_argument("--size", type=int, default=160, help="training scene side (default 160)")
    ap.add_argument("--seed", type=int, default=2024, help="training seed (default 2024)")
    ap.add_argument("--ridges", type=float, nargs="+", default=list(v.RIDGES), help="ridges tried")
    ap.add_argument("--moments", type=int, nargs="+", default=list(v.MOMENTS), help="moment orders tried")
    ap.add_argument("--patterns", type=int, nargs="+", default=list(v.PATTERNS),
                    help="pattern scenes added to the training set (0 and/or one count)")
    ap.add_argument("--photos", type=int, nargs="+", default=list(v.PHOTOS),
                    help="photograph crops added to the training set (0 and/or one count)")
    ap.add_argument("--kinds", nargs="+", default=["color", "mono"], choices=("color", "mono"),
                    help="kinds of layout to select for")
    ap.add_argument("--blend", action="store_true",
                    help="select lmmse-eari's blend (with the shipped lmmse weights) instead of the banks")
    ap.add_argument("--taus", type=float, nargs="+", default=list(v.BLEND_TAUS), help="blend thresholds tried")
    ap.add_argument("--sigmas", type=float, nargs="+", default=list(v.BLEND_SIGMAS), help="blend Gaussians tried")
    ap.add_argument("--shared", action="store_true",
                    help="select the shared-ratio second stage of colour lmmse (shipped weights) instead of "
                         "the banks")
    ap.add_argument("--commons", type=float, nargs="+", default=list(v.SHARED_COMMONS),
                    help="shared-ratio Gaussians of the all-colour ratio tried (pixels)")
    ap.add_argument("--offsets", type=float, nargs="+", default=list(v.SHARED_OFFSETS),
                    help="shared-ratio Gaussians of the colour offsets tried (pixels)")
    ap.add_argument("--residuals", type=float, nargs="+", default=list(v.SHARED_RESIDUALS),
                    help="shared-ratio Gaussians of the colour residual tried (pixels)")
    ap.add_argument("--stages", nargs="+", default=[f"{m}:{g:g}" for m, g in v.STAGES],
                    help="second stages tried, MODE:SIGMA")
    ap.set_defaults(bench_run=run_validation, bench_parser=ap)


def run_validation(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench demosaic-validation`` and print the tables."""
    if args.seed == validation.VALIDATION_SEED:
        args.bench_parser.error(f"--seed {args.seed}: the training seed must differ from the validation seed")
    if args.shared:
        rows = validation.select_shared(commons=args.commons, offsets=args.offsets, residuals=args.residuals)
    elif args.blend:
        rows = validation.select_blend(taus=args.taus, sigmas=args.sigmas, kinds=args.kinds)
    else:
        stages = [(st.split(":")[0], float(st.split(":")[1])) for st in args.stages]
        rows = validation.select(scenes=args.scenes, size=args.size, seed=args.seed, ridges=args.ridges,
                                 moments=args.moments, patterns=args.patterns, photos=args.photos,
                                 stages=stages, kinds=args.kinds)
    sys.stdout.write(validation.format_markdown(rows) + "\n")
    return 0
