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

from polcam.separation.tensor.xp import namespace

__all__ = ["tile_spans", "ramps", "tile_windows", "tile_batch", "blend", "tiled"]


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
