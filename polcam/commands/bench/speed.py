"""``polcam bench speed``: its options, and the printing of what :mod:`polcam.bench.speed`,
:mod:`polcam.bench.maps` and :mod:`polcam.bench.targets` measure."""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

from polcam.bench import maps, speed, targets
from polcam.bench.speed import load_average
from polcam.bench.targets import device_name
from polcam.commands._args import positive_int
from polcam.errors import MethodError
from polcam.io.atomic import atomic_write
from polcam.separation import method_spec

__all__ = ["add_arguments", "run_args"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the options of ``polcam bench speed`` to a parser."""
    p.add_argument("--sizes", type=int, nargs="*",
                   help="sides of the synthetic scenes (128 256 512 when --method is given; none: the frame "
                        "alone); without --sizes, --method and --maps: every speed target's figure")
    p.add_argument("--scenes", nargs="+", default=["Bunny4"], help="synthetic scenes (default Bunny4)")
    p.add_argument("--exact-max", type=int, default=256,
                   help="largest side the exact solver runs at (default 256)")
    p.add_argument("--no-frame", action="store_true", help="skip the full sensor frame")
    p.add_argument("--full-resolution", action="store_true",
                   help="also the full frame at full resolution (2448 x 2048 per angle)")
    p.add_argument("--frame-scene", default="Bunny5", help="scene rendered for the sensor frame (default Bunny5)")
    p.add_argument("--method",
                   help="method timed (tensor: its exact and fast solvers, the default with --sizes; another "
                        "method is timed alone, e.g. polarized-residual)")
    p.add_argument("--device", help="PyTorch device for the tensor method's fast solver or polarized-residual "
                                    "(default: numpy)")
    p.add_argument("--tol", type=float, help="stopping tolerance of the fast solver")
    p.add_argument("--workers", type=positive_int, help="threads (default: CPU count)")
    p.add_argument("--seed", type=int, default=0, help="render seed (default 0)")
    p.add_argument("--json", type=Path, help="also write the rows to this file")
    p.add_argument("--maps", action="store_true",
                   help="instead: raw frame to S0, DoLP and AoLP, polanalyser's route and polcam's "
                        "(bilinear, default demosaicing) on one 2448 x 2048 frame, mono and colour, "
                        "as ratios (polcam.bench.maps)")
    p.add_argument("--repeat", type=int, default=5,
                   help="--maps and the targets' maps: best of this many runs (default 5)")


def run_args(a: argparse.Namespace) -> int:
    """Run ``polcam bench speed`` with parsed options; print the table."""
    targets = not getattr(a, "maps", False) and a.sizes is None and a.method is None and a.tol is None \
        and a.workers is None and not a.no_frame and not a.full_resolution
    if a.device and (targets or getattr(a, "maps", False)):
        _print_device(a.device)
    if getattr(a, "maps", False):
        return _run_maps(a)
    if targets:
        return _run_targets(a)
    a.sizes = [128, 256, 512] if a.sizes is None else a.sizes
    a.method = a.method or "tensor"
    options: dict[str, Any] = {}
    if a.method != "tensor" and (a.tol is not None or a.workers is not None):
        raise MethodError(f"bench speed: --tol and --workers are the tensor method's options, "
                          f"not {a.method!r}'s")
    if a.device and a.method != "tensor":
        if "device" not in (method_spec(a.method).options or ()):
            raise MethodError(f"bench speed: --device: method {a.method!r} has no PyTorch backend "
                              "(tensor and polarized-residual have)")
    if a.device:
        _print_device(a.device)
        options["device"] = a.device
    if a.tol is not None:
        options["tol"] = a.tol
    if a.workers is not None:
        options["workers"] = a.workers
    print(f"CPU count {os.cpu_count()}, load average {load_average():.2f}")
    rows = speed.run(sizes=a.sizes, scenes=a.scenes, exact_max=a.exact_max, frame=not a.no_frame,
               full_resolution=a.full_resolution, frame_scene=a.frame_scene, options=options,
               seed=a.seed, method=a.method)
    names = sorted({r.device for r in rows if r.device})
    if names:
        print(f"device: {', '.join(names)}")
    _report(a, speed.format_markdown(rows), [asdict(r) for r in rows])
    return 0


def _report(a: argparse.Namespace, markdown: str, records: list[dict[str, Any]]) -> None:
    """Print a table, and write its rows to ``--json`` when given."""
    print(markdown)
    if a.json:
        with atomic_write(a.json, "w") as fh:
            json.dump(records, fh, indent=1)
        print(f"wrote {a.json}")


def _print_device(device: str) -> None:
    """Print the device's name (a GPU's model); MethodError when it is not available."""
    print(f"device {device}: {device_name(device)}", flush=True)


def _run_targets(a: argparse.Namespace) -> int:
    if a.device:
        print("the figures below run on the CPU: the maps and wen21 have no PyTorch backend")
    print(f"CPU count {os.cpu_count()}, load average {load_average():.2f}")
    rows = targets.run(repeat=a.repeat, scene=a.frame_scene)
    print(f"load average {load_average():.2f}")
    _report(a, targets.format_markdown(rows), [dict(asdict(r), met=r.met) for r in rows])
    return 0


def _run_maps(a: argparse.Namespace) -> int:
    print(f"CPU count {os.cpu_count()}, load average {load_average():.2f}")
    rows = maps.run(repeat=a.repeat, scene=a.frame_scene)
    print(f"load average {load_average():.2f}")
    _report(a, maps.format_markdown(rows), [asdict(r) for r in rows])
    return 0
