"""``polcam bench quality``: every separation method on the paper's synthetic scenes.

Renders the scene set of :mod:`polcam.synth.scenes` (Bunny1-7, Dragon1-2,
Armadillo), runs every method on each stack, and scores the diffuse layer
against the ground truth: PSNR (data range 1) and SSIM
(:func:`skimage.metrics.structural_similarity`, ``channel_axis=-1``,
``data_range=1``, Gaussian window sigma 1.5 as in Wang et al. 2004), over the
whole image and over the object mask, plus seconds.  Prints the paper's
Table 1/2 layout, writes CSV and Markdown, and plots PSNR against specular
strength (the paper's Fig. 3) as PNG.

The published figures of the paper's Tables 1-3 are kept here (independent
reference) so the docs can put ours beside them; the scenes are not the
paper's (it does not publish them), so only orderings compare, not values.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from skimage.metrics import structural_similarity

from polcam.io.atomic import atomic_path, atomic_write
from polcam.separation import METHODS, method_spec, separate
from polcam.synth.analytic import render_analytic
from polcam.synth.family import render_family, split_seeds
from polcam.synth.render import render
from polcam.synth.scenes import SCENES, STRESS, scene

__all__ = ["PAPER_TABLES", "Score", "psnr", "ssim", "score", "run", "run_family", "family_summary", "format_table",
           "write_outputs"]

#: (SSIM, PSNR) per method and scene from the paper's Tables 1 and 2 (Yang'10 ... Ours = tensor).
PAPER_TABLES: dict[str, dict[str, tuple[float, float]]] = {
    "yang10": {"Bunny1": (0.970, 38.54), "Bunny2": (0.939, 30.86), "Bunny3": (0.961, 36.72),
               "Bunny4": (0.922, 32.17), "Bunny5": (0.845, 25.19), "Bunny6": (0.716, 17.66),
               "Bunny7": (0.932, 31.02), "Dragon1": (0.910, 28.32), "Dragon2": (0.727, 21.58),
               "Armadillo": (0.886, 27.64)},
    "shen08": {"Bunny1": (0.931, 34.10), "Bunny2": (0.948, 32.35), "Bunny3": (0.857, 28.86),
               "Bunny4": (0.616, 19.25), "Bunny5": (0.804, 23.77), "Bunny6": (0.492, 16.94),
               "Bunny7": (0.874, 28.03), "Dragon1": (0.921, 29.12), "Dragon2": (0.662, 19.01),
               "Armadillo": (0.905, 28.41)},
    "shen09": {"Bunny1": (0.932, 35.88), "Bunny2": (0.950, 31.17), "Bunny3": (0.904, 32.14),
               "Bunny4": (0.694, 22.57), "Bunny5": (0.797, 24.63), "Bunny6": (0.602, 19.27),
               "Bunny7": (0.889, 28.94), "Dragon1": (0.941, 30.95), "Dragon2": (0.721, 22.68),
               "Armadillo": (0.929, 30.22)},
    "shen13": {"Bunny1": (0.971, 38.66), "Bunny2": (0.948, 32.25), "Bunny3": (0.907, 31.51),
               "Bunny4": (0.569, 16.24), "Bunny5": (0.701, 18.89), "Bunny6": (0.483, 15.52),
               "Bunny7": (0.847, 25.99), "Dragon1": (0.924, 29.12), "Dragon2": (0.610, 17.47),
               "Armadillo": (0.904, 28.34)},
    "tan05": {"Bunny1": (0.905, 30.46), "Bunny2": (0.865, 26.02), "Bunny3": (0.888, 29.59),
              "Bunny4": (0.847, 27.47), "Bunny5": (0.769, 21.82), "Bunny6": (0.717, 20.90),
              "Bunny7": (0.752, 22.12), "Dragon1": (0.838, 24.64), "Dragon2": (0.682, 20.06),
              "Armadillo": (0.814, 23.66)},
    "yoon06": {"Bunny1": (0.897, 25.30), "Bunny2": (0.949, 32.28), "Bunny3": (0.874, 23.35),
               "Bunny4": (0.777, 19.75), "Bunny5": (0.871, 26.01), "Bunny6": (0.658, 13.83),
               "Bunny7": (0.861, 22.59), "Dragon1": (0.884, 24.81), "Dragon2": (0.745, 20.32),
               "Armadillo": (0.851, 24.02)},
    "akashi16": {"Bunny1": (0.766, 21.70), "Bunny2": (0.866, 24.44), "Bunny3": (0.701, 19.28),
                 "Bunny4": (0.551, 14.06), "Bunny5": (0.686, 16.11), "Bunny6": (0.491, 12.08),
                 "Bunny7": (0.850, 24.05), "Dragon1": (0.856, 25.51), "Dragon2": (0.603, 15.08),
                 "Armadillo": (0.804, 22.92)},
    "yamamoto19": {"Bunny1": (0.969, 38.51), "Bunny2": (0.938, 30.83), "Bunny3": (0.960, 36.71),
                   "Bunny4": (0.923, 32.18), "Bunny5": (0.844, 25.19), "Bunny6": (0.716, 17.66),
                   "Bunny7": (0.933, 31.01), "Dragon1": (0.910, 28.32), "Dragon2": (0.727, 21.59),
                   "Armadillo": (0.886, 27.64)},
    "tensor": {"Bunny1": (0.993, 48.11), "Bunny2": (0.981, 41.77), "Bunny3": (0.989, 45.72),
               "Bunny4": (0.966, 36.67), "Bunny5": (0.951, 33.90), "Bunny6": (0.954, 35.16),
               "Bunny7": (0.978, 38.26), "Dragon1": (0.975, 38.70), "Dragon2": (0.906, 30.21),
               "Armadillo": (0.971, 38.88)},
}


@dataclass
class Score:
    """One method on one scene."""

    scene: str
    method: str
    psnr: float
    ssim: float
    psnr_mask: float
    ssim_mask: float
    seconds: float
    iterations: int | None = None
    converged: bool | None = None
    error: str | None = None


def psnr(x: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR in dB, data range 1, over all pixels or the masked ones (all channels)."""
    d = (np.asarray(x, np.float64) - np.asarray(ref, np.float64)) ** 2
    if mask is not None:
        d = d[mask]
    mse = float(d.mean()) if d.size else 0.0
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def ssim(x: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean SSIM (Gaussian window, sigma 1.5), over all pixels or the masked ones (border of 5 left out)."""
    val, smap = structural_similarity(
        np.asarray(ref, np.float64), np.asarray(x, np.float64), channel_axis=-1, data_range=1.0,
        gaussian_weights=True, sigma=1.5, use_sample_covariance=False, full=True,
    )
    if mask is None:
        return float(val)
    # like skimage's mean, leave out the border the window does not fit in
    pad = (2 * int(3.5 * 1.5 + 0.5) + 1 - 1) // 2
    inner = np.zeros_like(mask)
    inner[pad:-pad, pad:-pad] = mask[pad:-pad, pad:-pad]
    m = smap.mean(axis=-1)[inner]
    return float(m.mean()) if m.size else float("nan")


def score(diffuse: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> tuple[float, float, float, float]:
    """(PSNR, SSIM, PSNR over mask, SSIM over mask) of a diffuse layer ((H, W, 3), or (H, W) mono)."""
    d = np.clip(diffuse, 0, 1)
    if d.ndim == 2:
        d, truth = d[..., None], np.asarray(truth)[..., None]
    return psnr(d, truth), ssim(d, truth), psnr(d, truth, mask), ssim(d, truth, mask)


#: Named scene sets: the paper's, polcam's stress scenes (each breaking one method assumption), both.
#: The randomized family (``--set random``) is :func:`run_family`.
SCENE_SETS = ("paper", "stress", "all")


def scene_set(name: str) -> list[str]:
    """Scene names of a set in :data:`SCENE_SETS`."""
    if name not in SCENE_SETS:
        raise ValueError(f"scene set {name!r}: expected one of {', '.join(SCENE_SETS)}")
    return {"paper": list(SCENES), "stress": list(STRESS), "all": [*SCENES, *STRESS]}[name]


def run(*, scenes: Sequence[str] | None = None, methods: Sequence[str] | None = None,
        size: int = 128, seed: int = 0, options: dict[str, dict[str, Any]] | None = None,
        progress: bool = True, mono: bool = False) -> tuple[list[Score], dict[str, dict[str, float]]]:
    """Render the scenes and score every method.

    Parameters
    ----------
    scenes
        Scene names (default: all of :data:`polcam.synth.scenes.SCENES`).
    methods
        Method names (default: every registered colour method; with ``mono``,
        every method that takes mono stacks).
    mono
        Score on the scenes' luminance (the mean of R, G and B of every
        polarizer image and of the true diffuse): what a mono sensor (IMX250MZR) sees.
    size
        Image side in pixels.
    seed
        Rendering seed (noise, textures).
    options
        Per-method keyword options, e.g. ``{"tensor": {"max_iter": 50}}``.

    Returns
    -------
    scores : list of Score
    scene_stats : dict
        Per scene: specular-to-diffuse energy ratio and saturated fraction.
    """
    names = list(scenes or SCENES)
    meths = list(methods or [m for m in METHODS if not mono or method_spec(m).mono])
    scores: list[Score] = []
    stats: dict[str, dict[str, float]] = {}
    for name in names:
        r = render(scene(name), size=size, seed=seed)
        if mono:
            r.stack = r.stack.mean(axis=-1)
            r.diffuse = r.diffuse.mean(axis=-1)
            r.specular = r.specular.mean(axis=-1)
        mean = r.stack.mean(axis=0)
        stats[name] = {
            "specular_ratio": float(r.specular.sum() / max(r.diffuse.sum(), 1e-12)),
            "saturated": float(np.mean(np.any(r.stack >= 1.0, axis=(0, 3) if r.stack.ndim == 4 else 0)[r.mask]))
            if r.mask.any() else 0.0,
            "input_psnr": psnr(mean, r.diffuse),
        }
        scores += _score_scene(name, r.stack, r.diffuse, r.mask, meths, options or {}, progress)
    return scores, stats


def _score_scene(name: str, stack: np.ndarray, truth: np.ndarray, mask: np.ndarray, meths: Sequence[str],
                 options: dict[str, dict[str, Any]], progress: bool) -> list[Score]:
    """Every method on one stack, scored against the true diffuse."""
    scores: list[Score] = []
    for m in meths:
        t0 = time.perf_counter()
        try:
            res = separate(stack, method=m, **options.get(m, {}))
        except Exception as exc:  # a failing method is reported, not fatal to the table
            scores.append(Score(name, m, float("nan"), float("nan"), float("nan"), float("nan"),
                                time.perf_counter() - t0, error=f"{type(exc).__name__}: {exc}"))
            continue
        p, s, pm, sm = score(res.diffuse, truth, mask)
        scores.append(Score(name, m, p, s, pm, sm, res.info.get("seconds", time.perf_counter() - t0),
                            res.info.get("iterations"), res.info.get("converged")))
        if progress:
            print(f"  {name:<10} {m:<13} PSNR {p:6.2f}  SSIM {s:.3f}  "
                  f"(mask {pm:6.2f} / {sm:.3f})  {scores[-1].seconds:7.2f} s", flush=True)
    return scores


#: The scene families of :func:`run_family`: the randomized family (``--set random``), on which
#: choices are made, and the analytic family (``--set analytic``), from a second renderer, used for
#: no choice.
FAMILIES = ("random", "analytic")


def run_family(split: str = "validation", n: int = 40, *, seed: int | None = None, size: int = 128,
               methods: Sequence[str] | None = None, mono: bool = False,
               options: dict[str, dict[str, Any]] | None = None, progress: bool = True,
               family: str = "random",
               ) -> tuple[list[Score], dict[str, dict[str, float]], list[int], int | None]:
    """Score the methods on a split of a scene family (:mod:`polcam.synth.family`, :mod:`polcam.synth.analytic`).

    Parameters
    ----------
    split
        ``validation`` (fixed seeds, for choices) or ``test`` (fresh seeds, only reported).
    n
        Number of scenes.
    seed
        The test split's master seed (None: fresh; the one used is returned); must be None
        for validation.
    size
        Image side in pixels (a multiple of 4).
    methods
        Method names (default: every colour method; with ``mono``, every mono one).
    mono
        Score the IMX250MZR camera's stack against the luminance truth (``diffuse_mono``).
    options
        Per-method keyword options.
    family
        ``random`` (:func:`polcam.synth.family.render_family`) or ``analytic``
        (:func:`polcam.synth.analytic.render_analytic`, the same seeds and camera, another renderer).

    Returns
    -------
    scores : list of Score
        Object-mask PSNR in ``psnr_mask`` (the figure the family reports).
    stats : dict
        Per scene: ``saturated`` (clipped share of the object), ``input_psnr`` (object PSNR
        of the input's mean), ``exposure``, ``ks``.
    seeds : list of int
    master : int or None
    """
    if family not in FAMILIES:
        raise ValueError(f"scene family {family!r}: expected one of {', '.join(FAMILIES)}")
    seeds, master = split_seeds(split, n, seed=seed)
    meths = list(methods or [m for m in METHODS if not mono or method_spec(m).mono])
    for m in meths:
        method_spec(m)  # an unknown name is refused before any work
    scores: list[Score] = []
    stats: dict[str, dict[str, float]] = {}
    rend = render_family if family == "random" else render_analytic
    for sd in seeds:
        sc = rend(sd, size=size)
        stack, truth = (sc.mono_stack, sc.diffuse_mono) if mono else (sc.stack, sc.diffuse)
        stats[sc.name] = {
            "specular_ratio": float(np.clip(sc.ideal.mean(0), 0, 1).sum() / max(float(sc.diffuse.sum()), 1e-12)
                                    - 1.0),
            "saturated": float(sc.clipped[sc.mask].mean()) if sc.mask.any() else 0.0,
            "input_psnr": psnr(stack.mean(axis=0), truth, sc.mask),
            "exposure": float(sc.params["exposure"]), "ks": float(sc.params["ks"]),
        }
        scores += _score_scene(sc.name, stack, truth, sc.mask, meths, options or {}, progress)
    return scores, stats, seeds, master


def family_summary(scores: Sequence[Score], *, within: float = 0.3) -> str:
    """Markdown: per method the mean and median object PSNR, and the share of scenes where it is
    best or within ``within`` dB of the best method."""
    scenes = list(dict.fromkeys(s.scene for s in scores))
    methods = list(dict.fromkeys(s.method for s in scores))
    by = {(s.scene, s.method): (s.psnr_mask if not s.error else float("nan")) for s in scores}
    best = {sc: np.nanmax([by.get((sc, m), np.nan) for m in methods]) for sc in scenes}
    lines = [f"| method | mean object PSNR (dB) | median | best or within {within} dB | scenes |",
             "|---|---:|---:|---:|---:|"]
    for m in methods:
        vals = np.array([by.get((sc, m), np.nan) for sc in scenes])
        ok = np.isfinite(vals)
        near = np.mean([vals[i] >= best[sc] - within for i, sc in enumerate(scenes) if ok[i]]) if ok.any() else 0
        lines.append(f"| {m} | {np.mean(vals[ok]):.2f} | {np.median(vals[ok]):.2f} | {near:.0%} | {int(ok.sum())} |"
                     if ok.any() else f"| {m} | - | - | - | 0 |")
    return "\n".join(lines)


def format_table(scores: Sequence[Score], *, masked: bool = False) -> str:
    """Markdown in the paper's Table 1/2 layout: methods as rows, (SSIM, PSNR) per scene."""
    scenes = list(dict.fromkeys(s.scene for s in scores))
    methods = list(dict.fromkeys(s.method for s in scores))
    by = {(s.scene, s.method): s for s in scores}
    head = "| method | " + " | ".join(f"{sc} SSIM | {sc} PSNR" for sc in scenes) + " | mean PSNR | seconds |"
    sep = "|---" * (2 * len(scenes) + 3) + "|"
    lines = [head, sep]
    for m in methods:
        cells = []
        ps, secs = [], []
        for sc in scenes:
            s = by.get((sc, m))
            if s is None or s.error:
                cells += ["-", "-"]
                continue
            p, q = (s.psnr_mask, s.ssim_mask) if masked else (s.psnr, s.ssim)
            cells += [f"{q:.3f}", f"{p:.2f}"]
            ps.append(p)
            secs.append(s.seconds)
        mean = f"{np.mean(ps):.2f}" if ps else "-"
        sec = f"{np.mean(secs):.2f}" if secs else "-"
        lines.append(f"| {m} | " + " | ".join(cells) + f" | {mean} | {sec} |")
    return "\n".join(lines)


def format_object_psnr(scores: Sequence[Score]) -> str:
    """Markdown: object-mask PSNR, a row per scene and a column per method, the best in bold, and the mean."""
    scenes = list(dict.fromkeys(s.scene for s in scores))
    methods = list(dict.fromkeys(s.method for s in scores))
    by = {(s.scene, s.method): s.psnr_mask for s in scores if not s.error}
    lines = ["| scene | " + " | ".join(methods) + " |", "|---" + "|---:" * len(methods) + "|"]
    rows = [(sc, [by.get((sc, m), float("nan")) for m in methods]) for sc in scenes]
    means = [float(np.mean([v for _, vals in rows for v in [vals[i]]])) for i in range(len(methods))]
    for label, vals in [*rows, ("mean", means)]:
        best = np.nanmax(vals) if np.any(np.isfinite(vals)) else np.nan
        cells = [("-" if not np.isfinite(v) else (f"**{v:.2f}**" if v == best else f"{v:.2f}")) for v in vals]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_paper(scenes: Sequence[str]) -> str:
    """The paper's published figures in the same layout."""
    fake = [Score(sc, m, v[1], v[0], v[1], v[0], float("nan"))
            for m, table in PAPER_TABLES.items() for sc, v in table.items() if sc in scenes]
    return format_table(fake).replace(" | nan |", " | - |")


def write_outputs(scores: Sequence[Score], stats: dict[str, dict[str, float]], out_dir: Path) -> list[Path]:
    """scores.csv, table.md (whole image and mask, beside the paper's) and psnr_vs_specular.png."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["scene", "method", "psnr", "ssim", "psnr_mask", "ssim_mask", "seconds", "iterations",
                "converged", "specular_ratio", "saturated", "error"])
    for s in scores:
        st = stats.get(s.scene, {})
        w.writerow([s.scene, s.method, f"{s.psnr:.4f}", f"{s.ssim:.5f}", f"{s.psnr_mask:.4f}",
                    f"{s.ssim_mask:.5f}", f"{s.seconds:.3f}", s.iterations, s.converged,
                    f"{st.get('specular_ratio', float('nan')):.4f}", f"{st.get('saturated', float('nan')):.4f}",
                    s.error or ""])
    with atomic_write(out_dir / "scores.csv", "w") as fh:
        fh.write(buf.getvalue())
    written.append(out_dir / "scores.csv")
    scenes = list(dict.fromkeys(s.scene for s in scores))
    md = ["## Summary: object PSNR (dB) per method", "", family_summary(scores), "",
          "## Object PSNR (dB), scenes by methods", "", format_object_psnr(scores), "",
          "## Whole image", "", format_table(scores), "", "## Object mask", "",
          format_table(scores, masked=True), "", "## The paper (Tables 1 and 2)", "",
          format_paper(scenes), "", "## Scenes", "",
          "| scene | specular / diffuse energy | saturated share of object | input PSNR |",
          "|---|---|---|---|"]
    md += [f"| {sc} | {v['specular_ratio']:.3f} | {v['saturated']:.3f} | {v['input_psnr']:.2f} |"
           for sc, v in stats.items()]
    with atomic_write(out_dir / "table.md", "w") as fh:
        fh.write("\n".join(md) + "\n")
    written.append(out_dir / "table.md")
    written.append(_plot(scores, stats, out_dir / "psnr_vs_specular.png"))
    return written


def _plot(scores: Sequence[Score], stats: dict[str, dict[str, float]], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # like the paper's Fig. 3: one object (the Bunny series when present), specular rising
    bunnies = [sc for sc in stats if sc.startswith("Bunny")]
    scenes = sorted(bunnies or list(stats), key=lambda sc: stats[sc]["specular_ratio"])
    methods = list(dict.fromkeys(s.method for s in scores))
    cmap = plt.get_cmap("tab20")
    markers = "os^vD<>pP*Xhd"
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    for i, m in enumerate(methods):
        by = {s.scene: s.psnr for s in scores if s.method == m and not s.error}
        xs = [stats[sc]["specular_ratio"] for sc in scenes if sc in by]
        ys = [by[sc] for sc in scenes if sc in by]
        ax.plot(xs, ys, marker=markers[i % len(markers)], color=cmap(i % 20), label=m,
                linewidth=2.5 if m.startswith("tensor") else 1)
    if all(stats[sc]["specular_ratio"] > 0 for sc in scenes):
        ax.set_xscale("log")
    ax.set_xlabel("specular / diffuse energy of the scene (" + ", ".join(scenes) + ")")
    ax.set_ylabel("PSNR of the diffuse layer (dB)")
    ax.set_title("Separation quality as the specular reflection increases")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
