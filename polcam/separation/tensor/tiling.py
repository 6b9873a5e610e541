"""Overlapping tiles: where they lie, how their per-tile results are blended.

Above :data:`~polcam.separation.tensor.options.AUTO_UNTILED_PIXELS` pixels the
fast solver splits the image into overlapping tiles, each its own tensor
problem; :func:`blend` joins their diffuse layers.  Written once for numpy
arrays and PyTorch tensors.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from polcam._xp import namespace

__all__ = ["tile_spans", "ramps", "tile_windows", "tile_batch", "blend", "tiled", "seam_jumps"]


def tile_spans(n: int, tile: int, overlap: int) -> list[tuple[int, int]]:
    """Start/stop of tiles of side ``tile`` covering ``0 .. n`` with at least ``overlap`` shared.

    One span ``(0, n)`` when ``n <= tile``; otherwise tiles of exactly ``tile``
    pixels, evenly spread so the first starts at 0 and the last stops at n.
    """
    if n <= tile:
        return [(0, n)]
    count = math.ceil((n - overlap) / (tile - overlap))
    starts = np.round(np.linspace(0, n - tile, count)).astype(int)
    return [(int(a), int(a) + tile) for a in starts]


def ramps(spans: Sequence[tuple[int, int]]) -> list[np.ndarray]:
    """Blending weight of each tile along one axis: a linear ramp over the parts it shares."""
    out = []
    for i, (a, b) in enumerate(spans):
        wt = np.ones(b - a)
        x = np.arange(a, b) + 0.5
        if i > 0 and spans[i - 1][1] > a:                    # rise over the part shared with the previous
            wt = np.minimum(wt, (x - a) / (spans[i - 1][1] - a))
        if i + 1 < len(spans) and spans[i + 1][0] < b:       # fall over the part shared with the next
            wt = np.minimum(wt, (b - x) / (b - spans[i + 1][0]))
        out.append(wt)
    return out


def _pair(tile: int | tuple[int, int]) -> tuple[int, int]:
    """(height, width) of a tile given as one side or a pair."""
    if isinstance(tile, (tuple, list)):
        return int(tile[0]), int(tile[1])
    return int(tile), int(tile)


def _spans(shape: tuple[int, int], tile: int | tuple[int, int], overlap: int
           ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    th, tw = _pair(tile)
    return tile_spans(shape[0], th, overlap), tile_spans(shape[1], tw, overlap)


def tile_windows(shape: tuple[int, int], tile: int | tuple[int, int], overlap: int
                 ) -> list[tuple[slice, slice]]:
    """(rows, cols) windows of the tiles of an (H, W) image, row by row (:func:`tile_spans`).

    ``tile`` is the side of square tiles or their (height, width).
    """
    ys, xs = _spans(shape, tile, overlap)
    return [(slice(*y), slice(*x)) for y in ys for x in xs]


def tile_batch(images: Any, ys: Sequence[tuple[int, int]], xs: Sequence[tuple[int, int]]) -> Any:
    """Every tile of (n4, 4, H, W, 3) images, unfolded: (tiles, n4, 4 n1, 3 n2).

    Tiles row by row over the spans ``ys`` x ``xs`` (all of one size); each is
    :func:`polcam.separation.tensor.operators.unfold` of its window.
    """
    xp = namespace(images)
    ry = xp.index_array([np.arange(a, b) for a, b in ys], like=images)
    rx = xp.index_array([np.arange(a, b) for a, b in xs], like=images)
    n4, na = images.shape[:2]
    t = images[:, :, ry[:, None, :, None], rx[None, :, None, :]]      # (n4, 4, ny, nx, n1, n2, 3)
    ny, nx, n1, n2, c = t.shape[2:]
    return xp.permute(t, (2, 3, 0, 1, 4, 6, 5)).reshape(ny * nx, n4, na * n1, c * n2)


def blend(shape: tuple[int, int], tile: int | tuple[int, int], overlap: int, results: Any) -> Any:
    """Blend per-tile results (in :func:`tile_windows` order) into one (H, W, C) image.

    Per pixel: the average of the tiles covering it, each weighted by a
    separable linear ramp that falls to zero across the part it shares with a
    neighbour (a tile's edge pixels count least), normalised by the sum of the
    weights, so overlapping constant results blend to that constant.

    Parameters
    ----------
    shape
        (H, W).
    tile, overlap
        As :func:`tile_windows`.
    results
        (tiles, n1, n2, C) array or a list of (n1, n2, C) arrays (numpy or torch).

    Returns
    -------
    array
        (H, W, C) float64.
    """
    h, w = shape
    ys, xs = _spans(shape, tile, overlap)
    if len(results) != len(ys) * len(xs):
        raise ValueError(f"{len(results)} tile results for {len(ys) * len(xs)} tiles")
    xp = namespace(results[0])
    wy, wx = ramps(ys), ramps(xs)
    acc = xp.zeros((h, w, results[0].shape[-1]), like=results[0], dtype=xp.float64)
    wsum = xp.zeros((h, w, 1), like=results[0], dtype=xp.float64)
    for n in range(len(results)):
        i, j = divmod(n, len(xs))
        rows, cols = slice(*ys[i]), slice(*xs[j])
        wt = xp.asarray((wy[i][:, None] * wx[j][None, :])[..., None], like=acc)
        acc[rows, cols] += wt * xp.astype(results[n], xp.float64)
        wsum[rows, cols] += wt
    return acc / wsum


def tiled(shape: tuple[int, int], tile: int | tuple[int, int], overlap: int,
          solve: Callable[[slice, slice], np.ndarray], *, workers: int = 1) -> np.ndarray:
    """Run ``solve`` on overlapping tiles (in threads) and :func:`blend` the results.

    Parameters
    ----------
    shape
        (H, W) of the image.
    tile, overlap
        Tile side (or (height, width)) and the least overlap between neighbours (pixels).
    solve
        ``solve(rows, cols)`` returns the (h, w, C) result for that window.
    workers
        Threads running tiles at once.

    Returns
    -------
    numpy.ndarray
        (H, W, C) float64.
    """
    windows = tile_windows(shape, tile, overlap)
    if workers > 1 and len(windows) > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            results = list(pool.map(lambda rc: solve(*rc), windows))
    else:
        results = [solve(*rc) for rc in windows]
    return blend(shape, tile, overlap, results)


def seam_jumps(layer: np.ndarray, *, tile: int | tuple[int, int], overlap: int,
               reference: np.ndarray | None = None, flat: float = 0.5) -> tuple[float, float]:
    """How much a blended (H, W, C) layer jumps across tile borders and inside tiles.

    The jump of a pixel pair is ``mean_C |f(q) - f(p)|`` over horizontally and
    vertically adjacent pixels, with ``f = layer`` or, given a ``reference``
    (the input the layer was computed from), ``f = layer / max(reference, 1e-3)``
    per channel (the share of the light kept, whose jumps show a seam in
    intensity or colour and not the input's own edges), counted only over pairs
    whose reference jump is at most its ``flat`` quantile (flat areas, where a
    seam shows).  A pair is at a border when it touches the part two
    neighbouring tiles share (:func:`tile_spans`).  With the true layer known,
    pass ``layer = estimate - truth`` and no reference: the error's jumps.

    Returns
    -------
    border, inside : float
        Mean jump of the pairs at tile borders and of all others; a seam makes
        the first larger (a ratio near 1: no seam).
    """
    f = np.asarray(layer, dtype=np.float64)
    ref = None if reference is None else np.asarray(reference, dtype=np.float64)
    if ref is not None:
        f = f / np.maximum(ref, 1e-3)
    h, w = f.shape[:2]
    ys, xs = _spans((h, w), tile, overlap)
    at, away = [], []
    for axis, spans in ((0, ys), (1, xs)):
        jump = np.abs(np.diff(f, axis=axis)).mean(axis=-1)
        border = np.zeros(f.shape[axis] - 1, bool)
        for (_, b0), (a1, _) in zip(spans, spans[1:]):
            border[max(a1 - 1, 0):b0] = True
        border = np.broadcast_to(border[:, None] if axis == 0 else border[None, :], jump.shape)
        keep = np.ones(jump.shape, bool)
        if ref is not None:
            rj = np.abs(np.diff(ref, axis=axis)).mean(axis=-1)
            keep = rj <= np.quantile(rj, flat)
        at.append(jump[keep & border])
        away.append(jump[keep & ~border])
    return float(np.concatenate(at).mean()), float(np.concatenate(away).mean())
