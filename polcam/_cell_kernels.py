"""Compiled loops of the live maps (private; numba, imported on first use by :func:`polcam.pipeline.live_maps`).

Each loop does, in float32, the element operations of the OpenCV calls it replaces, in the
same order, so the results are those calls' bit for bit wherever the inputs are integer
counts (every sum is then exact in float32), and within a float32 rounding of them for a
corrected float mosaic.  They run without the GIL and are cached on disk.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["binomial3", "cell_stokes"]


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def cell_stokes(mosaic: np.ndarray, angle_rows: np.ndarray, angle_cols: np.ndarray,
                offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """S0 above black and S1, S2 of every 2 x 2 polarizer cell of a mosaic, float32.

    ``mosaic``: (H, W), H and W even, any real dtype; the sample of angle ``a`` (0, 45, 90,
    135 degrees as 0..3) in a cell is at row ``angle_rows[a]``, column ``angle_cols[a]`` of it.
    Per cell, with the four samples as float32::

        S0 = ((I0 + I90) + (I45 + I135)) * 0.5 + offset     (offset = -2 black: 2 S0 above black / 2)
        S1 = I0 - I90                                       S2 = I45 - I135

    Returns three (H/2, W/2) float32 arrays.
    """
    h2, w2 = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    s0 = np.empty((h2, w2), dtype=np.float32)
    s1 = np.empty((h2, w2), dtype=np.float32)
    s2 = np.empty((h2, w2), dtype=np.float32)
    r0, r1, r2, r3 = angle_rows[0], angle_rows[1], angle_rows[2], angle_rows[3]
    c0, c1, c2, c3 = angle_cols[0], angle_cols[1], angle_cols[2], angle_cols[3]
    half = np.float32(0.5)
    off = np.float32(offset)
    for y in range(h2):
        row0, row1, row2, row3 = mosaic[2 * y + r0], mosaic[2 * y + r1], mosaic[2 * y + r2], mosaic[2 * y + r3]
        for x in range(w2):
            i0 = np.float32(row0[2 * x + c0])
            i45 = np.float32(row1[2 * x + c1])
            i90 = np.float32(row2[2 * x + c2])
            i135 = np.float32(row3[2 * x + c3])
            s0[y, x] = ((i0 + i90) + (i45 + i135)) * half + off
            s1[y, x] = i0 - i90
            s2[y, x] = i45 - i135
    return s0, s1, s2


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def binomial3(a: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """The 3 x 3 binomial filter ``[1 2 1]^T [1 2 1] / 16`` of a (h, w) float32 image, h, w >= 2.

    OpenCV's ``GaussianBlur(a, (3, 3), 0, borderType=BORDER_REFLECT_101)``: rows first, then
    columns, each output ``centre * 0.5 + (before + after) * 0.25``, edges mirrored without
    repeating the edge sample.
    """
    h, w = a.shape
    rows = np.empty((h, w), dtype=np.float32)
    out = np.empty((h, w), dtype=np.float32)
    half, quarter = np.float32(0.5), np.float32(0.25)
    for y in range(h):
        r = a[y]
        t = rows[y]
        t[0] = r[0] * half + (r[1] + r[1]) * quarter
        for x in range(1, w - 1):
            t[x] = r[x] * half + (r[x - 1] + r[x + 1]) * quarter
        t[w - 1] = r[w - 1] * half + (r[w - 2] + r[w - 2]) * quarter
    for y in range(h):
        up = rows[y - 1] if y > 0 else rows[1]
        down = rows[y + 1] if y < h - 1 else rows[h - 2]
        mid = rows[y]
        o = out[y]
        for x in range(w):
            o[x] = mid[x] * half + (up[x] + down[x]) * quarter
    return out
