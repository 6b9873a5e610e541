"""``polcam bench real --relit``: every real stack under every relit variant, the no-harm measures.

The real table (:mod:`polcam.bench.real`) runs each stack as recorded; a
default method must also do no harm when the same scene is overexposed or
lit by a light the camera is not balanced for.  This module runs every stack
under :data:`VARIANTS` and measures, per stack, variant and method:

``matte_kept``
    The share of light kept in the diffuse over the **matte achromatic**
    pixels: the achromatic mask of :func:`polcam.bench.real.achromatic_mask`
    (true grey DoLP < 0.03, saturation < 0.12, mean > 0.08, all as recorded),
    less the pixels with a clipped sample in the variant (any of the relit
    true stack's 12 samples at 0.99 or above, grown by 2 pixels, the
    demosaicing's reach) and the pixels brighter than their neighbourhood
    (grey mean more than 15 % over its median in a 41-pixel window): there a
    method may rightly remove unpolarized sheen from a glossy white surface.
``top_removed``, ``spread``
    As in :mod:`polcam.bench.real` (brightest 1 % removed, specular colour spread).
``top_clipped``, ``top_unpolarized``, ``top_rising``, ``top_rising_polarized``
    What the brightest 1 % (the pixels ``top_removed`` is taken over) holds, the same for every
    method of a stack and variant (:func:`brightest_composition`): the shares of those pixels with
    a clipped sample, nearly unpolarized (true grey DoLP under 0.03), brighter than their
    neighbourhood (as ``matte_kept`` leaves out), and both that and unclipped and polarized, where
    a highlight shows the signs a separation can read.  Where the brightest 1 % is a matte white
    surface or clipped, removing it is harm, not separation.
``top_removed_rising_polarized``
    ``top_removed`` over the last of those alone (NaN where there are none).
``invented``
    Structure invented in clipped regions.  Where every polarizer sample of a
    colour channel is clipped, the camera says only "at least white": the
    region carries no information beyond its border.  A fill that adds none is
    harmonic there (a membrane stretched over the layer's own values at the
    region's edge; a region left as measured is a constant membrane), so the
    measure is the diffuse's mean absolute departure from the harmonic
    interpolation of its values on the region's edge, over the region's
    interior, per unit of the input's light there::

        invented = sum_c sum_{p in K_c} |D_c(p) - H_c(p)| / sum_c sum_{p in K_c} I_c(p)

    with ``K_c`` the pixels whose four channel-``c`` samples are all at 0.99
    or above, eroded by one pixel, keeping the connected parts of at least
    :data:`MIN_REGION` pixels (a glint of a few pixels has no room for a
    visible structure, and its few interior pixels all touch the edge), and ``H_c`` the solution of Laplace's
    equation on ``K_c`` equal to ``D_c`` on its edge (natural boundary at the
    image border).  Facets, blobs, rings and pits score; a smooth ramp from
    the border or a region left alone does not.  NaN where nothing clips.

The real stacks under ``../shared/data`` are CC BY-NC: read them from there for
evaluation, never copy them into the product.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from polcam.bench.real import (
    achromatic_mask,
    brightest,
    camera_stack,
    find_scenes,
    load_stack,
    metrics,
    prepare,
    relight,
)
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.errors import PolcamError
from polcam.polarimetry import dolp
from polcam.separation import METHODS, method_spec, separate

__all__ = ["VARIANTS", "CLIP_LEVEL", "MIN_REGION", "UNPOLARIZED_DOLP", "RelitScore", "matte_mask", "brightest_composition",
           "invented_structure", "run", "format_table", "summary"]

#: The relit variants: name -> (exposure, light RGB).  ``overexposed``: 1.5 times the light, what
#: was above 2/3 of the white level clips; ``tinted``: the light a raw IMX250MYR frame sees
#: before white balance, about (0.55, 1, 0.7), so every surface takes its colour.
VARIANTS: dict[str, tuple[float, tuple[float, float, float]]] = {
    "recorded": (1.0, (1.0, 1.0, 1.0)),
    "overexposed": (1.5, (1.0, 1.0, 1.0)),
    "tinted": (1.0, (0.55, 1.0, 0.7)),
    "tinted+overexposed": (1.5, (0.55, 1.0, 0.7)),
}
#: A sample at or above this is clipped (the stacks are 8-bit: 253/255 and above).
CLIP_LEVEL = 0.99
#: Smallest clipped region (interior pixels, one channel) the invented-structure measure judges.
MIN_REGION = 25
#: Local highlights: grey mean over (1 + LOCAL_BRIGHT) times its median in a LOCAL_WINDOW window.
LOCAL_BRIGHT = 0.15
LOCAL_WINDOW = 41
#: A pixel is nearly unpolarized below this true grey DoLP (as :func:`polcam.bench.real.achromatic_mask`).
UNPOLARIZED_DOLP = 0.03


@dataclass
class RelitScore:
    """One method on one stack under one variant."""

    scene: str
    variant: str
    method: str
    matte_kept: float
    top_removed: float
    spread: float
    invented: float
    clipped_share: float
    seconds: float
    error: str | None = None
    top_clipped: float = float("nan")
    top_unpolarized: float = float("nan")
    top_rising: float = float("nan")
    top_rising_polarized: float = float("nan")
    top_removed_rising_polarized: float = float("nan")


def matte_mask(achromatic: np.ndarray, relit_true: np.ndarray, *, clip_level: float = CLIP_LEVEL,
               grow: int = 2, bright: float = LOCAL_BRIGHT, window: int = LOCAL_WINDOW) -> np.ndarray:
    """The matte achromatic pixels: ``achromatic`` less clipped and locally bright pixels, (H, W) bool.

    Parameters
    ----------
    achromatic
        (H, W) bool, the achromatic pixels as recorded.
    relit_true
        (4, H, W, 3) the true stack under the variant, in [0, 1].
    clip_level
        A sample at or above it is clipped.
    grow
        Clipped pixels are grown by this many pixels (a square window).
    bright, window
        A pixel whose grey mean exceeds ``(1 + bright)`` times the median of a ``window`` x
        ``window`` neighbourhood is a local highlight.
    """
    from scipy import ndimage

    s = np.asarray(relit_true, np.float64)
    clipped = (s >= clip_level).any(axis=(0, 3))
    if grow > 0:
        clipped = ndimage.binary_dilation(clipped, structure=np.ones((2 * grow + 1, 2 * grow + 1), bool))
    local = _locally_bright(s.mean(axis=(0, 3)), bright, window)
    return np.asarray(achromatic, bool) & ~clipped & ~local


def _locally_bright(grey: np.ndarray, bright: float, window: int) -> np.ndarray:
    """(H, W) bool: ``grey`` over ``(1 + bright)`` times its median in a ``window`` x ``window`` neighbourhood."""
    import cv2

    g = np.asarray(grey, np.float32)
    # the median filter on 8-bit (OpenCV takes windows over 5 only for 8-bit images): 1/255 steps
    med = cv2.medianBlur(np.clip(g * 255 + 0.5, 0, 255).astype(np.uint8), int(window)).astype(np.float64) / 255
    return g > (1.0 + bright) * np.maximum(med, 1.0 / 255)


def brightest_composition(given: np.ndarray, relit_true: np.ndarray, *, clip_level: float = CLIP_LEVEL,
                          bright: float = LOCAL_BRIGHT, window: int = LOCAL_WINDOW,
                          unpolarized: float = UNPOLARIZED_DOLP) -> dict[str, float]:
    """What the brightest 1 % of pixels holds: the pixels ``top_removed`` is taken over.

    ``top_removed`` rewards removing the light of the brightest pixels; that is separation where
    they are highlights and harm where they are a matte white surface.  This says which.

    Parameters
    ----------
    given
        (4, H, W, 3) the stack the methods separate (the brightest 1 % by its mean intensity, as
        :func:`polcam.bench.real.metrics` takes it).
    relit_true
        (4, H, W, 3) the true stack under the variant, in [0, 1] (what the pixels are).
    clip_level
        A true sample at or above it is clipped.
    bright, window
        As :func:`matte_mask`: a pixel brighter than ``(1 + bright)`` times its ``window``-pixel
        median rises above its neighbourhood.
    unpolarized
        A pixel whose true grey DoLP is under it is nearly unpolarized.

    Returns
    -------
    dict
        Shares of the brightest 1 % in [0, 1]: ``top_clipped`` (a true sample clipped),
        ``top_unpolarized``, ``top_rising`` (brighter than its neighbourhood) and
        ``top_rising_polarized`` (rising, unclipped and polarized: a highlight's signs).

    Examples
    --------
    >>> import numpy as np
    >>> wall = np.full((4, 64, 64, 3), 0.4); wall[:, :8, :8] = 1.0      # a clipped matte white corner
    >>> brightest_composition(wall, wall)["top_clipped"]
    1.0
    """
    return _composition(*_brightest_masks(given, relit_true, clip_level=clip_level, bright=bright, window=window,
                                          unpolarized=unpolarized))


def _composition(top: np.ndarray, clipped: np.ndarray, unpol: np.ndarray, rising: np.ndarray) -> dict[str, float]:
    """:func:`brightest_composition`'s shares from its masks."""
    n = max(int(top.sum()), 1)

    def share(m: np.ndarray) -> float:
        return float((m & top).sum() / n)

    return {"top_clipped": share(clipped), "top_unpolarized": share(unpol), "top_rising": share(rising),
            "top_rising_polarized": share(rising & ~clipped & ~unpol)}


def _brightest_masks(given: np.ndarray, relit_true: np.ndarray, *, clip_level: float = CLIP_LEVEL,
                     bright: float = LOCAL_BRIGHT, window: int = LOCAL_WINDOW,
                     unpolarized: float = UNPOLARIZED_DOLP) -> tuple[np.ndarray, ...]:
    """(H, W) bool masks of :func:`brightest_composition`: the brightest 1 %, clipped, unpolarized, rising."""
    t = np.asarray(relit_true, np.float64)
    top = brightest(np.asarray(given, np.float64))
    clipped = (t >= clip_level).any(axis=(0, 3))
    unpol = dolp(t.mean(axis=-1)) < unpolarized
    rising = _locally_bright(t.mean(axis=(0, 3)), bright, window)
    return top, clipped, unpol, rising


def _harmonic(values: np.ndarray, unknown: np.ndarray) -> np.ndarray:
    """Solve Laplace's equation on ``unknown`` pixels with ``values`` fixed elsewhere (5-point stencil,
    natural boundary at the image border); returns a copy of ``values`` with the solution filled in."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    h, w = unknown.shape
    idx = -np.ones((h, w), np.int64)
    ys, xs = np.nonzero(unknown)
    n = len(ys)
    out = np.array(values, np.float64, copy=True)
    if n == 0:
        return out
    idx[ys, xs] = np.arange(n)
    rows, cols, vals = [], [], []
    diag = np.zeros(n)
    rhs = np.zeros(n)
    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        ny, nx = ys + dy, xs + dx
        inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
        diag += inside
        k = np.nonzero(inside)[0]
        j = idx[ny[k], nx[k]]
        free = j >= 0
        rows.append(k[free])
        cols.append(j[free])
        vals.append(-np.ones(int(free.sum())))
        fixed = k[~free]
        rhs[fixed] += values[ny[fixed], nx[fixed]]
    a = coo_matrix((np.concatenate([diag, *vals]),
                    (np.concatenate([np.arange(n), *rows]), np.concatenate([np.arange(n), *cols]))),
                   shape=(n, n)).tocsc()
    out[ys, xs] = spsolve(a, rhs)
    return out


def invented_structure(diffuse: np.ndarray, given: np.ndarray, *, clip_level: float = CLIP_LEVEL
                       ) -> tuple[float, float]:
    """Structure a diffuse layer invents inside clipped regions (module docstring).

    Parameters
    ----------
    diffuse
        (H, W, C) diffuse layer (C = 3, or 1 for mono).
    given
        (4, H, W, C) the stack the method separated.
    clip_level
        A sample at or above it is clipped.

    Returns
    -------
    invented : float
        Mean absolute departure of the diffuse from the harmonic membrane over its own values on
        the clipped regions' edges, per unit of the input's light there; NaN where no clipped
        region is large enough to judge.
    clipped_share : float
        Share of pixels in any channel's clipped region (before erosion).
    """
    from scipy import ndimage

    d = np.asarray(diffuse, np.float64)
    g = np.asarray(given, np.float64)
    inp = g.mean(axis=0)
    num = den = 0.0
    any_clip = np.zeros(d.shape[:2], bool)
    for c in range(d.shape[-1]):
        region = (g[..., c] >= clip_level).all(axis=0)
        any_clip |= region
        interior = ndimage.binary_erosion(region, border_value=1)
        lab, n = ndimage.label(interior)
        if n:
            sizes = np.bincount(lab.ravel())
            interior = (sizes >= MIN_REGION)[lab] & (lab > 0)
        if not interior.any():
            continue
        h = _harmonic(d[..., c], interior)
        num += float(np.abs(d[..., c] - h)[interior].sum())
        den += float(inp[..., c][interior].sum())
    return (num / den if den > 0 else float("nan")), float(any_clip.mean())


def run(data: Path, *, methods: Sequence[str] | None = None, scenes: Sequence[str] | None = None,
        variants: Sequence[str] | None = None, crop: Sequence[int] | None = None, scale: float = 0.5,
        mono: bool = False, options: dict[str, dict[str, Any]] | None = None,
        progress: bool = True) -> list[RelitScore]:
    """Every stack under every variant with every method.

    Parameters
    ----------
    data
        Folder of the real stacks (:func:`polcam.bench.real.find_scenes`).
    methods
        Method names (default: every registered method).
    scenes
        Only these stacks.
    variants
        Names from :data:`VARIANTS` (default: all).
    crop, scale
        Applied to the recorded stack first (:func:`polcam.bench.real.prepare`; default half scale).
    mono
        The mono camera: the relit stack's luminance (mean of R, G and B) through an IMX250MZR
        mosaic and the default demosaicing; methods default to those that take mono stacks,
        ``spread`` is 0 (one channel).
    options
        Per-method keyword options.

    Returns
    -------
    list of RelitScore
    """
    found, names, meths = _selection(data, scenes, variants, methods, mono)
    options = options or {}
    out: list[RelitScore] = []
    for name, files in found.items():
        recorded = prepare(load_stack(files), crop=crop, scale=scale)
        ach = achromatic_mask(recorded)
        for v in names:
            exposure, light = VARIANTS[v]
            true = relight(recorded, exposure=exposure, light=light)
            matte = matte_mask(ach, true)
            if mono:
                true = true.mean(axis=-1, keepdims=True)
                given = _mono_camera(true[..., 0])[..., None]
            else:
                given = camera_stack(true)
            masks = _brightest_masks(given, true)
            top = _composition(*masks)
            signs = masks[0] & masks[3] & ~masks[1] & ~masks[2]      # brightest, rising, unclipped, polarized
            for m in meths:
                out.append(replace(_score(name, v, m, given, true, matte, mono=mono, options=options.get(m, {}),
                                          highlight_like=signs), **top))
                if progress and out[-1].error is None:
                    s = out[-1]
                    print(f"  {name:<8} {v:<19} {m:<19} matte kept {s.matte_kept:.3f}  top1% {s.top_removed:.3f}  "
                          f"spread {s.spread:.3f}  invented {s.invented:.4f} (clipped {s.clipped_share:.1%})  "
                          f"{s.seconds:6.2f} s", flush=True)
    return out


def _selection(data: Path, scenes: Sequence[str] | None, variants: Sequence[str] | None,
               methods: Sequence[str] | None, mono: bool) -> tuple[dict[str, Any], list[str], list[str]]:
    """The stacks, variants and methods to run, each checked (PolcamError naming what is unknown)."""
    found = find_scenes(Path(data))
    if not found:
        raise PolcamError(f"--data {data}: no real colour stack found")
    if scenes:
        unknown = [s for s in scenes if s not in found]
        if unknown:
            raise PolcamError(f"scene(s) {', '.join(unknown)} not in {data}; found {', '.join(found)}")
        found = {k: v for k, v in found.items() if k in scenes}
    names = list(variants or VARIANTS)
    bad = [v for v in names if v not in VARIANTS]
    if bad:
        raise PolcamError(f"variant(s) {', '.join(bad)}: expected some of {', '.join(VARIANTS)}")
    meths = list(methods or [m for m in METHODS if not mono or method_spec(m).mono])
    for m in meths:
        method_spec(m)
    return found, names, meths


def _score(name: str, v: str, m: str, given: np.ndarray, true: np.ndarray, matte: np.ndarray, *, mono: bool,
           options: dict[str, Any], highlight_like: np.ndarray | None = None) -> RelitScore:
    """One method on one relit stack; a failing method is reported in ``error``, not fatal to the table."""
    t0 = time.perf_counter()
    try:
        res = separate(given[..., 0] if mono else given, method=m, **options)
    except Exception as exc:  # a failing method is reported, not fatal to the table
        return RelitScore(name, v, m, *([float("nan")] * 5), time.perf_counter() - t0,
                          error=f"{type(exc).__name__}: {exc}")
    sec = float(res.info.get("seconds", time.perf_counter() - t0))
    dif = res.diffuse[..., None] if mono else res.diffuse
    spe = res.specular[..., None] if mono else res.specular
    mt = metrics(dif, spe, given, true, achromatic=matte)
    inv, share = invented_structure(dif, given)
    signs = float("nan")
    if highlight_like is not None and highlight_like.any():
        inp = given.mean(axis=0)
        signs = float(spe[highlight_like].sum() / max(inp[highlight_like].sum(), 1e-12))
    return RelitScore(name, v, m, mt["achromatic_kept"], mt["top_removed"], mt["spread"], inv, share, sec,
                      top_removed_rising_polarized=signs)


def _mono_camera(true_grey: np.ndarray) -> np.ndarray:
    """What a mono polarization camera gives: (4, H, W) mosaicked (IMX250MZR), demosaiced, clipped."""
    raw = mosaic_stack(true_grey.astype(np.float32), layout="imx250mzr")
    return np.clip(demosaic(raw, layout="imx250mzr"), 0.0, 1.0).astype(np.float64)


def format_table(scores: Sequence[RelitScore]) -> str:
    """Markdown: one row per stack, variant and method; then what each stack's brightest 1 % holds."""
    lines = ["| stack | variant | method | matte achromatic kept | brightest 1 % removed | "
             "of it rising, unclipped, polarized | specular spread | invented in clipped regions | clipped pixels |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for s in scores:
        if s.error:
            lines.append(f"| {s.scene} | {s.variant} | {s.method} | error: {s.error} | | | | | |")
            continue
        inv = "-" if not np.isfinite(s.invented) else f"{s.invented:.4f}"
        sig = "-" if not np.isfinite(s.top_removed_rising_polarized) else f"{s.top_removed_rising_polarized:.3f}"
        lines.append(f"| {s.scene} | {s.variant} | {s.method} | {s.matte_kept:.3f} | {s.top_removed:.3f} | {sig} | "
                     f"{s.spread:.3f} | {inv} | {s.clipped_share:.1%} |")
    seen = {(s.scene, s.variant): s for s in scores if np.isfinite(s.top_clipped)}
    if seen:
        lines += ["", "What the brightest 1 % holds (shares of its pixels; `brightest_composition`):", "",
                  "| stack | variant | clipped | unpolarized | rising | rising, unclipped, polarized |",
                  "|---|---|---:|---:|---:|---:|"]
        lines += [f"| {s.scene} | {s.variant} | {s.top_clipped:.2f} | {s.top_unpolarized:.2f} | {s.top_rising:.2f} | "
                  f"{s.top_rising_polarized:.2f} |" for s in seen.values()]
    return "\n".join(lines)


def summary(scores: Sequence[RelitScore]) -> dict[str, dict[str, float]]:
    """Per method, the figures the default-method rule reads (:mod:`polcam.bench.default_rule`).

    Returns
    -------
    dict
        method -> ``matte_kept_min_mean`` (the lowest, over variants, of the mean over stacks),
        ``matte_kept_min`` (the lowest over stacks and variants), ``top_removed`` and ``spread``
        (means over stacks and variants), ``invented_max`` (the largest over stacks and variants
        with clipped regions; 0 where none clip).
    """
    out: dict[str, dict[str, float]] = {}
    for m in dict.fromkeys(s.method for s in scores):
        rows = [s for s in scores if s.method == m and not s.error]
        if not rows:
            continue
        variants = list(dict.fromkeys(s.variant for s in rows))
        means = [float(np.mean([s.matte_kept for s in rows if s.variant == v])) for v in variants]
        inv = [s.invented for s in rows if np.isfinite(s.invented)]
        out[m] = {
            "matte_kept_min_mean": min(means),
            "matte_kept_min": float(min(s.matte_kept for s in rows)),
            "top_removed": float(np.mean([s.top_removed for s in rows])),
            "spread": float(np.mean([s.spread for s in rows])),
            "invented_max": float(max(inv)) if inv else 0.0,
        }
    return out
