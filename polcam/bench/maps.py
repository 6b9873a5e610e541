"""``polcam bench speed --maps``: raw frame to Stokes, DoLP and AoLP, polcam beside polanalyser.

One 2448 x 2048 raw frame (a render of a synthetic scene, 12-bit counts in
16 bits, mosaicked for the IMX250MZR and the IMX250MYR) goes to a
full-resolution stack and its S0, DoLP and AoLP by three routes, in the same
process, each timed best of ``repeat``:

* ``polanalyser``: polanalyser's ``demosaicing`` (its bilinear OpenCV route),
  ``calcStokes`` with the four polarizer angles, ``cvtStokesToDoLP`` and
  ``cvtStokesToAoLP`` (as its users run it: counts, colour in OpenCV's BGR order);
* ``polcam bilinear``: :func:`polcam.demosaic` with ``method="bilinear"``
  and :func:`polcam.pipeline.products` (``s0``, ``dolp``, ``aolp``: one fused
  pass, :func:`polcam.polarimetry.maps`);
* ``polcam default``: the same with the default demosaicing of the layout
  (``eari`` mono, ``lmmse`` colour).

Both the wall-clock seconds and the process's CPU seconds are reported, with
each route's ratio to polanalyser's (above 1: faster than polanalyser).  On a
shared machine the wall-clock figures include waiting for the CPU; the CPU
seconds (all threads together) are the steadier comparison of work done.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from polcam import pipeline
from polcam.demosaicing import default_method, demosaic
from polcam.errors import MethodError
from polcam.mosaic import parse_layout
from polcam.synth.render import mosaic, render
from polcam.synth.scenes import scene as make_scene

__all__ = ["MapsRow", "format_markdown", "frame", "routes", "run"]

ANGLES_DEG = (0.0, 45.0, 90.0, 135.0)


@dataclass
class MapsRow:
    """One route on one layout."""

    layout: str
    route: str
    seconds: float          # best wall-clock seconds
    cpu_seconds: float      # best CPU seconds of the process (all threads)
    ratio: float = float("nan")       # polanalyser's seconds / these (wall clock)
    cpu_ratio: float = float("nan")   # the same with CPU seconds


def frame(layout: str, *, scene: str = "Bunny5", seed: int = 0) -> np.ndarray:
    """A 2448 x 2048 uint16 raw mosaic (12-bit counts) of a rendered ``scene`` for ``layout``."""
    r = render(make_scene(scene), size=1224, seed=seed)
    st = np.tile(r.stack, (1, 2, 2, 1))[:, :2048, :2448]
    return np.round(np.clip(mosaic(st, layout), 0.0, 1.0) * 4095.0).astype(np.uint16)


def routes(layout: str) -> dict[str, Callable[[np.ndarray], Any]]:
    """The timed routes for ``layout``: name -> ``fn(raw) -> (s0, dolp, aolp)``."""
    import polanalyser as pa

    code = pa.COLOR_PolarRGB if parse_layout(layout).is_color else pa.COLOR_PolarMono
    angles = np.deg2rad(np.array(ANGLES_DEG))

    def peer(raw: np.ndarray) -> Any:
        images = pa.demosaicing(raw, code)
        s = pa.calcStokes(images, angles)
        with np.errstate(divide="ignore", invalid="ignore"):  # its DoLP divides by S0 = 0 in the dark
            return s[..., 0], pa.cvtStokesToDoLP(s), pa.cvtStokesToAoLP(s)

    def ours(method: str) -> Callable[[np.ndarray], Any]:
        def fn(raw: np.ndarray) -> Any:
            stack = demosaic(raw, layout=layout, method=method)
            m = pipeline.products(stack, ("s0", "dolp", "aolp"))
            return m["s0"], m["dolp"], m["aolp"]

        return fn

    return {"polanalyser": peer, "polcam bilinear": ours("bilinear"),
            f"polcam default ({default_method(layout)})": ours(default_method(layout))}


def _best(fn: Callable[[], Any], repeat: int) -> tuple[float, float]:
    wall, cpu = math.inf, math.inf
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall, cpu = min(wall, time.perf_counter() - w0), min(cpu, time.process_time() - c0)
    return wall, cpu


def run(*, repeat: int = 5, layouts: Sequence[str] = ("imx250mzr", "imx250myr"), scene: str = "Bunny5",
        progress: bool = True) -> list[MapsRow]:
    """Time every route on each layout's frame (interleaved: one round of every route, ``repeat`` times).

    Returns
    -------
    list of MapsRow
        Per layout, polanalyser's row first (ratio 1), then polcam's.

    Raises
    ------
    MethodError
        polanalyser is not installed.
    """
    try:
        import polanalyser  # noqa: F401
    except ImportError:
        raise MethodError("bench speed --maps needs polanalyser (pip install polanalyser)") from None
    rows: list[MapsRow] = []
    for layout in layouts:
        raw = frame(layout, scene=scene)
        fns = routes(layout)
        for fn in fns.values():   # warm-up: imports, OpenCV's thread pool, first-touch pages
            fn(raw)
        best = {name: (math.inf, math.inf) for name in fns}
        for _ in range(repeat):   # rounds interleave the routes, so load drifts hit them alike
            for name, fn in fns.items():
                w, c = _best(lambda fn=fn: fn(raw), 1)
                best[name] = (min(best[name][0], w), min(best[name][1], c))
        ref_w, ref_c = best["polanalyser"]
        for name, (w, c) in best.items():
            rows.append(MapsRow(layout=layout, route=name, seconds=w, cpu_seconds=c,
                                ratio=ref_w / w, cpu_ratio=ref_c / c))
            if progress:
                print(f"  {layout:<10} {name:<26} {w:7.3f} s  cpu {c:7.3f} s  "
                      f"x{ref_w / w:5.2f} (cpu x{ref_c / c:5.2f})", flush=True)
    return rows


def format_markdown(rows: Sequence[MapsRow]) -> str:
    """Markdown table of the rows."""
    lines = ["| layout | route | seconds | CPU seconds | speed vs polanalyser | CPU vs polanalyser |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.layout} | {r.route} | {r.seconds:.3f} | {r.cpu_seconds:.3f} | "
                     f"{r.ratio:.2f} | {r.cpu_ratio:.2f} |")
    return "\n".join(lines)
