"""``polcam stokes``: demosaic raw frames and write the stack, S0-S2, DoLP, AoLP and the fit residual."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from polcam._version import __version__
from polcam.commands._args import add_max_pixels_argument
from polcam.commands._checks import check_run_options
from polcam.demosaicing import resolve_demosaic
from polcam.errors import PolcamError
from polcam.io import read_frame
from polcam.io.atomic import atomic_write
from polcam.io.listing import list_raw_files
from polcam.pipeline import PRODUCTS, require_layout, run_frame
from polcam.sinks.files import FORMATS, write_meta, write_products

__all__ = ["LIT_DOLP_BIAS", "add_parser", "cmd_stokes", "dolp_of_lit", "lit_floor", "run_stokes"]

#: Products of ``polcam stokes`` whose values lie in [0, 1] (uint16 with ``--format tiff16``).
UNIT_RANGE = ("i000", "i045", "i090", "i135", "dolp")

#: Largest DoLP that noise alone may add to a pixel counted as lit (:func:`lit_floor`).
LIT_DOLP_BIAS = 0.05


def lit_floor(black_level: float, white_level: float) -> float:
    """The least S0 of a lit pixel, on the normalised scale of a frame with these levels.

    Noise of standard deviation sigma in each angle image gives ``(S1, S2)`` of
    unpolarized light a length of mean ``sqrt(pi) sigma`` (a Rayleigh
    distribution: S1 = I0 - I90 and S2 = I45 - I135 each have standard deviation
    ``sqrt(2) sigma``), so its DoLP reads ``sqrt(pi) sigma / S0`` on average.
    With sigma one quantisation step ``1 / (white - black)`` of the frame, a
    pixel is lit when that bias is at most :data:`LIT_DOLP_BIAS`:
    ``S0 >= sqrt(pi) / LIT_DOLP_BIAS / (white - black)`` (35 steps: 0.139 for
    8-bit frames, 0.0087 for 12-bit ones, with S0 = (I0 + I45 + I90 + I135) / 2).
    """
    return math.sqrt(math.pi) / LIT_DOLP_BIAS / max(float(white_level) - float(black_level), 1.0)


def dolp_of_lit(s0: np.ndarray, dolp: np.ndarray, floor: float) -> dict[str, float]:
    """Mean and median DoLP over the lit pixels (``s0 >= floor``, per colour channel), and their share.

    ``mean`` and ``median`` are NaN when no pixel is lit.
    """
    lit = np.asarray(s0) >= floor
    vals = np.asarray(dolp)[lit]
    share = float(lit.mean()) if lit.size else 0.0
    if vals.size == 0:
        return {"floor_s0": floor, "lit_share": share, "mean": math.nan, "median": math.nan}
    return {"floor_s0": floor, "lit_share": share, "mean": float(vals.mean()), "median": float(np.median(vals))}


def _dolp_text(d: dict[str, float]) -> str:
    if d["lit_share"] == 0:
        return f"no lit pixels (S0 >= {d['floor_s0']:.3g})"
    return (f"DoLP over the lit pixels (S0 >= {d['floor_s0']:.3g}, {d['lit_share']:.0%} of the pixels): "
            f"mean {d['mean']:.3f}, median {d['median']:.3f}")


def run_stokes(files: Sequence[Path], out_dir: Path, *, layout: str | None, demosaic: str | None,
               resolution: str, fmt: str, quiet: bool = False,
               max_pixels: int | None = None) -> dict[str, Any]:
    """Every frame of ``files`` through the pipeline's Stokes products into ``out_dir/<stem>/``.

    Returns the summary written to ``out_dir/summary.json`` (``done``,
    ``failed``: input and error of each bad frame, ``frames``: each frame's meta).  ``demosaic``:
    the demosaicing method (None: the registry's default for each frame's layout).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    done: list[dict[str, Any]] = []
    failed: list[dict[str, str]] = []
    for path in files:
        t0 = time.perf_counter()
        try:
            frame = require_layout(read_frame(path, layout=layout, max_pixels=max_pixels), str(path))
            dem = resolve_demosaic(demosaic, frame.layout)
            result = run_frame(frame, demosaic=dem, resolution=resolution, stokes_products=PRODUCTS)
            target = out_dir / path.stem
            lit = dolp_of_lit(result.products["s0"], result.products["dolp"],
                              lit_floor(frame.black_level, frame.white_level))
            meta = {"input": str(path), "layout": str(frame.layout),
                    "demosaic": dem.method,
                    "resolution": resolution, "polcam_version": __version__,
                    "bit_depth": frame.bit_depth, "black_level": frame.black_level,
                    "white_level": frame.white_level,
                    "dolp_lit": {k: (None if math.isnan(v) else v) for k, v in lit.items()}}
            write_products(target, result.products, fmt=fmt, unit=UNIT_RANGE, metadata=meta)
            seconds = time.perf_counter() - t0
            meta["seconds"] = seconds
            meta["shape"] = list(result.stack.shape)
            write_meta(target, meta)
            done.append(meta)
            if not quiet:
                print(f"{path.name}: {frame.layout} {result.stack.shape} -> {target}  {_dolp_text(lit)}  "
                      f"{seconds:.2f} s")
        except (PolcamError, OSError) as exc:
            failed.append({"input": str(path), "error": str(exc)})
            print(f"error: {exc}", file=sys.stderr)
    summary = {"done": len(done), "failed": failed, "frames": done}
    with atomic_write(out_dir / "summary.json", "w") as fh:
        json.dump(summary, fh, indent=2)
    return summary


def cmd_stokes(args: argparse.Namespace) -> int:
    """Run ``polcam stokes``; returns the exit status."""
    files = list_raw_files(args.inputs, recursive=args.recursive)
    if not files:
        print(f"error: no raw frames found in {', '.join(map(str, args.inputs))}", file=sys.stderr)
        return 2
    check_run_options(layout=args.layout, demosaic=args.demosaic, resolution=args.resolution,
                      fmt=args.format)
    summary = run_stokes(files, args.out, layout=args.layout, demosaic=args.demosaic,
                         resolution=args.resolution, fmt=args.format, quiet=args.quiet,
                         max_pixels=args.max_pixels)
    print(f"{summary['done']} frame(s) written to {args.out}, {len(summary['failed'])} failed")
    return 1 if summary["failed"] else 0


def add_parser(sub: Any, demosaic_methods: Sequence[str]) -> argparse.ArgumentParser:
    """Add ``stokes`` to the sub-parsers."""
    s = sub.add_parser("stokes", help="demosaic raw frames and write the stack, S0-S2, DoLP, AoLP",
                       description="Read raw polarization mosaics (png/tif/pgm/bmp/raw/npy/dng), "
                                   "demosaic them and write, per frame, OUT/<stem>/ with i000..i135 "
                                   "(the four angle images), s0, s1, s2, dolp (0..1), aolp (radians in "
                                   "[0, pi) from the image x axis), residual ((I0+I90)-(I45+I135)) and "
                                   "meta.json; OUT/summary.json lists done and failed frames. Each frame's "
                                   "line gives the DoLP of its lit pixels: S0 at least 35 quantisation "
                                   "steps of the frame, where noise of one step adds at most 0.05 to the "
                                   "DoLP (meta.json: dolp_lit).")
    s.add_argument("inputs", nargs="+", type=Path, help="raw frame files or folders")
    s.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    s.add_argument("--layout", help="sensor layout (imx250mzr, imx250myr, mono:A,B,C,D, "
                                    "color:A,B,C,D:BAYER); default: from the sidecar / pixel format")
    s.add_argument("--demosaic", choices=demosaic_methods,
                   help="demosaicing method (default: the best for the frame's layout, "
                        "polcam.demosaicing.default_method)")
    s.add_argument("--resolution", default="full", choices=("full", "cell"),
                   help="full: one output pixel per sensor pixel (default); cell: one per 2x2 polarizer cell")
    s.add_argument("--format", default="exr", choices=tuple(FORMATS),
                   help="exr (float32, default), tiff (float32) or tiff16 (uint16 scaled from [0, 1]; "
                        "signed maps stay float32)")
    add_max_pixels_argument(s)
    s.add_argument("--recursive", action="store_true", help="descend into sub-folders")
    s.add_argument("--quiet", action="store_true", help="print only the final line and errors")
    s.set_defaults(func=cmd_stokes)
    return s
