"""The ``polcam`` command line.  ``polcam COMMAND --help`` documents each command."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from polcam import __version__
from polcam.errors import CameraUnavailableError, PolcamError

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
FORMATS = {"exr": (".exr", None), "tiff": (".tif", "float32"), "tiff16": (".tif", "uint16")}


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------

def _inputs(paths: Iterable[Path], *, recursive: bool) -> list[Path]:
    """Raw frame files among ``paths`` (folders expanded, sidecars skipped)."""
    from polcam.io import RAW_EXTENSIONS

    out: list[Path] = []
    for p in paths:
        if p.is_dir():
            it = p.rglob("*") if recursive else p.iterdir()
            out += sorted(f for f in it if f.is_file() and f.suffix.lower() in RAW_EXTENSIONS)
        else:
            out.append(p)
    return out


def _stokes_products(stack: np.ndarray) -> dict[str, np.ndarray]:
    from polcam import stokes as st

    s = st.stokes(stack)
    return {
        "i000": stack[0], "i045": stack[1], "i090": stack[2], "i135": stack[3],
        "s0": s.s0, "s1": s.s1, "s2": s.s2,
        "dolp": st.dolp(s), "aolp": st.aolp(s),
        "residual": st.fit_residual(stack),
    }


# products whose values lie in [0, 1] (the others are signed or larger: kept float for tiff16)
_UNIT_RANGE = ("i000", "i045", "i090", "i135", "dolp")


def _dtype_for(name: str, fmt: str) -> str | None:
    if fmt == "tiff16":
        return "uint16" if name in _UNIT_RANGE else "float32"
    return FORMATS[fmt][1]


def _run_stokes(files: Sequence[Path], out_dir: Path, *, layout: str | None, method: str,
                resolution: str, fmt: str, quiet: bool = False) -> dict[str, Any]:
    from polcam.demosaicing import demosaic
    from polcam.io import read_frame, write_image
    from polcam.io.atomic import atomic_write

    ext = FORMATS[fmt][0]
    out_dir.mkdir(parents=True, exist_ok=True)
    done: list[dict[str, Any]] = []
    failed: list[dict[str, str]] = []
    for path in files:
        t0 = time.perf_counter()
        try:
            frame = read_frame(path, layout=layout)
            stack = demosaic(frame, method=method, resolution=resolution)
            target = out_dir / path.stem
            target.mkdir(parents=True, exist_ok=True)
            products = _stokes_products(stack)
            meta = {"input": str(path), "layout": str(frame.layout), "demosaic": method,
                    "resolution": resolution, "polcam_version": __version__,
                    "bit_depth": frame.bit_depth, "black_level": frame.black_level,
                    "white_level": frame.white_level}
            for name, arr in products.items():
                write_image(target / f"{name}{ext}", arr, metadata={**meta, "product": name},
                            dtype=_dtype_for(name, fmt))
            seconds = time.perf_counter() - t0
            meta["seconds"] = seconds
            meta["shape"] = list(stack.shape)
            with atomic_write(target / "meta.json", "w") as fh:
                json.dump(meta, fh, indent=2)
            done.append(meta)
            if not quiet:
                d = products["dolp"]
                print(f"{path.name}: {frame.layout} {stack.shape} -> {target}  "
                      f"mean DoLP {float(np.mean(d)):.3f}  {seconds:.2f} s")
        except (PolcamError, OSError) as exc:
            failed.append({"input": str(path), "error": str(exc)})
            print(f"error: {exc}", file=sys.stderr)
    summary = {"done": len(done), "failed": failed, "frames": done}
    with atomic_write(out_dir / "summary.json", "w") as fh:
        json.dump(summary, fh, indent=2)
    return summary


# ---------------------------------------------------------------------------
# commands
# ---------------------------------------------------------------------------

def cmd_stokes(args: argparse.Namespace) -> int:
    files = _inputs(args.inputs, recursive=args.recursive)
    if not files:
        print(f"error: no raw frames found in {', '.join(map(str, args.inputs))}", file=sys.stderr)
        return 2
    summary = _run_stokes(files, args.out, layout=args.layout, method=args.demosaic,
                          resolution=args.resolution, fmt=args.format, quiet=args.quiet)
    print(f"{summary['done']} frame(s) written to {args.out}, {len(summary['failed'])} failed")
    return 1 if summary["failed"] else 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Replay capture of the fixtures, Stokes maps, separation, and a Rerun recording."""
    src = args.input or FIXTURES / "raw"
    if not src.is_dir():
        print(f"error: fixture folder {src} not found (give --input DIR)", file=sys.stderr)
        return 2
    out: Path = args.out
    method = args.demosaic or "eari"
    print(f"polcam {__version__} demo: raw frames in {src} -> {out}")
    n = len(_inputs([src], recursive=False))
    print(f"1/3 capture: the replay camera plays the {n} frame(s) of {src} into {out / 'capture'}")
    code = main(["capture", "--device", f"replay:{src}", "--frames", str(n), "--out", str(out / "capture"),
                 "--separate", "none", "--quiet"])
    if code:
        return code
    captured = _inputs([out / "capture"], recursive=False)
    print(f"2/3 demosaic ({method}) and Stokes maps at full resolution -> {out / 'stokes'}")
    summary = _run_stokes(captured, out / "stokes", layout=None, method=method, resolution="full", fmt="exr")
    if summary["failed"]:
        return 1
    print(f"3/3 separation at the polarizer-cell resolution (tensor for colour, imin for mono) -> "
          f"{out / 'layers'}; Rerun recording {out / 'demo.rrd'}")
    sep = ["--method", args.separate] if args.separate else []
    code = main(["process", str(out / "capture"), "-o", str(out / "layers"), "--demosaic", method,
                 "--rerun", str(out / "demo.rrd"), "--quiet", *sep])
    print(f"demo done: {len(captured)} frame(s) in {out.resolve()}: capture/ (raw frames + sidecars), "
          f"stokes/<frame>/ (i000..i135, s0, s1, s2, dolp, aolp, residual), layers/<frame>/ "
          f"(diffuse, specular, s0, dolp, aolp, meta.json), demo.rrd (view it with `rerun {out / 'demo.rrd'}`)")
    return code


def parse_option(text: str, *, flag: str = "--option") -> tuple[str, Any]:
    """``KEY=VALUE`` of a method-option flag: VALUE as JSON, else the string itself."""
    if "=" not in text:
        raise PolcamError(f"{flag} {text!r}: expected KEY=VALUE (VALUE as JSON, e.g. max_iter=50)")
    key, value = text.split("=", 1)
    try:
        return key.strip(), json.loads(value)
    except ValueError:
        return key.strip(), value


def cmd_process(args: argparse.Namespace) -> int:
    import signal

    from polcam import process as proc

    opts = proc.ProcessOptions(
        method=args.method, method_options=dict(parse_option(o) for o in args.option or []),
        layout=args.layout, demosaic=args.demosaic, resolution=args.resolution, format=args.format,
        calibration=str(args.calibration) if args.calibration else None)
    if args.method is not None or opts.method_options:
        from polcam.separation._registry import check_options

        # before any work: an unknown method or option would fail every frame
        # (without --method the options are the colour default's, tensor)
        check_options(args.method or "tensor", opts.method_options)
    if args.calibration is not None and not args.calibration.is_file():
        print(f"error: calibration file {args.calibration} not found", file=sys.stderr)
        return 2
    jobs, problems = proc.plan(args.inputs, args.out, recursive=args.recursive)
    for p in problems:
        print(f"error: {p['input']}: {p['error']}", file=sys.stderr)
    if not jobs and not problems:
        print(f"error: no raw frames found in {', '.join(map(str, args.inputs))}", file=sys.stderr)
        return 2
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"error: cannot create {args.out}: {exc.strerror}", file=sys.stderr)
        return 2
    interrupted = False

    def on_signal(signum: int, _frame: Any) -> None:
        nonlocal interrupted
        interrupted = True

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    sink = None
    if args.rerun is not None:
        sink = proc.RunRecording(args.rerun, [j.name for j in jobs])
    t0 = time.perf_counter()
    progress = None
    task = None
    if not (args.quiet or args.json):
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        progress = Progress(TextColumn("[bold]process"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("{task.fields[rate]}"), TimeElapsedColumn(),
                            TextColumn("left"), TimeRemainingColumn(), transient=False,
                            console=__import__("rich.console", fromlist=["Console"]).Console(stderr=True))
        task = progress.add_task("frames", total=len(jobs), rate="")
        progress.start()
    counter = {"n": 0}

    def on_result(r: dict[str, Any]) -> None:
        counter["n"] += 1
        if r["status"] == "failed":
            msg = f"error: {r['error']}"
            if progress is not None:
                progress.console.print(msg)
            elif not args.json:
                print(msg, file=sys.stderr)
        if args.json:
            print(json.dumps({"event": "frame", **r}), flush=True)
        if sink is not None and r["status"] in ("done", "skipped"):
            sink.log_frame(Path(args.out) / r["name"], proc.FORMATS[opts.format][0], r["name"])
        if progress is not None and task is not None:
            elapsed = time.perf_counter() - t0
            progress.update(task, advance=1, rate=f"{counter['n'] / max(elapsed, 1e-9) * 60:.1f} frames/min")

    try:
        workers = max(1, min(args.workers or proc.default_workers(), len(jobs)))
        results = proc.run(jobs, opts, workers=workers,
                           scheduler=args.scheduler, force=args.force, on_result=on_result,
                           stop=lambda: interrupted)
    finally:
        if progress is not None:
            progress.stop()
        for sig, handler in old.items():
            signal.signal(sig, handler)
        if sink is not None:
            sink.close()
    summary = proc.summarize(results, problems, opts=opts, seconds=time.perf_counter() - t0,
                             interrupted=interrupted)
    try:
        path: Path | str = proc.write_summary(args.out, summary)
    except PolcamError as exc:  # e.g. the disk filled up: the frames written so far are whole
        print(f"error: {exc}", file=sys.stderr)
        path = "(summary.json not written)"
        summary["failed"].append({"input": str(args.out / "summary.json"), "error": str(exc)})
    line = (f"{summary['done']} done, {summary['skipped']} up to date, {len(summary['failed'])} failed"
            f"{', interrupted' if interrupted else ''} in {summary['seconds']:.1f} s -> {path}")
    if args.json:
        print(json.dumps({"event": "summary", **{k: v for k, v in summary.items() if k != "results"}}))
    elif not args.quiet or summary["failed"]:
        print(line)
    if interrupted:
        return 130
    return 1 if summary["failed"] else 0


def cmd_devices(args: argparse.Namespace) -> int:
    from polcam.camera import list_devices

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


def cmd_formats(args: argparse.Namespace) -> int:
    from polcam.mosaic import LAYOUTS, PIXEL_FORMATS, _vendor_key

    key = _vendor_key(args.vendor)
    print("layouts: " + ", ".join(f"{k} = {v}" for k, v in LAYOUTS.items()))
    print(f"{'vendor':<32} {'pixel format':<44} {'bits':>4} {'packing':<9} {'kind':<12} layout")
    for (vendor, name), f in sorted(PIXEL_FORMATS.items()):
        if key is not None and vendor not in ("*", key):
            continue
        print(f"{vendor:<32} {name:<44} {f.bit_depth:>4} {f.packing:<9} {f.kind:<12} {f.layout or ''}")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from polcam.synth.render import render, write_scene
    from polcam.synth.scenes import scene, scene_names

    names = args.scenes or list(scene_names())
    for name in names:
        r = render(scene(name), size=args.size, seed=args.seed)
        written = write_scene(r, args.out / name, bit_depth=args.bit_depth)
        print(f"{name}: {len(written)} files in {args.out / name}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    if args.bench == "demosaic":
        from polcam.bench import demosaic as bench

        rows = bench.run(data_dir=args.data, size=args.size, seed=args.seed)
        print(bench.format_markdown(rows))
        return 0
    if args.bench == "quality":
        from polcam.bench import quality

        scenes = args.scenes or quality.scene_set(args.set)
        scores, stats = quality.run(scenes=scenes, methods=args.methods, size=args.size,
                                    seed=args.seed, mono=args.mono)
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
        from polcam.bench import real

        return real.run_args(args)
    if args.bench == "calibration":
        from polcam.calibration import bench as cal_bench

        return cal_bench.run_args(args)
    raise AssertionError(args.bench)


# ---------------------------------------------------------------------------
# parser
# ---------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    from polcam.demosaicing import DEMOSAIC_METHODS

    p = argparse.ArgumentParser(
        prog="polcam",
        description="Polarization cameras: raw frames to polarization stacks, Stokes maps and "
                    "diffuse/specular layers.",
    )
    p.add_argument("--version", action="version", version=f"polcam {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("stokes", help="demosaic raw frames and write the stack, S0-S2, DoLP, AoLP",
                       description="Read raw polarization mosaics (png/tif/pgm/bmp/raw/npy/dng), "
                                   "demosaic them and write, per frame, OUT/<stem>/ with i000..i135 "
                                   "(the four angle images), s0, s1, s2, dolp (0..1), aolp (radians in "
                                   "[0, pi) from the image x axis), residual ((I0+I90)-(I45+I135)) and "
                                   "meta.json; OUT/summary.json lists done and failed frames.")
    s.add_argument("inputs", nargs="+", type=Path, help="raw frame files or folders")
    s.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    s.add_argument("--layout", help="sensor layout (imx250mzr, imx250myr, mono:A,B,C,D, "
                                    "color:A,B,C,D:BAYER); default: from the sidecar / pixel format")
    s.add_argument("--demosaic", default="bilinear", choices=DEMOSAIC_METHODS,
                   help="demosaicing method (default: bilinear)")
    s.add_argument("--resolution", default="full", choices=("full", "cell"),
                   help="full: one output pixel per sensor pixel; cell: one per 2x2 polarizer cell")
    s.add_argument("--format", default="exr", choices=tuple(FORMATS),
                   help="exr (float32), tiff (float32) or tiff16 (uint16 scaled from [0, 1]; "
                        "signed maps stay float32)")
    s.add_argument("--recursive", action="store_true", help="descend into sub-folders")
    s.add_argument("--quiet", action="store_true", help="print only the final line and errors")
    s.set_defaults(func=cmd_stokes)

    pr = sub.add_parser(
        "process", help="diffuse/specular layers and Stokes maps of folders of raw frames",
        description="Process raw frames (files or folders; every format polcam reads): per frame "
                    "OUT/<stem>/ with diffuse, specular, s0, dolp (0..1), aolp (radians, [0, pi), from "
                    "the image x axis) and meta.json (input SHA-256, layout, calibration and its hash, "
                    "method and options, version, timings, solver info, fingerprint); OUT/summary.json "
                    "for the run. Resumable: frames whose outputs match their input and options are "
                    "skipped (--force redoes them). Bad inputs are reported and skipped; the exit "
                    "status is then 1.")
    pr.add_argument("inputs", nargs="+", type=Path, help="raw frame files or folders")
    pr.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    pr.add_argument("--layout", help="sensor layout; overrides the sidecar (imx250mzr, imx250myr, "
                                     "mono:A,B,C,D, color:A,B,C,D:BAYER)")
    pr.add_argument("--method", help="separation method (default: tensor for colour layouts, imin for "
                                     "mono); one of polcam.METHODS")
    pr.add_argument("--option", action="append", metavar="KEY=VALUE",
                    help="a separation option, VALUE as JSON (repeatable), e.g. --option max_iter=50")
    pr.add_argument("--demosaic", default="bilinear", choices=DEMOSAIC_METHODS,
                    help="demosaicing method (default bilinear)")
    pr.add_argument("--resolution", default="cell", choices=("cell", "full"),
                    help="cell: one pixel per 2x2 polarizer cell (default; 1224x1024 for a 5 MP sensor); "
                         "full: one per sensor pixel")
    pr.add_argument("--format", default="exr", choices=tuple(FORMATS),
                    help="exr (float32, default), tiff (float32) or tiff16 (uint16 for the [0, 1] "
                         "products; s0 and aolp stay float32)")
    pr.add_argument("--calibration", type=Path, help="calibration file (polcam calibrate)")
    pr.add_argument("--rerun", type=Path, metavar="FILE.rrd", help="also write the run as a Rerun "
                                                                    "recording, one time step per frame")
    pr.add_argument("--workers", type=int, help="local worker processes (default: the number of cores; "
                                                 "one BLAS thread each)")
    pr.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask distributed cluster "
                                                           "(tcp://host:8786; needs polcam[dask])")
    pr.add_argument("--recursive", action="store_true", help="descend into sub-folders (output names "
                                                            "keep the relative path)")
    pr.add_argument("--force", action="store_true", help="redo frames whose outputs are up to date")
    pr.add_argument("--quiet", action="store_true", help="no progress bar; only errors and failures")
    pr.add_argument("--json", action="store_true", help="machine-readable JSON lines on stdout "
                                                        "(one per frame, then a summary)")
    pr.set_defaults(func=cmd_process)

    from polcam.calibration.cli import add_calibrate_parser
    from polcam.capture import add_capture_parser

    add_capture_parser(sub)
    from polcam.viewer import add_parser as add_view_parser

    add_view_parser(sub)
    add_calibrate_parser(sub)

    d = sub.add_parser("demo", help="run the main job on the bundled fixtures",
                       description="Run polcam on the raw frames bundled in fixtures/raw: capture them "
                                   "with the replay camera, write full-resolution Stokes maps, separate "
                                   "diffuse and specular layers (polcam process) and record the run "
                                   "for the Rerun viewer, all under --out.")
    d.add_argument("--out", type=Path, default=Path("demo-output"), help="output folder (default demo-output)")
    d.add_argument("--input", type=Path, help="folder of raw frames (default: the bundled fixtures)")
    d.add_argument("--demosaic", choices=DEMOSAIC_METHODS, help="demosaicing method (default: eari)")
    d.add_argument("--separate", help="separation method (default: tensor for colour, imin for mono)")
    d.set_defaults(func=cmd_demo)

    v = sub.add_parser("devices", help="list the cameras Aravis sees",
                       description="List GenICam cameras (GigE Vision, USB3 Vision) through Aravis: "
                                   "id, vendor, model, serial, protocol, address.")
    v.add_argument("--fake", action="store_true", help="also show Aravis' simulated camera Fake_1")
    v.add_argument("--json", action="store_true", help="print JSON")
    v.set_defaults(func=cmd_devices)

    f = sub.add_parser("formats", help="list sensor layouts and supported pixel formats",
                       description="List the named layouts and every pixel format polcam reads, "
                                   "by vendor (formats are identified by name plus vendor).")
    f.add_argument("--vendor", help="only this vendor's formats (plus the GenICam standard ones)")
    f.set_defaults(func=cmd_formats)

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

    b = sub.add_parser("bench", help="benchmarks (demosaic, sihr, quality, speed, calibration)",
                       description="Benchmarks that reproduce the tables of docs/benchmarks.md. demosaic: "
                                   "demosaicing quality and speed against ground truth, beside polanalyser. "
                                   "sihr: the single-image highlight-removal methods on the Shen 2013 images "
                                   "against the published PSNR/SSIM table. quality: every separation method on "
                                   "the synthetic scenes. speed: the tensor method's exact and fast solvers. "
                                   "calibration: dark, flat and polarizer calibration on a synthetic imperfect "
                                   "sensor.")
    bsub = b.add_subparsers(dest="bench", required=True, metavar="BENCH")
    bd = bsub.add_parser("demosaic", help="demosaicing quality and speed",
                         description="Demosaicing quality (PSNR of I, S0, DoLP; AoLP error) and speed against "
                                     "ground truth on synthetic scenes and a real colour stack, beside "
                                     "polanalyser.")
    bd.add_argument("--data", type=Path, help="a real colour stack folder (0_1.png .. 135_1.png)")
    bd.add_argument("--size", type=int, help="size of the synthetic scenes")
    bd.add_argument("--seed", type=int, default=0, help="random seed of the synthetic scenes (default 0)")
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
    bq.add_argument("--set", choices=("paper", "stress", "all"), default="paper",
                    help="scene set: the paper's, polcam's stress scenes, or both (default paper)")
    bq.add_argument("--mono", action="store_true",
                    help="score the scenes' luminance with the methods that take mono stacks")
    bq.add_argument("--size", type=int, default=128, help="scene side in pixels (default 128)")
    bq.add_argument("--seed", type=int, default=0, help="random seed of the scenes (default 0)")
    bq.add_argument("--out", type=Path, help="output folder (default bench-output/quality)")
    from polcam.bench import speed as _speed
    from polcam.calibration import bench as _cal_bench

    bp = bsub.add_parser("speed", help="the tensor method's exact and fast solvers",
                         description="The tensor method's exact and fast solvers on the same inputs: seconds, "
                                     "speed ratio, PSNR difference, iterations and peak memory on synthetic "
                                     "scenes, and the fast solver on a full 2448 x 2048 sensor frame from raw "
                                     "to diffuse and specular (docs/benchmarks.md). Each case runs in a fresh "
                                     "process.")
    _speed.add_arguments(bp)
    bc = bsub.add_parser("calibration", help="calibration on a synthetic imperfect sensor",
                         description="Dark, flat and polarizer calibration of a synthetic imperfect sensor: "
                                     "recovered maps, Stokes errors before and after, separation with and "
                                     "without calibration (docs/benchmarks.md).")
    _cal_bench.add_arguments(bc)
    from polcam.bench import real as _real

    _real.add_parser(bsub)
    b.set_defaults(func=cmd_bench)
    return p


def reference_markdown() -> str:
    """docs/cli.md: every command's --help, rendered at 100 columns."""
    import os

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parts = ["# polcam command line", "",
                 "Generated from the parsers (`python -m polcam.cli --markdown > docs/cli.md`); "
                 "`polcam COMMAND --help` prints the same.", "", "```", parser.format_help().rstrip(), "```"]
        for name, cmd in sub.choices.items():
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
    """Entry point of ``polcam`` and ``python -m polcam``."""
    return run_command(build_parser().parse_args(argv))


def run_command(args: argparse.Namespace) -> int:
    """Run a parsed command (its ``func``) and map errors to exit statuses.

    0 or the command's own status; 3 when a camera is unavailable (Aravis
    missing, no such camera, busy); 2 for any other :class:`PolcamError`
    (the message on stderr); 130 when interrupted.  The standalone entry
    points (``python -m polcam.capture``, ``python -m polcam.calibration``)
    use it too.
    """
    try:
        return int(args.func(args) or 0)
    except CameraUnavailableError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    if sys.argv[1:] == ["--markdown"]:
        sys.stdout.write(reference_markdown())
        sys.exit(0)
    sys.exit(main())
