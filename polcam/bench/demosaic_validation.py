"""Model selection of the ``lmmse`` demosaicing on a validation set polcam renders itself.

Run ``polcam bench demosaic-validation`` to redo every choice of the shipped
``lmmse`` (the ridge of the fit, the second stage of colour and of mono layouts and its
Gaussian): it prints one table row per variant and the variant it picks.

The validation set (:func:`validation_scenes`) is polcam's own and disjoint from the
training set:

* ``rendered``: scenes of :func:`polcam.bench.lmmse_training.training_stack` drawn from
  :data:`VALIDATION_SEED` (the shipped weights are trained from seed 2024), mosaicked with
  the training's raw noise model;
* ``patterns``: the four scenes of :mod:`polcam.synth.patterns` (smooth, textured, edges,
  sweep) built from :data:`VALIDATION_SEED` (the benchmark reports them from seed 0),
  quantised to 16 bits like the benchmark;
* ``photos``: crops of the CC0 photographs of
  :data:`polcam.synth.photos.VALIDATION_PHOTOS` (none of them is a training photograph)
  with simulated polarization (:func:`polcam.synth.photos.photo_stack`), mosaicked with
  the training's raw noise model.

The real stacks of the shared data folder (CC BY-NC or unlicensed) are never read here:
they are evaluation data for the final report only (``polcam bench demosaic``).

The score of a variant is the mean over the groups of (S0 PSNR + DoLP PSNR), each
group's PSNRs averaged over its scenes (:func:`score`).

``--blend`` selects ``lmmse-eari``'s blend (:func:`select_blend`) and ``--shared`` the
Gaussians of the colour shared-ratio stage (:func:`select_shared`), both with the shipped
weights.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from polcam.bench.demosaic import quality
from polcam.bench.lmmse_training import LUMA, fit_all, gram_sums, noisy_raw, training_stack
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.demosaicing.lmmse import LMMSE_PARAMS, run_lmmse, shipped_weights
from polcam.demosaicing.lmmse_eari import BLEND_PARAMS, run_blend
from polcam.errors import MethodError
from polcam.mosaic import Layout, parse_layout
from polcam.synth.patterns import SCENES, make_scene
from polcam.synth.photos import VALIDATION_PHOTOS, photo_stack

__all__ = ["VALIDATION_SEED", "evaluate", "score", "select", "select_blend", "select_shared", "stage_params",
           "validation_scenes"]

#: Seed of the validation scenes (training: 2024; the benchmark's synthetic scenes: 0).
VALIDATION_SEED = 1
#: Layouts of the selection: one colour, one mono.
LAYOUTS = ("imx250myr", "imx250mzr")
#: Ridges tried (relative to the mean diagonal of the Gram matrix).
RIDGES = (1e-3, 3e-3, 1e-2, 3e-2, 1e-1)
#: Moment orders tried (:func:`polcam.bench.lmmse_training.fit_bank`).
MOMENTS = (1, 2)
#: Numbers of pattern scenes (:func:`polcam.bench.lmmse_training.pattern_stack`) added to the training set.
PATTERNS = (0, 50)
#: Numbers of photograph crops (:func:`polcam.synth.photos.photo_stack`) added to the training set.
PHOTOS = (0, 80)
#: Blend thresholds and Gaussians tried for ``lmmse-eari`` (:func:`select_blend`).
BLEND_TAUS = (0.03, 0.05, 0.1, 0.2, 0.4)
BLEND_SIGMAS = (2.0, 4.0)
#: Gaussians (pixels) of the shared-ratio stage tried (:func:`select_shared`): the all-colour ratio,
#: the colours' offsets, the colours' residual.
SHARED_COMMONS = (0.8, 1.2, 1.6)
SHARED_OFFSETS = (12.0, 24.0)
SHARED_RESIDUALS = (3.0, 4.0, 6.0)
#: Second stages tried, (mode, sigma).
STAGES = (("none", 2.0), ("difference", 2.0), ("ratio", 1.0), ("ratio", 1.5), ("ratio", 2.0), ("ratio", 3.0))


def stage_params(mode: str, sigma: float) -> dict[str, float | str]:
    """:data:`~polcam.demosaicing.lmmse.LMMSE_PARAMS` with the second stage ``mode`` ("ratio",
    "difference", "none", or "ratio-tent" / "difference-tent": the tent kernel) and its
    ``sigma`` (the Gaussian; with the tent, the Gaussian the tent is convolved with), for colour
    and mono layouts alike."""
    base, tent = (mode[:-5], True) if mode.endswith("-tent") else (mode, False)
    if base not in ("ratio", "difference", "none"):
        raise MethodError(f"second stage {mode!r}: expected ratio, difference or none, optionally -tent")
    return {**LMMSE_PARAMS, "color_stage": base, "mono_stage": base, "sigma": sigma, "mono_sigma": sigma,
            "kernel": "tent" if tent else "gauss", "tent_sigma": sigma}


def validation_scenes(*, color: bool, seed: int = VALIDATION_SEED, rendered: int = 16, size: int = 160,
                      pattern_size: int = 256, photos: int = 4) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
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
    photos
        Crops per validation photograph (side ``size``; 0: no ``photos`` group).

    Returns
    -------
    list of (group, scene name, truth, raw)
        ``truth`` (4, H, W, 3) or (4, H, W) float32 in [0, 1]; ``raw`` its mosaic in the
        IMX250MYR (colour) or IMX250MZR (mono) layout, float32 in [0, 1], with the training's
        noise model (rendered, photos) or 16-bit quantisation (patterns).
    """
    layout = parse_layout(LAYOUTS[0] if color else LAYOUTS[1])
    rng = np.random.default_rng(seed)
    out = []
    for i in range(rendered):
        stack = training_stack(rng, size)
        if not color:
            stack = np.tensordot(stack, LUMA, axes=([3], [0])).astype(np.float32)
        raw = np.clip(noisy_raw(rng, mosaic_stack(stack, layout=layout)), 0, 1)
        out.append(("rendered", f"rendered-{i}", stack, raw))
    for name in SCENES:
        stack = make_scene(name, height=pattern_size, width=pattern_size, seed=seed, color=color).stack
        raw = np.round(np.clip(mosaic_stack(stack, layout=layout), 0, 1) * 65535) / 65535
        out.append(("patterns", name, stack, raw.astype(np.float32)))
    rng = np.random.default_rng([seed, 2])  # its own generator: the other groups do not depend on it
    for photo in VALIDATION_PHOTOS:
        for i in range(photos):
            stack = photo_stack(rng, size, photos=(photo,), scale=(0.5, 1.0))
            if not color:
                stack = np.tensordot(stack, LUMA, axes=([3], [0])).astype(np.float32)
            raw = np.clip(noisy_raw(rng, mosaic_stack(stack, layout=layout)), 0, 1)
            out.append(("photos", f"{photo}-{i}", stack, raw))
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
           photos: Sequence[int] = PHOTOS, stages: Sequence[tuple[str, float]] = STAGES,
           baselines: Sequence[str] = ("bilinear", "eari", "lmmse", "lmmse-eari"),
           validation: dict[str, int] | None = None,
           kinds: Sequence[str] = ("color", "mono")) -> list[dict[str, Any]]:
    """Fit the banks for every (pattern scenes added, photograph crops added, moment order, ridge)
    (one pass of rendering), run every (bank, stage) variant and the ``baselines`` on the
    validation set of each kind.  ``validation``: keyword arguments of :func:`validation_scenes`
    (sizes; the seed is always :data:`VALIDATION_SEED`); ``kinds``: "color" and/or "mono".

    Returns
    -------
    list of dict
        One row per (kind, variant): ``kind`` ("color"/"mono"), ``variant``, ``patterns``, ``photos``,
        ``moments``, ``ridge``, ``stage``, ``sigma`` (None for baselines), ``score`` and the per-group
        means of :func:`evaluate`.
    """
    for name, counts in (("patterns", patterns), ("photos", photos)):
        if any(n not in (0, max(counts)) for n in counts):
            raise MethodError(f"{name} {list(counts)}: expected 0 and/or one count")
    base = gram_sums(scenes=scenes, size=size, seed=seed)
    extra = {"patterns": gram_sums(scenes=0, size=size, seed=seed, patterns=max(patterns)) if max(patterns) else None,
             "photos": gram_sums(scenes=0, size=size, seed=seed, photos=max(photos)) if max(photos) else None}
    banks = {}
    for npat, nph in itertools.product(patterns, photos):
        sums = base
        for n, key in ((npat, "patterns"), (nph, "photos")):
            if n:
                sums = {k: [a + b for a, b in zip(v, extra[key][k], strict=True)] for k, v in sums.items()}
        banks.update({(npat, nph, m, r): fit_all(sums, ridge=r, moments=m) for m in moments for r in ridges})
    rows: list[dict[str, Any]] = []
    for kind, lay, val in _validation_sets(kinds, validation):
        rows += _baseline_rows(kind, lay, val, baselines, ("patterns", "photos", "moments", "ridge", "stage", "sigma"))
        for ((npat, nph, order, ridge), bank), (mode, sigma) in itertools.product(banks.items(), stages):
            params = stage_params(mode, sigma)
            res = evaluate(lambda raw, b=bank, p=params: run_lmmse(raw, lay, weights=b, params=p), val)
            name = f"lmmse +{npat} patterns, +{nph} photos, moments {order}, ridge {ridge:g}, {mode} {sigma:g}"
            rows.append({"kind": kind, "variant": name, "patterns": npat, "photos": nph, "moments": order,
                         "ridge": ridge, "stage": mode, "sigma": sigma, "score": score(res), **res})
    return rows


def _validation_sets(kinds: Sequence[str], validation: dict[str, int] | None) -> Iterator[tuple[str, Layout, Any]]:
    """(kind, layout, validation scenes) for each of ``kinds`` ("color", "mono") asked for."""
    for color, layout in ((True, LAYOUTS[0]), (False, LAYOUTS[1])):
        kind = "color" if color else "mono"
        if kind in kinds:
            yield kind, parse_layout(layout), validation_scenes(
                color=color, **{k: v for k, v in (validation or {}).items() if k != "seed"})


def _baseline_rows(kind: str, lay: Layout, val: Any, baselines: Sequence[str],
                   empty: Sequence[str]) -> list[dict[str, Any]]:
    """One row per registered method in ``baselines`` on ``val``, the columns ``empty`` set to None."""
    rows = []
    for m in baselines:
        res = evaluate(lambda raw, m=m: demosaic(raw, layout=lay, method=m), val)
        rows.append({"kind": kind, "variant": m, **dict.fromkeys(empty), "score": score(res), **res})
    return rows


def select_blend(*, taus: Sequence[float] = BLEND_TAUS, sigmas: Sequence[float] = BLEND_SIGMAS,
                 baselines: Sequence[str] = ("bilinear", "eari", "lmmse"),
                 validation: dict[str, int] | None = None,
                 kinds: Sequence[str] = ("color", "mono")) -> list[dict[str, Any]]:
    """Run ``lmmse-eari`` with the shipped ``lmmse`` weights for every (tau, sigma) of its blend
    (:data:`polcam.demosaicing.lmmse_eari.BLEND_PARAMS`, the floor kept) and the ``baselines`` on
    the validation set of each kind.

    Returns
    -------
    list of dict
        Rows like :func:`select`'s, with ``tau`` and ``sigma`` (None for baselines).
    """
    rows: list[dict[str, Any]] = []
    for kind, lay, val in _validation_sets(kinds, validation):
        rows += _baseline_rows(kind, lay, val, baselines, ("tau", "sigma", "ridge"))
        for tau, sigma in itertools.product(taus, sigmas):
            params = {**BLEND_PARAMS, "tau": tau, "sigma": sigma}
            res = evaluate(lambda raw, p=params: run_blend(raw, lay, params=p), val)
            # "ridge" set: format_markdown's "best" line picks among the blend's rows
            rows.append({"kind": kind, "variant": f"lmmse-eari tau {tau:g}, sigma {sigma:g}", "tau": tau,
                         "sigma": sigma, "ridge": 0.0, "score": score(res), **res})
    return rows


def select_shared(*, commons: Sequence[float] = SHARED_COMMONS, offsets: Sequence[float] = SHARED_OFFSETS,
                  residuals: Sequence[float] = SHARED_RESIDUALS,
                  baselines: Sequence[str] = ("bilinear", "eari", "lmmse", "lmmse-eari"),
                  validation: dict[str, int] | None = None) -> list[dict[str, Any]]:
    """Run ``lmmse`` with the shipped weights and the shared-ratio second stage
    (:func:`polcam.demosaicing._shared_ratio.shared_ratio_stage`) for every (common, offset,
    residual) Gaussian, the per-colour ratio stage (tent kernel) and the ``baselines`` on the
    colour validation set.

    Returns
    -------
    list of dict
        Rows like :func:`select`'s, with ``common``, ``offset`` and ``residual`` (None for the
        baselines and the ratio stage).
    """
    _, lay, val = next(_validation_sets(("color",), validation))
    none = {"common": None, "offset": None, "residual": None}
    rows = _baseline_rows("color", lay, val, baselines, ("ridge", *none))
    variants = [("lmmse, ratio stage (tent)", {"color_stage": "ratio", "kernel": "tent"}, none)]
    for common, offset, residual in itertools.product(commons, offsets, residuals):
        variants.append((f"lmmse, shared ratio, common {common:g}, offsets {offset:g}, residual {residual:g}",
                         {"color_stage": "shared-ratio", "common_sigma": common, "offset_sigma": offset,
                          "residual_sigma": residual},
                         {"common": common, "offset": offset, "residual": residual}))
    weights = shipped_weights()
    for name, upd, cols in variants:
        params = {**LMMSE_PARAMS, **upd}
        res = evaluate(lambda raw, p=params: run_lmmse(raw, lay, weights=weights, params=p), val)
        # "ridge" set: format_markdown's "best" line picks among these rows
        rows.append({"kind": "color", "variant": name, "ridge": 0.0, **cols, "score": score(res), **res})
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
