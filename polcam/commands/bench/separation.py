"""``polcam bench quality``, ``sihr``, ``speed``, ``real``, ``stability``, ``default-rule`` and
``train-residual``: the separation methods' benchmarks, the rule that picks the default method and
the training of polarized-residual's learned stage."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from polcam._jsonable import jsonable
from polcam.bench import default_rule, quality, real, relit, residual_training, sihr, stability
from polcam.commands._args import reproducing_command
from polcam.commands.bench import speed
from polcam.errors import FrameReadError, MethodError, PolcamError
from polcam.io.atomic import atomic_write
from polcam.separation.polarized_residual import LEARNED_MONO_WEIGHTS as RESIDUAL_MONO_WEIGHTS
from polcam.separation.polarized_residual import LEARNED_WEIGHTS as RESIDUAL_WEIGHTS
from polcam.synth.analytic import scene_name as analytic_scene_name
from polcam.synth.family import scene_name, split_seeds

__all__ = ["add_parsers"]


def add_parsers(bsub: Any) -> None:
    """Add the separation sub-commands to ``polcam bench``."""
    _add_sihr(bsub)
    _add_quality(bsub)
    _add_train_residual(bsub)
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
    speed.add_arguments(bp)
    bp.set_defaults(bench_run=speed.run_args)
    _add_real(bsub)
    _add_stability(bsub)
    _add_default_rule(bsub)


def _add_sihr(bsub: Any) -> None:
    bs = bsub.add_parser("sihr", help="single-image highlight removal on the Shen 2013 images",
                         description="PSNR/SSIM and seconds of the single-image methods on the Shen 2013 "
                                     "images, beside the published table.")
    bs.add_argument("--data", type=Path, required=True,
                    help="the shen2013 folder (animals.png, animals_gt.png, ...) or its parent")
    bs.add_argument("--methods", nargs="+",
                    help="only these methods (space or comma separated; default: every registered method "
                         "of the reference table, plus yamamoto19)")
    bs.set_defaults(bench_run=run_sihr)


def run_sihr(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench sihr`` and print the table."""
    if not args.data.is_dir():
        print(f"error: --data {args.data}: not a folder (expected animals.png, animals_gt.png, ... of "
              "shen2013, or the folder holding shen2013/)", file=sys.stderr)
        return 2
    methods = [m for item in args.methods for m in item.split(",") if m] if args.methods else None
    try:
        rows = sihr.run(args.data, methods)
    except (MethodError, FrameReadError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    sys.stdout.write(sihr.format_table(rows))
    return 0


def _add_quality(bsub: Any) -> None:
    bq = bsub.add_parser("quality", help="every separation method on the synthetic scenes",
                         description="Every separation method on the synthetic scenes (PSNR, SSIM, whole image "
                                     "and object mask; CSV, Markdown, plot), beside the paper's tables.")
    bq.add_argument("--methods", nargs="+", help="only these methods")
    bq.add_argument("--scenes", nargs="+", help="only these scenes (default: those of --set)")
    bq.add_argument("--set", choices=("paper", "stress", "all", "random", "analytic"), default="paper",
                    help="scene set: the paper's, polcam's stress scenes, both, the randomized family "
                         "(polcam.synth.family), or the analytic family from a second renderer, used for no "
                         "choice (polcam.synth.analytic; default paper)")
    bq.add_argument("--split", choices=("validation", "test"), default="validation",
                    help="with --set random or analytic: validation (fixed seeds; of the random family, for "
                         "choices) or test (fresh seeds at every run, printed; default validation)")
    bq.add_argument("--n", type=int, default=40, help="with --set random or analytic: number of scenes (default 40)")
    bq.add_argument("--mono", action="store_true",
                    help="score the scenes' luminance with the methods that take mono stacks")
    bq.add_argument("--size", type=int, default=128, help="scene side in pixels (default 128)")
    bq.add_argument("--seed", type=int, help="noise seed of the named scenes (default 0); with --set random or "
                                             "analytic --split test: the master seed of the scene seeds (default "
                                             "fresh)")
    bq.add_argument("--out", type=Path, help="output folder (default bench-output/quality)")
    bq.set_defaults(bench_run=run_quality)


def run_quality(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench quality``: the table on stdout, CSV, Markdown and a plot in --out."""
    if args.set in quality.FAMILIES:
        return _quality_family(args)
    scenes = args.scenes or quality.scene_set(args.set)
    scores, stats = quality.run(scenes=scenes, methods=args.methods, size=args.size,
                                seed=0 if args.seed is None else args.seed, mono=args.mono)
    print(quality.format_object_psnr(scores))
    for f in quality.write_outputs(scores, stats, args.out or Path("bench-output") / "quality"):
        print(f"wrote {f}")
    return 0


def _quality_family(args: argparse.Namespace) -> int:
    """``polcam bench quality --set random`` (or ``analytic``): a split of a scene family."""
    try:
        seeds, master = split_seeds(args.split, args.n, seed=args.seed)
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if master is not None:
        print(f"test split: master seed {master} (reproduce this run with --split test --seed {master})")
    name = scene_name if args.set == "random" else analytic_scene_name
    print("scenes: " + " ".join(name(s) for s in seeds), flush=True)
    try:
        scores, stats, _, _ = quality.run_family(args.split, args.n, seed=master, size=args.size,
                                                 methods=args.methods, mono=args.mono, family=args.set)
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(quality.family_summary(scores))
    kind = "" if args.set == "random" else "analytic-"
    out = args.out or Path("bench-output") / f"quality-{kind}{args.split}{'-mono' if args.mono else ''}"
    for f in quality.write_outputs(scores, stats, out):
        print(f"wrote {f}")
    return 0


def _add_real(bsub: Any) -> None:
    p = bsub.add_parser(
        "real", help="every colour separation method on real colour stacks",
        description="Every colour separation method on real full-resolution colour polarization stacks "
                    "(mosaicked in the IMX250MYR layout, demosaiced, separated), judged by physics: "
                    "diffuse above Imin, specular colour spread, brightest 1 % removed, achromatic "
                    "unpolarized pixels kept, seconds; a Markdown table and a montage per scene.")
    p.add_argument("--data", type=Path, help="folder with real-color-stack/ and real-color-stacks/ "
                                             "(default ../shared/data when present)")
    p.add_argument("--methods", nargs="+", help="only these methods (default: all)")
    p.add_argument("--scenes", nargs="+", help="only these scenes (default: all found)")
    p.add_argument("--crop", type=int, nargs=4, metavar=("Y", "X", "H", "W"),
                   help="crop the true stacks to this window first")
    p.add_argument("--scale", type=float, help="then resize by this factor in (0, 1] (default 1; 0.5 with --relit)")
    p.add_argument("--exposure", type=float, default=1.0,
                   help="relight: multiply the true stacks by this gain, then clip at 1 (default 1)")
    p.add_argument("--light", type=float, nargs=3, default=(1.0, 1.0, 1.0), metavar=("R", "G", "B"),
                   help="relight: the light's colour against the recording's white balance (default 1 1 1)")
    p.add_argument("--relit", action="store_true",
                   help="the standing table: every stack under every relit variant (recorded, overexposed, "
                        "tinted, tinted+overexposed; polcam.bench.relit) with the no-harm measures: matte "
                        "achromatic kept, brightest 1 %% removed, specular spread, structure invented in "
                        "clipped regions; and what each stack's brightest 1 %% holds (clipped, unpolarized, "
                        "rising above its neighbourhood)")
    p.add_argument("--variants", nargs="+", help="with --relit: only these variants (default: all)")
    p.add_argument("--mono", action="store_true",
                   help="with --relit: the mono camera (the stacks' luminance through an IMX250MZR mosaic) "
                        "and the methods that take mono stacks")
    p.add_argument("--out", type=Path, default=Path("bench-output/real"), help="output folder "
                                                                              "(default bench-output/real)")
    p.set_defaults(bench_run=run_real)


def run_real(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench real`` (``--relit``: the relit variants' table)."""
    data = args.data if args.data is not None else real.default_data()
    if data is None or not real.find_scenes(data):
        print(f"error: --data {data}: no real colour stack found (expected real-color-stack/ or "
              "real-color-stacks/<scene>/ with 0/45/90/135 PNGs)", file=sys.stderr)
        return 2
    if args.relit:
        return _run_relit(args, data)
    if args.mono or args.variants:
        print("error: --mono and --variants need --relit", file=sys.stderr)
        return 2
    try:
        scores, layers = real.run(data, methods=args.methods, scenes=args.scenes, crop=args.crop,
                                  scale=1.0 if args.scale is None else args.scale,
                                  exposure=args.exposure, light=args.light)
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(real.format_table(scores))
    for f in real.write_outputs(scores, layers, args.out):
        print(f"wrote {f}")
    return 0


def _run_relit(args: argparse.Namespace, data: Path) -> int:
    if args.exposure != 1.0 or tuple(args.light) != (1.0, 1.0, 1.0):
        print("error: --relit runs its own variants; expected no --exposure or --light", file=sys.stderr)
        return 2
    try:
        scores = relit.run(data, methods=args.methods, scenes=args.scenes, crop=args.crop,
                           scale=0.5 if args.scale is None else args.scale, mono=args.mono,
                           variants=args.variants)
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    table = relit.format_table(scores)
    print(table)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "relit.md", "w") as fh:
        fh.write(table + "\n")
    with atomic_write(out / "relit.json", "w") as fh:
        fh.write(json.dumps(jsonable({"rows": [vars(s) for s in scores], "summary": relit.summary(scores)}),
                            indent=1) + "\n")
    print(f"wrote {out / 'relit.md'}\nwrote {out / 'relit.json'}")
    return 0


def _add_stability(bsub: Any) -> None:
    p = bsub.add_parser("stability", help="how much a method's layer moves when its input barely does",
                        description="Per synthetic scene and method: the largest change of the diffuse layer "
                                    "under a perturbation of the input far below any noise (continuity), and "
                                    "the per-pixel deviation of the layer over noise seeds of a static scene "
                                    "(flicker), with the mean PSNR (docs/methods/polarized-residual.md).")
    p.add_argument("--set", default="all", choices=("paper", "stress", "all"), help="scene set (default all)")
    p.add_argument("--scenes", nargs="+", help="only these scenes")
    p.add_argument("--methods", nargs="+", default=["polarized-residual", "imin"],
                   help="methods (default polarized-residual imin)")
    p.add_argument("--size", type=int, default=96, help="scene side in pixels (default 96)")
    p.add_argument("--frames", type=int, default=6, help="noise seeds per scene for the flicker (default 6)")
    p.add_argument("--rel", type=float, default=3e-7,
                   help="relative deviation of the continuity's perturbation (default 3e-7)")
    p.add_argument("--hold-illuminant", action="store_true",
                   help="pass the first frame's illuminant estimate to the later frames (as polcam capture does)")
    p.add_argument("--mono", action="store_true", help="the scenes' luminance (mono), for methods that take it")
    p.add_argument("--out", type=Path, default=Path("bench-output") / "stability",
                   help="output folder (default bench-output/stability)")
    p.set_defaults(bench_run=run_stability)


def run_stability(a: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench stability``; print the table and write the files."""
    rows = stability.run(scenes=a.scenes or quality.scene_set(a.set), methods=a.methods, size=a.size,
                         frames=a.frames, rel=a.rel, hold_illuminant=a.hold_illuminant, mono=a.mono)
    print(stability.format_markdown(rows))
    for f in stability.write_outputs(rows, a.out):
        print(f"wrote {f}")
    return 0


def _add_default_rule(bsub: Any) -> None:
    p = bsub.add_parser("default-rule", help="the default separation method per input form, from measured tables",
                        description="Assemble the table behind the default separation method per input form "
                                    "(polcam.bench.default_rule) from the outputs of polcam bench real --relit "
                                    "[--mono] and polcam bench quality --set random --split validation [--mono].")
    p.add_argument("--real", type=Path, action="append", required=True,
                   help="relit.json of polcam bench real --relit (repeat for several runs)")
    p.add_argument("--real-mono", type=Path, action="append", default=[],
                   help="relit.json of polcam bench real --relit --mono (repeat)")
    p.add_argument("--validation", type=Path, required=True, help="scores.csv of the colour validation split")
    p.add_argument("--validation-mono", type=Path, required=True, help="scores.csv of the mono validation split")
    p.add_argument("--command", action="append", default=[], help="a command that produced the inputs (repeat)")
    p.add_argument("--out", type=Path, help="write the table here (JSON)")
    p.set_defaults(bench_run=run_default_rule)


def run_default_rule(a: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench default-rule``: print the picks, optionally write the table."""
    table = default_rule.build_table(a.real, a.validation, a.validation_mono, real_mono=a.real_mono,
                                     commands=a.command)
    for form, (m, why) in table["picked"].items():
        print(f"{form}: {m} ({why})")
    if a.out is not None:
        with atomic_write(a.out, "w") as fh:
            fh.write(json.dumps(table, indent=1) + "\n")
        print(f"wrote {a.out}")
    return 0


def _add_train_residual(bsub: Any) -> None:
    rt = residual_training
    ap = bsub.add_parser("train-residual", help="train polarized-residual's learned unpolarized-specular stage",
                         description="Train the learned stage of polarized-residual (unpolarized=\"learned\") on "
                                     "the randomized family's training seeds (polcam.bench.residual_training) and "
                                     "write the weights atomically, with how they were made and what they keep of "
                                     "matte grey checkers and a matte colour chart (harm_checks). Weights that fail those checks do not "
                                     "replace the shipped ones: they go to <out>.rejected.npz and the command "
                                     "exits with status 1.")
    ap.add_argument("--scenes", type=int, default=rt.DEFAULT_SCENES, help=f"training scenes (default {rt.DEFAULT_SCENES})")
    ap.add_argument("--size", type=int, default=128, help="scene side in pixels (default 128)")
    ap.add_argument("--start", type=int, default=0, help="offset of the first training seed (default 0)")
    ap.add_argument("--samples", type=int, default=rt.DEFAULT_SAMPLES,
                    help=f"pixels fitted (default {rt.DEFAULT_SAMPLES})")
    ap.add_argument("--iterations", type=int, default=rt.DEFAULT_ITERATIONS,
                    help=f"L-BFGS iterations (default {rt.DEFAULT_ITERATIONS})")
    ap.add_argument("--l2", type=float, default=rt.DEFAULT_L2, help=f"weight decay (default {rt.DEFAULT_L2:g})")
    ap.add_argument("--matte-scenes", type=int, default=rt.DEFAULT_MATTE_SCENES,
                    help=f"matte scenes with no specular light (target 0) added to the training "
                         f"(default {rt.DEFAULT_MATTE_SCENES})")
    ap.add_argument("--matte-samples", type=int, default=rt.DEFAULT_MATTE_SAMPLES,
                    help=f"pixels of the matte scenes fitted (default {rt.DEFAULT_MATTE_SAMPLES})")
    ap.add_argument("--camera", choices=rt.CAMERAS, default="colour",
                    help="the camera the weights are for: the family's colour camera, or its mono camera, whose "
                         "stacks polarized-residual runs with weights of their own (default colour)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the subset and the initial weights (default 0)")
    ap.add_argument("--out", type=Path, default=None,
                    help="output .npz (default: the shipped weights of --camera)")
    ap.set_defaults(bench_run=_run_train_residual, bench_parser=ap)


def _run_train_residual(args: argparse.Namespace) -> int:
    """Run a parsed ``polcam bench train-residual``: train, then write the weights and how they were made."""
    rt = residual_training
    for name, least in (("scenes", 1), ("size", 32), ("samples", 1), ("iterations", 1)):
        if getattr(args, name) < least:
            args.bench_parser.error(f"--{name} {getattr(args, name)}: expected an integer of at least {least}")
    if args.start < 0 or args.l2 < 0 or args.matte_scenes < 0 or args.matte_samples < 0:
        args.bench_parser.error("--start, --l2, --matte-scenes and --matte-samples: expected non-negative numbers")
    shipped = RESIDUAL_MONO_WEIGHTS if args.camera == "mono" else RESIDUAL_WEIGHTS
    if args.out is None:
        args.out = shipped
    t0 = time.perf_counter()
    weights = rt.train(args.scenes, size=args.size, start=args.start, max_samples=args.samples,
                       iterations=args.iterations, l2=args.l2, seed=args.seed, matte=args.matte_scenes,
                       matte_samples=args.matte_samples, camera=args.camera)
    command = reproducing_command("polcam bench train-residual", args,
                                  ("camera", "scenes", "size", "start", "samples", "iterations", "l2", "matte_scenes",
                                   "matte_samples", "seed"))
    checks = rt.harm_checks(weights, camera=args.camera)
    info = {"command": command, "camera": args.camera, "hidden": list(rt.DEFAULT_HIDDEN), "harm_checks": checks,
            "data": f"the {args.camera} camera's stacks of the randomized scene family's training seeds "
                    "(polcam.synth.family.training_seeds), albedo from public-domain / CC0 photographs of "
                    "scikit-image; no other data"}
    failed = rt.failed_checks(checks)
    took = f"{time.perf_counter() - t0:.0f} s (loss {float(weights['loss']):.4g})"
    if failed and Path(args.out).resolve() == Path(shipped).resolve():
        # the shipped weights are what every separation uses: weights that thin a matte surface do not replace them
        rejected = Path(args.out).with_name(Path(args.out).stem + ".rejected.npz")
        rt.save_weights(weights, rejected, info=info)
        sys.stderr.write(f"polcam bench train-residual: the new weights fail the do-no-harm checks "
                         f"({'; '.join(failed)}; expected at least the floors of "
                         f"polcam.bench.residual_training.HARM_FLOORS): {args.out} is left as it was; the new "
                         f"weights are in {rejected} ({took})\n")
        return 1
    rt.save_weights(weights, args.out, info=info)
    sys.stderr.write(f"wrote {args.out} in {took}; checker kept {checks['checker16_kept']:.4f} / "
                     f"{checks['checker32_kept']:.4f}, the chart's worst grey {checks['chart_worst_grey']:.4f}\n")
    if failed:
        sys.stderr.write(f"warning: these weights fail the do-no-harm checks ({'; '.join(failed)})\n")
    return 0
