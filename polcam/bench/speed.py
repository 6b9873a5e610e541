"""``polcam bench speed``: the tensor method's exact and fast solvers on the same inputs (or one other method).

Cases:

* synthetic scenes (:mod:`polcam.synth.scenes`, default Bunny4) rendered at
  each ``--sizes`` side: the exact solver (up to ``--exact-max``) and the fast
  one on the same stack (with its default tiling, and above
  :data:`~polcam.separation.tensor.AUTO_UNTILED_PIXELS` also as one tile, the
  exact solver's problem), with seconds, the speed ratio, the PSNR of the diffuse
  layer against the ground truth and its difference between the solvers, the
  PSNR of the fast result against the exact one, iterations, tiles and peak
  memory;
* a full sensor frame (``--frame``): a 2448 x 2048 IMX250MYR raw mosaic made from
  a render of ``--frame-scene`` (1224 x 1224, repeated 2 x 2 and cropped), taken
  from raw to diffuse and specular with the fast solver at the polarizer-cell
  resolution (1224 x 1024 per angle) and, with ``--full-resolution``, at full
  resolution; the seconds include bilinear demosaicing.

With ``--maps`` it times the route from a raw frame to S0, DoLP and AoLP
instead, polcam's beside polanalyser's (:mod:`polcam.bench.maps`).  With none
of ``--sizes``, ``--method``, ``--maps`` (nor the solver's ``--tol``, ``--workers``,
``--no-frame``, ``--full-resolution``) it prints every speed target's figure
in one run (:mod:`polcam.bench.targets`: the maps' ratios, wen21 and the colour
default at cell resolution, a raw frame to layers).  ``--device`` names the
device first (a GPU's model), or fails with an error when it is not available.

With ``--method NAME`` (any registered method, e.g. ``polarized-residual``)
that method alone is timed on the same cases (one row per case, no exact solver);
``--device`` runs it on a PyTorch device where the method has that backend
(``polarized-residual``).

Every case runs in a fresh Python process and is timed there around the work
only.  Peak memory is the largest proportional set size (PSS: shared pages
split between the processes sharing them) of that process and its worker
processes together, sampled every 0.1 s during the work (on Linux; elsewhere
the process's largest resident set); it includes the interpreter and
libraries (about 150 MB).  The machine is usually shared: the load average
before and after each case is recorded.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polcam.bench.quality import psnr
from polcam.demosaicing import demosaic
from polcam.parallel import start_workers
from polcam.separation import method_spec, separate
from polcam.separation.tensor import AUTO_UNTILED_PIXELS, warm_up
from polcam.synth.render import mosaic, render
from polcam.synth.scenes import scene

__all__ = ["SpeedRow", "format_markdown", "load_average", "measure", "run"]


@dataclass
class SpeedRow:
    """One solver on one input."""

    case: str
    solver: str
    height: int
    width: int
    seconds: float
    iterations: int
    converged: bool
    tiles: int
    peak_mb: float
    psnr: float = float("nan")            # diffuse against the ground truth (synthetic scenes)
    psnr_delta: float = float("nan")      # this solver's PSNR minus the exact solver's
    psnr_vs_exact: float = float("nan")   # this solver's diffuse against the exact one's
    speedup: float = float("nan")         # exact seconds / these seconds
    load: tuple[float, float] = (float("nan"), float("nan"))
    options: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    device: str = ""                      # the torch device's name (fast solver with device=)
    device_peak_mb: float = float("nan")  # its largest allocation (CUDA), MB
    error: str = ""


def _full_frame_raw(scene_name: str, seed: int) -> np.ndarray:

    r = render(scene(scene_name), size=1224, seed=seed)
    st = np.tile(r.stack, (1, 2, 2, 1))[:, :2048, :2448]
    return mosaic(st, "imx250myr")


def _pss_mb(pid: int) -> float:
    """Proportional set size of a process and its descendants (Linux), MB; nan elsewhere.

    Shared pages (a forked worker's copy-on-write view of its parent) count once,
    split between the processes sharing them, so the sum is the memory in use.
    """
    total = 0.0
    stack = [pid]
    try:
        while stack:
            p = stack.pop()
            with open(f"/proc/{p}/smaps_rollup") as fh:
                for line in fh:
                    if line.startswith("Pss:"):
                        total += float(line.split()[1]) / 1024
                        break
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as fh:
                    stack += [int(c) for c in fh.read().split()]
    except (OSError, ValueError):
        return float("nan") if total == 0 else total
    return total


class _PeakMemory:
    """Largest :func:`_pss_mb` of this process tree, sampled every ``period`` seconds."""

    def __init__(self, period: float = 0.1) -> None:
        import threading

        self.peak = _pss_mb(os.getpid())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period,), daemon=True)

    def _run(self, period: float) -> None:
        while not self._stop.wait(period):
            v = _pss_mb(os.getpid())
            if v == v:
                self.peak = max(self.peak, v) if self.peak == self.peak else v

    def __enter__(self) -> _PeakMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def measure(case: dict[str, Any]) -> dict[str, Any]:
    """Run one case in this process and return its figures (used by the child processes).

    ``case`` keys: ``kind`` (``"scene"`` or ``"frame"``), ``scene``, ``size`` (scene
    side), ``resolution`` (frame: ``"cell"`` or ``"full"``), ``seed``,
    ``options`` (separation options, e.g. ``{"solver": "exact"}``), ``method``
    (default ``"tensor"``), ``save`` (a .npy path for the diffuse layer, or None).
    """
    import resource
    import time


    opts = dict(case.get("options", {}))
    method = case.get("method", "tensor")
    device_name, cuda = "", False
    if opts.get("device"):
        import torch

        if method == "tensor":
            warm_up(opts["device"])    # the device's one-off start stays out of the figure
        else:
            rng = np.random.default_rng(0)
            separate(rng.uniform(0.1, 0.6, (4, 100, 70, 3)), method=method, device=opts["device"])
        dev = torch.device(opts["device"])
        cuda = dev.type == "cuda"
        device_name = torch.cuda.get_device_name(dev) if cuda else str(dev)
        if cuda:
            torch.cuda.reset_peak_memory_stats(dev)
    truth = None
    if case["kind"] == "scene":

        r = render(scene(case["scene"]), size=case["size"], seed=case.get("seed", 0))
        stack, truth = r.stack, r.diffuse
        del r
        with _PeakMemory() as mem:
            start_workers()  # the sampling thread means a fork server: started before the clock
            t0 = time.perf_counter()
            res = separate(stack, method=method, **opts)
            seconds = time.perf_counter() - t0
    else:
        raw = _full_frame_raw(case["scene"], case.get("seed", 0))
        with _PeakMemory() as mem:
            start_workers()
            t0 = time.perf_counter()
            stack = demosaic(raw, layout="imx250myr", method="bilinear", resolution=case["resolution"])
            res = separate(stack, method=method, **opts)
            seconds = time.perf_counter() - t0
    device_peak = float("nan")
    if cuda:
        import torch

        device_peak = torch.cuda.max_memory_allocated(torch.device(opts["device"])) / 2**20
    peak = mem.peak
    if peak != peak:                       # no /proc: the largest resident set (this process)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if case.get("save"):
        np.save(case["save"], res.diffuse)
    info = res.info
    return {
        "height": int(stack.shape[1]), "width": int(stack.shape[2]), "seconds": seconds,
        "iterations": int(info.get("iterations", 0)), "converged": bool(info.get("converged")),
        "tiles": int(info.get("tiles", 1)), "peak_mb": peak,
        "psnr": psnr(np.clip(res.diffuse, 0, 1), truth) if truth is not None else float("nan"),
        "timings": {k: float(v) for k, v in info.get("timings", {}).items()},
        "device": device_name, "device_peak_mb": device_peak,
    }


def load_average() -> float:
    """The 1-minute load average (NaN where the system does not report one)."""
    try:
        return os.getloadavg()[0]
    except OSError:  # pragma: no cover - not on Linux
        return float("nan")


def _child(case: dict[str, Any]) -> dict[str, Any]:
    """:func:`measure` in a fresh interpreter."""
    code = ("import json, sys\nfrom polcam.bench.speed import measure\n"
            "from polcam.parallel import commands_own_main\n"
            "with commands_own_main():  # this child is polcam's own: as in polcam process\n"
            "    print(json.dumps(measure(json.loads(sys.argv[1]))))")
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(case)], capture_output=True,
                          text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark case {case} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(*, sizes: Sequence[int] = (128, 256, 512), scenes: Sequence[str] = ("Bunny4",),
        exact_max: int = 256, frame: bool = True, full_resolution: bool = False,
        frame_scene: str = "Bunny5", options: dict[str, Any] | None = None, seed: int = 0,
        progress: bool = True, isolate: bool = True, method: str = "tensor") -> list[SpeedRow]:
    """Time the exact and fast solvers (or one other method).

    Parameters
    ----------
    sizes
        Sides of the square synthetic scenes.
    scenes
        Scene names (:func:`polcam.synth.scenes.scene`).
    exact_max
        Largest side the exact solver runs at (it takes minutes beyond 256).
    frame, full_resolution
        Also the full sensor frame at the cell resolution, and at full resolution.
    frame_scene
        Scene rendered for the frame.
    options
        Extra options of the fast solver (e.g. ``{"device": "cpu"}``, ``{"tol": 1e-3}``).
    seed
        Rendering seed.
    progress
        Print each row as it is measured.
    isolate
        Run each case in a fresh process (for its own peak memory); False runs
        them here (tests).
    method
        ``"tensor"`` (the exact and fast solvers), or another registered method,
        timed alone with ``options`` as its options.

    Returns
    -------
    list of SpeedRow
    """
    method_spec(method)                              # unknown names refused before any work
    fast_opts = {"solver": "fast", **(options or {})} if method == "tensor" else dict(options or {})
    rows: list[SpeedRow] = []
    go = _child if isolate else measure
    with tempfile.TemporaryDirectory() as tmp:
        cases: list[tuple[str, str, dict[str, Any]]] = []
        for name in scenes:
            for size in sizes:
                base = {"kind": "scene", "scene": name, "size": int(size), "seed": seed, "method": method}
                label = f"{name} {size}x{size}"
                if method != "tensor":
                    cases.append((label, method, {**base, "options": fast_opts}))
                    continue
                if size <= exact_max:
                    cases.append((label, "exact", {**base, "options": {"solver": "exact"}}))
                cases.append((label, "fast", {**base, "options": fast_opts}))
                if size * size > AUTO_UNTILED_PIXELS and "tile" not in fast_opts and size <= exact_max:
                    # the default tiles above that size; the untiled fast solver is the exact one's problem
                    cases.append((label, "fast, one tile", {**base, "options": {**fast_opts, "tile": size}}))
        if frame:
            for res_name in ("cell",) + (("full",) if full_resolution else ()):
                cases.append((f"2448x2048 raw, {res_name} resolution", "fast" if method == "tensor" else method,
                              {"kind": "frame", "scene": frame_scene, "resolution": res_name,
                               "seed": seed, "options": fast_opts, "method": method}))
        exact_rows: dict[str, tuple[SpeedRow, str]] = {}
        for n, (label, solver, case) in enumerate(cases):
            path = str(Path(tmp) / f"{n}.npy")
            case = {**case, "save": path}
            before = load_average()
            try:
                got = go(case)
            except (RuntimeError, MemoryError) as exc:   # report the case, go on with the others
                rows.append(SpeedRow(case=label, solver=solver, height=0, width=0, seconds=float("nan"),
                                     iterations=0, converged=False, tiles=0, peak_mb=float("nan"),
                                     load=(before, load_average()), options=dict(case["options"]),
                                     error=str(exc).strip().splitlines()[-1][:200]))
                if progress:
                    print(f"  {label} {solver}: failed: {rows[-1].error}", flush=True)
                continue
            row = SpeedRow(case=label, solver=solver, height=got["height"], width=got["width"],
                           seconds=got["seconds"], iterations=got["iterations"],
                           converged=got["converged"], tiles=got["tiles"], peak_mb=got["peak_mb"],
                           psnr=got["psnr"], load=(before, load_average()), options=dict(case["options"]),
                           timings=got["timings"], device=got.get("device", ""),
                           device_peak_mb=got.get("device_peak_mb", float("nan")))
            if solver == "exact":
                exact_rows[label] = (row, path)
            elif label in exact_rows and not math.isnan(exact_rows[label][0].seconds):
                ref, ref_path = exact_rows[label]
                row.psnr_delta = row.psnr - ref.psnr
                row.psnr_vs_exact = psnr(np.load(path), np.load(ref_path))
                row.speedup = ref.seconds / row.seconds
            rows.append(row)
            if progress:
                print(_line(row), flush=True)
    return rows


def _f(x: float, fmt: str) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def _line(r: SpeedRow) -> str:
    return (f"  {r.case:<32} {r.solver:<14} {r.seconds:8.2f} s  x{_f(r.speedup, '.1f'):>5}  "
            f"PSNR {_f(r.psnr, '.2f')} (d {_f(r.psnr_delta, '+.3f')})  it {r.iterations}  "
            f"tiles {r.tiles}  peak {_peak(r)} MB  load {r.load[0]:.1f}/{r.load[1]:.1f}")


def _peak(r: SpeedRow) -> str:
    """Host peak memory, and the device's beside it where one was used."""
    gpu = "" if math.isnan(r.device_peak_mb) else f" + GPU {r.device_peak_mb:.0f}"
    return f"{r.peak_mb:.0f}{gpu}"


def format_markdown(rows: Sequence[SpeedRow]) -> str:
    """Markdown table of the rows."""
    head = ("| input | solver | H x W | seconds | speed-up | PSNR (dB) | PSNR fast - exact | "
            "fast vs exact (dB) | iterations | tiles | peak memory (MB) | load before/after |")
    lines = [head, "|---" * 12 + "|"]
    for r in rows:
        if r.error:
            lines.append(f"| {r.case} | {r.solver} | failed: {r.error} |" + " |" * 9)
            continue
        lines.append(
            f"| {r.case} | {r.solver} | {r.height} x {r.width} | {r.seconds:.2f} | "
            f"{_f(r.speedup, '.1f')} | {_f(r.psnr, '.2f')} | {_f(r.psnr_delta, '+.3f')} | "
            f"{_f(r.psnr_vs_exact, '.1f')} | {r.iterations} | {r.tiles} | {_peak(r)} | "
            f"{r.load[0]:.1f} / {r.load[1]:.1f} |")
    return "\n".join(lines)
