"""Model selection of the ``lmmse`` demosaicing on a validation set polcam renders itself.

Run ``python -m polcam.demosaicing.validation`` to redo every choice of the shipped
``lmmse`` (the ridge of the fit, the second stage of colour and of mono layouts and its
Gaussian): it prints one table row per variant and the variant it picks.

The validation set (:func:`validation_scenes`) is polcam's own and disjoint from the
training set:

* ``rendered``: scenes of :func:`polcam.demosaicing.training.training_stack` drawn from
  :data:`VALIDATION_SEED` (the shipped weights are trained from seed 2024), mosaicked with
  the training's raw noise model;
* ``patterns``: the four scenes of :mod:`polcam.synth.patterns` (smooth, textured, edges,
  sweep) built from :data:`VALIDATION_SEED` (the benchmark reports them from seed 0),
  quantised to 16 bits like the benchmark.

The real stacks of the shared data folder (CC BY-NC or unlicensed) are never read here:
they are evaluation data for the final report only (``polcam bench demosaic``).

The score of a variant is the mean over the two groups of (S0 PSNR + DoLP PSNR), each
group's PSNRs averaged over its scenes (:func:`score`).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from polcam.bench.demosaic import quality
from polcam.demosaicing._registry import demosaic, mosaic_stack
from polcam.demosaicing.lmmse import LMMSE_PARAMS, run_lmmse
from polcam.demosaicing.training import LUMA, _noisy, fit_all, gram_sums, training_stack
from polcam.errors import MethodError
from polcam.mosaic import parse_layout
from polcam.synth.patterns import SCENES, make_scene

__all__ = ["VALIDATION_SEED", "evaluate", "main", "score", "select", "validation_scenes"]

#: Seed of the validation scenes (training: 2024; the benchmark's synthetic scenes: 0).
VALIDATION_SEED = 1
#: Layouts of the selection: one colour, one mono.
LAYOUTS = ("imx250myr", "imx250mzr")
#: Ridges tried (relative to the mean diagonal of the Gram matrix).
RIDGES = (1e-3, 3e-3, 1e-2, 3e-2, 1e-1)
#: Moment orders tried (:func:`polcam.demosaicing.training.fit_bank`).
MOMENTS = (1, 2)
#: Numbers of pattern scenes (:func:`polcam.demosaicing.training.pattern_stack`) added to the training set.
PATTERNS = (0, 50)
#: Second stages tried, (mode, sigma).
STAGES = (("none", 2.0), ("difference", 2.0), ("ratio", 1.0), ("ratio", 1.5), ("ratio", 2.0), ("ratio", 3.0))


def validation_scenes(*, color: bool, seed: int = VALIDATION_SEED, rendered: int = 16, size: int = 160,
                      pattern_size: int = 256) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """The validation set of one kind (colour or mono).

    Parameters
    ----------
    color
        RGB stacks (the mono set is the luminance of the rendered scenes and the mono pattern
        scenes).
    seed
        Seed of both groups.
    rendered, size
        Number and side of the rendered scenes.
    pattern_size
        Side of the pattern scenes.

    Returns
    -------
    list of (group, scene name, truth, raw)
        ``truth`` (4, H, W, 3) or (4, H, W) float32 in [0, 1]; ``raw`` its mosaic in the
        IMX250MYR (colour) or IMX250MZR (mono) layout, float32 in [0, 1], with the training's
        noise model (rendered) or 16-bit quantisation (patterns).
    """
    layout = parse_layout(LAYOUTS[0] if color else LAYOUTS[1])
    rng = np.random.default_rng(seed)
    out = []
    for i in range(rendered):
        stack = training_stack(rng, size)
        if not color:
            stack = np.tensordot(stack, LUMA, axes=([3], [0])).astype(np.float32)
        raw = np.clip(_noisy(rng, mosaic_stack(stack, layout=layout)), 0, 1)
        out.append(("rendered", f"rendered-{i}", stack, raw))
    for name in SCENES:
        stack = make_scene(name, height=pattern_size, width=pattern_size, seed=seed, color=color).stack
        raw = np.round(np.clip(mosaic_stack(stack, layout=layout), 0, 1) * 65535) / 65535
        out.append(("patterns", name, stack, raw.astype(np.float32)))
    return out


def evaluate(fn: Callable[[np.ndarray], np.ndarray],
             scenes: Sequence[tuple[str, str, np.ndarray, np.ndarray]]) -> dict[str, dict[str, float]]:
    """Mean S0 PSNR, DoLP PSNR (dB) and AoLP error (degrees) per group of a demosaicing
    function ``fn(raw) -> stack`` over :func:`validation_scenes`' scenes."""
    per: dict[str, list[dict[str, float]]] = {}
    for group, _name, truth, raw in scenes:
        per.setdefault(group, []).append(quality(truth, fn(raw)))
    return {g: {k: float(np.nanmean([r[k] for r in rows])) for k in ("psnr_s0", "psnr_dolp", "aolp_mae_deg")}
            for g, rows in per.items()}


def score(result: dict[str, dict[str, float]]) -> float:
    """The selection score: the mean over groups of S0 PSNR + DoLP PSNR (dB)."""
    return float(np.mean([r["psnr_s0"] + r["psnr_dolp"] for r in result.values()]))


def select(*, scenes: int = 150, size: int = 160, seed: int = 2024, ridges: Sequence[float] = RIDGES,
           moments: Sequence[int] = MOMENTS, patterns: Sequence[int] = PATTERNS,
           stages: Sequence[tuple[str, float]] = STAGES,
           baselines: Sequence[str] = ("bilinear", "eari"),
           validation: dict[str, int] | None = None) -> list[dict[str, Any]]:
    """Fit the banks for every (pattern scenes added, moment order, ridge) (one pass of
    rendering), run every (bank, stage) variant and the ``baselines`` on the validation set of
    each kind.  ``validation``: keyword arguments of :func:`validation_scenes` (sizes; the
    seed is always :data:`VALIDATION_SEED`).

    Returns
    -------
    list of dict
        One row per (kind, variant): ``kind`` ("color"/"mono"), ``variant``, ``patterns``, ``moments``, ``ridge``,
        ``stage``, ``sigma`` (None for baselines), ``score`` and the per-group means of :func:`evaluate`.
    """
    base = gram_sums(scenes=scenes, size=size, seed=seed)
    extra = gram_sums(scenes=0, size=size, seed=seed, patterns=max(patterns)) if max(patterns) else None
    banks = {}
    for npat in patterns:
        if npat not in (0, max(patterns)):
            raise MethodError(f"patterns {list(patterns)}: expected 0 and/or one count")
        sums = base if npat == 0 else {k: [a + b for a, b in zip(v, extra[k], strict=True)]
                                       for k, v in base.items()}
        banks.update({(npat, m, r): fit_all(sums, ridge=r, moments=m) for m in moments for r in ridges})
    rows: list[dict[str, Any]] = []
    for color, layout in ((True, LAYOUTS[0]), (False, LAYOUTS[1])):
        kind = "color" if color else "mono"
        lay = parse_layout(layout)
        val = validation_scenes(color=color, **{k: v for k, v in (validation or {}).items() if k != "seed"})
        for m in baselines:
            res = evaluate(lambda raw, m=m: demosaic(raw, layout=lay, method=m), val)
            rows.append({"kind": kind, "variant": m, "patterns": None, "moments": None, "ridge": None, "stage": None,
                         "sigma": None, "score": score(res), **res})
        for ((npat, order, ridge), bank), (mode, sigma) in itertools.product(banks.items(), stages):
            params = {**LMMSE_PARAMS, "color_stage": mode, "mono_stage": mode, "sigma": sigma,
                      "mono_sigma": sigma}
            res = evaluate(lambda raw, b=bank, p=params: run_lmmse(raw, lay, weights=b, params=p), val)
            name = f"lmmse +{npat} patterns, moments {order}, ridge {ridge:g}, {mode} {sigma:g}"
            rows.append({"kind": kind, "variant": name, "patterns": npat, "moments": order, "ridge": ridge,
                         "stage": mode, "sigma": sigma, "score": score(res), **res})
    return rows


def format_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """One table per kind, and the best lmmse variant of each."""
    lines: list[str] = []
    for kind in dict.fromkeys(r["kind"] for r in rows):
        sel = [r for r in rows if r["kind"] == kind]
        groups = [g for g in sel[0] if isinstance(sel[0][g], dict)]
        lines += [f"{kind} (validation seed {VALIDATION_SEED}; S0 / DoLP PSNR dB, AoLP error deg):", "",
                  "| variant | " + " | ".join(groups) + " | score |", "|---|" + "---:|" * (len(groups) + 1)]
        for r in sel:
            cells = [f"{r[g]['psnr_s0']:.2f} / {r[g]['psnr_dolp']:.2f} / {r[g]['aolp_mae_deg']:.2f}" for g in groups]
            lines.append(f"| {r['variant']} | " + " | ".join(cells) + f" | {r['score']:.2f} |")
        best = max((r for r in sel if r["ridge"] is not None), key=lambda r: r["score"])
        lines += ["", f"best {kind}: {best['variant']}", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry: run :func:`select` and print the tables."""
    ap = argparse.ArgumentParser(prog="python -m polcam.demosaicing.validation",
                                 description="Model selection of the lmmse demosaicing on polcam's own "
                                             "validation scenes.")
    ap.add_argument("--scenes", type=int, default=150, help="training scenes (default 150)")
    ap.add_argument("--size", type=int, default=160, help="training scene side (default 160)")
    ap.add_argument("--seed", type=int, default=2024, help="training seed (default 2024)")
    ap.add_argument("--ridges", type=float, nargs="+", default=list(RIDGES), help="ridges tried")
    ap.add_argument("--moments", type=int, nargs="+", default=list(MOMENTS), help="moment orders tried")
    ap.add_argument("--patterns", type=int, nargs="+", default=list(PATTERNS),
                    help="pattern scenes added to the training set (0 and/or one count)")
    ap.add_argument("--stages", nargs="+", default=[f"{m}:{g:g}" for m, g in STAGES],
                    help="second stages tried, MODE:SIGMA")
    args = ap.parse_args(argv)
    if args.seed == VALIDATION_SEED:
        ap.error(f"--seed {args.seed}: the training seed must differ from the validation seed")
    stages = [(st.split(':')[0], float(st.split(':')[1])) for st in args.stages]
    rows = select(scenes=args.scenes, size=args.size, seed=args.seed, ridges=args.ridges, moments=args.moments,
                  patterns=args.patterns, stages=stages)
    sys.stdout.write(format_markdown(rows) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
