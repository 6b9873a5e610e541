"""``polcam bench speed`` with no case chosen: every speed target's figure in one run.

On one 2448 x 2048 raw frame (:func:`polcam.bench.maps.frame`, a render of
``scene``), in this process:

* **maps** (:func:`polcam.bench.maps.run`): raw frame to S0, DoLP and AoLP by
  polanalyser's route and polcam's, mono and colour, best of ``repeat``, as the
  ratio polanalyser's seconds / polcam's (targets: ``bilinear`` >= 2, the
  default demosaicing >= 1);
* **separation at cell resolution**: the colour frame demosaiced to a
  1224 x 1024 stack (``bilinear``, ``resolution="cell"``, the live view's stack)
  and separated by :func:`polcam.separate` with ``wen21`` (target <= 0.6 s) and
  with the colour default (:func:`polcam.separation.default_method`, target
  <= 1 s), best of ``sep_repeat``;
* **raw to layers**: the colour frame through :func:`polcam.pipeline.run_frame`
  at cell resolution with the default separation (demosaicing, maps and the
  layers), best of ``sep_repeat``; its inverse is the layer rate a free core
  could sustain.

The live rates (maps >= 20 fps, layers >= 1 fps) are measured by ``polcam
capture`` itself (``maps_fps`` and ``layers_fps`` in its summary).  Wall-clock
seconds on a shared machine include waiting for the CPU: the load average is
printed before and after.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import polcam
from polcam import pipeline
from polcam.bench import maps
from polcam.demosaicing import default_method as default_demosaic
from polcam.errors import MethodError
from polcam.frame import Frame
from polcam.mosaic import parse_layout
from polcam.separation import default_method

__all__ = ["TargetRow", "device_name", "format_markdown", "run"]

COLOUR = "imx250myr"


@dataclass
class TargetRow:
    """One figure beside its target."""

    figure: str
    value: float
    unit: str          # "x" (speed ratio, higher is better) or "s" (seconds, lower is better)
    target: float

    @property
    def met(self) -> bool:
        """Whether the figure meets its target."""
        return self.value >= self.target if self.unit == "x" else self.value <= self.target


def device_name(device: str) -> str:
    """The name of the PyTorch ``device`` (a GPU's model name for ``cuda``).

    Raises
    ------
    MethodError
        PyTorch is missing, the name is not a device, or no CUDA GPU is available.
    """
    try:
        import torch
    except ImportError:
        none = "no GPU available: " if device.startswith("cuda") else ""
        raise MethodError(f"bench speed --device {device}: {none}PyTorch is not installed "
                          "(pip install 'polcam[torch]')") from None
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise MethodError(f"bench speed --device {device}: not a torch device name ({exc})") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise MethodError(f"bench speed --device {device}: no CUDA GPU available "
                              f"(PyTorch {torch.__version__} sees none)")
        return str(torch.cuda.get_device_name(dev))
    return str(dev)


def _best(fn: Callable[[], Any], repeat: int) -> float:
    fn()  # warm-up: imports, thread pools, first-touch pages
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run(*, repeat: int = 5, sep_repeat: int = 3, scene: str = "Bunny5", progress: bool = True) -> list[TargetRow]:
    """Measure every figure (module docstring).

    Returns
    -------
    list of TargetRow
        Maps ratios (mono, colour), separation seconds, raw-to-layers seconds.

    Raises
    ------
    MethodError
        polanalyser is not installed (the maps' reference route).
    """

    rows: list[TargetRow] = []
    for r in maps.run(repeat=repeat, scene=scene, progress=progress):
        if r.route == "polanalyser":
            continue
        kind = "colour" if parse_layout(r.layout).is_color else "mono"
        default = r.route.startswith("polcam default")
        what = f"default ({default_demosaic(r.layout)})" if default else "bilinear"
        rows.append(TargetRow(f"maps, {kind}: polcam {what} vs polanalyser", r.ratio, "x", 1.0 if default else 2.0))
    raw = maps.frame(COLOUR, scene=scene)
    stack = polcam.demosaic(raw, layout=COLOUR, method="bilinear", resolution="cell")
    h, w = stack.shape[1:3]
    colour_default = default_method("stack")
    seconds: dict[str, float] = {}
    for method in dict.fromkeys(("wen21", colour_default)):
        seconds[method] = _best(lambda m=method: polcam.separate(stack, method=m), sep_repeat)
        if progress:
            print(f"  separate {method:<20} {w} x {h}  {seconds[method]:.3f} s", flush=True)
    rows.append(TargetRow(f"separation, wen21, {w} x {h} colour", seconds["wen21"], "s", 0.6))
    rows.append(TargetRow(f"separation, colour default ({colour_default}), {w} x {h}", seconds[colour_default], "s", 1.0))
    frame = Frame(mosaic=raw, layout=parse_layout(COLOUR), bit_depth=12)
    t = _best(lambda: pipeline.run_frame(frame, demosaic="bilinear", resolution="cell", separate=True), sep_repeat)
    if progress:
        print(f"  raw {raw.shape[1]} x {raw.shape[0]} -> layers ({colour_default}, cell)  {t:.3f} s", flush=True)
    # the live layers' target (>= 1 fps) as the time one frame's route may take
    rows.append(TargetRow(f"raw {raw.shape[1]} x {raw.shape[0]} colour -> maps and layers ({colour_default}, cell)",
                          t, "s", 1.0))
    return rows


def format_markdown(rows: list[TargetRow]) -> str:
    """Markdown table of the figures, their targets and whether each is met."""
    lines = ["| figure | value | target | met |", "|---|---|---|---|"]
    for r in rows:
        value = f"{r.value:.2f}x" if r.unit == "x" else f"{r.value:.3f} s"
        target = f">= {r.target:g}x" if r.unit == "x" else f"<= {r.target:g} s"
        lines.append(f"| {r.figure} | {value} | {target} | {'yes' if r.met else 'no'} |")
    return "\n".join(lines)
