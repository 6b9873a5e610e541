"""``polcam bench stability``: how much a separation method's layer moves when its input barely does.

Two measurements per synthetic scene (:mod:`polcam.synth.scenes`) and method, on the object mask:

* **continuity**: every sample below the white level (0.98) multiplied by ``1 + N(0, rel)``
  (default ``rel`` 3e-7, far below any camera's noise; clipped samples stay at the white level, as a
  real clipped sample does), for three seeds; the largest change of the diffuse layer, and the share
  of object pixels that move by more than 1e-3.  A method without hard switches moves by about
  ``rel`` times the signal; a jump shows a switch that rounding can flip.
* **flicker**: the scene rendered with ``frames`` noise seeds (frames of a static scene), each
  separated; the 99th percentile and the largest per-pixel standard deviation of the diffuse
  layer over the frames (the largest over the colour channels), and the mean object PSNR.  With
  ``hold_illuminant``, a method that estimates the illuminant gets the first frame's estimate on
  the later frames, as ``polcam capture`` does by default
  (:class:`polcam.acquisition.live.LiveProcessor`).

docs/methods/polarized-residual.md ("Stability") reports both for
``polarized-residual``; ``imin`` is the reference of a method with no switch.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from polcam.bench.quality import score
from polcam.errors import MethodError
from polcam.io.atomic import atomic_write
from polcam.separation import SATURATED, estimated_illuminant, separate, takes_illuminant
from polcam.synth.render import render
from polcam.synth.scenes import scene

__all__ = ["StabilityRow", "perturbed", "run", "format_markdown", "write_outputs"]


@dataclass(frozen=True)
class StabilityRow:
    """One scene and method.

    Attributes
    ----------
    jump
        Largest change of the diffuse layer (object pixels, any channel) under the perturbation.
    jump_share
        Share of object pixels that moved by more than 1e-3 (the largest over the seeds).
    flicker_p99, flicker_max
        99th percentile and largest per-pixel standard deviation over the frames (object pixels).
    psnr
        Mean object PSNR (dB) of the frames' diffuse layers against the truth.
    held
        Whether the first frame's illuminant estimate was passed to the later frames.
    """

    scene: str
    method: str
    jump: float
    jump_share: float
    flicker_p99: float
    flicker_max: float
    psnr: float
    held: bool


def perturbed(stack: np.ndarray, rel: float, seed: int) -> np.ndarray:
    """``stack`` with every sample below the white level multiplied by ``1 + N(0, rel)`` (float32, same shape).

    The white level is the one the separation methods treat as clipped (:data:`polcam.separation.SATURATED`):
    a clipped sample stays as it is, as a real one does.
    """
    s = np.asarray(stack, dtype=np.float32)
    noise = np.random.default_rng(seed).normal(0.0, rel, s.shape)
    return np.where(s >= SATURATED, s, s * (1.0 + noise)).astype(np.float32)


def _object(layer: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-pixel largest channel of ``layer`` ((H, W) or (H, W, 3)) on the object ``mask``."""
    a = np.asarray(layer)
    return (a.max(axis=-1) if a.ndim == 3 else a)[mask]


def run(*, scenes: Sequence[str], methods: Sequence[str], size: int = 96, frames: int = 6,
        rel: float = 3e-7, hold_illuminant: bool = False, mono: bool = False,
        options: dict[str, dict[str, Any]] | None = None) -> list[StabilityRow]:
    """Measure continuity and flicker (module docstring) for every scene and method.

    Parameters
    ----------
    scenes, methods
        Scene names (:mod:`polcam.synth.scenes`) and separation methods (stack or single-image).
    size
        Image side in pixels.
    frames
        Noise seeds rendered per scene for the flicker (>= 2); seed 0 is also the continuity's stack.
    rel
        Relative deviation of the continuity's perturbation (> 0).
    hold_illuminant
        Pass the first frame's illuminant estimate to the later frames, for methods that take one.
    mono
        The scenes' luminance (a mono sensor), for methods that take mono stacks.
    options
        Per-method keyword options.

    Returns
    -------
    list of StabilityRow
    """
    if frames < 2:
        raise MethodError(f"bench stability: frames={frames}: expected at least 2")
    if not rel > 0:
        raise MethodError(f"bench stability: rel={rel}: expected a positive number")
    options = options or {}
    rows: list[StabilityRow] = []
    for name in scenes:
        renders = [render(scene(name), size=size, seed=s) for s in range(frames)]
        if mono:
            for r in renders:
                r.stack = r.stack.mean(axis=-1)
                r.diffuse = r.diffuse.mean(axis=-1)
        mask = np.asarray(renders[0].mask, bool)
        for method in methods:
            opts = dict(options.get(method, {}))
            stack0 = np.asarray(renders[0].stack, np.float32)
            first = separate(stack0, method=method, **opts)
            jump, share = 0.0, 0.0
            for seed in range(3):
                moved = separate(perturbed(stack0, rel, seed), method=method, **opts)
                d = _object(np.abs(moved.diffuse - first.diffuse), mask)
                jump, share = max(jump, float(d.max())), max(share, float((d > 1e-3).mean()))
            held = hold_illuminant and "illuminant" not in opts and takes_illuminant(method)
            est = estimated_illuminant(first.info) if held else None
            later = dict(opts, illuminant=est) if est is not None else opts
            layers = [first.diffuse] + [separate(np.asarray(r.stack, np.float32), method=method, **later).diffuse
                                        for r in renders[1:]]
            sd = _object(np.std(np.stack(layers), axis=0), mask)
            psnr = float(np.mean([score(d, r.diffuse, r.mask)[2] for d, r in zip(layers, renders)]))
            rows.append(StabilityRow(name, method, jump, share, float(np.quantile(sd, 0.99)), float(sd.max()),
                                     psnr, est is not None))
    return rows


def format_markdown(rows: Sequence[StabilityRow]) -> str:
    """A Markdown table of the rows, then the mean over scenes per method."""
    out = ["| scene | method | largest jump | share > 1e-3 | flicker p99 | flicker max | PSNR (dB) | illuminant |",
           "|---|---|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        out.append(f"| {r.scene} | {r.method} | {r.jump:.4f} | {r.jump_share:.4f} | {r.flicker_p99:.4f} | "
                   f"{r.flicker_max:.4f} | {r.psnr:.2f} | {'held' if r.held else 'per frame'} |")
    for m in dict.fromkeys(r.method for r in rows):
        rs = [r for r in rows if r.method == m]
        out.append(f"| **mean** | {m} | {np.mean([r.jump for r in rs]):.4f} | {np.mean([r.jump_share for r in rs]):.4f} "
                   f"| {np.mean([r.flicker_p99 for r in rs]):.4f} | {np.mean([r.flicker_max for r in rs]):.4f} | "
                   f"{np.mean([r.psnr for r in rs]):.2f} | |")
    return "\n".join(out)


def write_outputs(rows: Sequence[StabilityRow], out_dir: Path) -> list[Path]:
    """stability.csv and table.md in ``out_dir`` (written atomically)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["scene", "method", "jump", "jump_share", "flicker_p99", "flicker_max", "psnr", "illuminant_held"])
    for r in rows:
        w.writerow([r.scene, r.method, f"{r.jump:.6f}", f"{r.jump_share:.6f}", f"{r.flicker_p99:.6f}",
                    f"{r.flicker_max:.6f}", f"{r.psnr:.4f}", r.held])
    with atomic_write(out_dir / "stability.csv", "w") as fh:
        fh.write(buf.getvalue())
    with atomic_write(out_dir / "table.md", "w") as fh:
        fh.write(format_markdown(rows) + "\n")
    return [out_dir / "stability.csv", out_dir / "table.md"]
