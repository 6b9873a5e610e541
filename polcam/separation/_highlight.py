"""Where a pixel stands above its surroundings in the illuminant's colour: the evidence of a highlight.

Used by ``polarized-residual`` (docs/methods/polarized-residual.md, "Highlight evidence"): the
specular layer of a pixel is bounded by how far the pixel rises above the floor of its
neighbourhood, in every channel at once, by a multiple of the illuminant's colour.
"""

from __future__ import annotations

from typing import Any

from polcam import _imageops
from polcam._xp import namespace
from polcam.separation._common import min3

__all__ = ["EVIDENCE_MEDIAN", "FLOOR_QUANTILE", "peak_excess", "surroundings_floor"]

#: Side of the median filter its callers take before the opening: it keeps demosaicing's one- or
#: two-pixel overshoot at edges out of both the pixel's level and its surroundings' floor.
EVIDENCE_MEDIAN = 5
#: The quantile of the surroundings' level that is their floor in the rank opening: the lower
#: quartile.  Darker features that reach into every window but cover under a quarter of it (holes
#: and pits, the gaps between patches, print, narrow shadows) do not lower the floor of the surface
#: around them; a highlight that covers up to three quarters of the window still rises above it.
#: Chosen on the first 400 validation scenes with the learned stage retrained for each
#: (docs/decisions/evidence-floor.md): the plain opening alone 28.22 dB, best or within 0.3 dB of
#: imin and wen21 on 85.2 %; 0.1: 28.22, 84.0 %; 0.25: 28.20, 83.5 %; and against the matte colour
#: chart of :func:`polcam.bench.residual_training.colour_chart`, whose worst grey patch keeps 0.979,
#: 0.951 and 0.985 of its light (the floor of the training command's checks is 0.97).
FLOOR_QUANTILE = 0.25
#: Levels of the quantile filter: it finds the quantile to within ``1 / (_LEVELS - 1)`` of the
#: channel's range, exactly on a plateau (the plain opening bounds the floor from below).
_LEVELS = 128
#: Larger images are shrunk by an integer factor to about this side before the quantile filter
#: (the learned stage's training side): a floor is a level of the surroundings, not of single pixels.
_RANK_SIDE = 128


def peak_excess(ic: Any, g: Any, *, window: int, smooth: int) -> Any:
    """The largest multiple of ``g`` that a pixel holds above its neighbourhood's floor, per pixel.

    A specular highlight adds ``s G`` to the diffuse light of a surface: in every channel the
    pixel rises above the same surface around it by ``s G_c``.  The floor of the surroundings is the
    morphological opening (an erosion, then a dilation, by a ``window`` x ``window`` square) of
    ``ic`` Gaussian-smoothed over ``smooth`` pixels (so that the erosion does not pick the noise's
    minimum): the opening keeps every structure wider than the window (a shaded surface's
    monotone fall-off to an occluding contour, a uniform patch, a step between materials) and
    removes the peaks narrower than it.  The excess is

        E = max(0, min_c (ic_c - open(ic_s)_c) / g_c)

    so ``ic - E g >= open(ic_s)`` in every channel: a layer that removes at most ``E g`` never
    digs below the surroundings' floor in any channel (no dark or coloured pits), and takes
    nothing from a uniform matte patch, a material edge, or a matte rim however polarized its
    light.  A peak in one channel only (a thin coloured line on another colour) has no excess.

    Parameters
    ----------
    ic
        (H, W, 3) float32 mean over angles (numpy or torch).
    g
        (3,) float32 illuminant colour, mean 1, of the same kind.
    window
        Odd side in pixels of the opening's square.
    smooth
        Odd side of the median filter applied before the openings.

    Returns
    -------
    (H, W) float32 >= 0, in units of ``g``, of the same kind as ``ic``.
    """
    xp = namespace(ic)
    base = _imageops.median(ic, smooth)
    excess = min3((xp.minimum(ic, base) - surroundings_floor(base, window)) / g)
    return xp.astype(xp.maximum(excess, 0.0), xp.float32)


def surroundings_floor(base: Any, window: int) -> Any:
    """The floor of a pixel's surroundings: the larger of the opening and the rank opening of ``base``.

    Parameters
    ----------
    base
        (H, W, 3) float32 level (numpy or torch), the mean over angles median-filtered.
    window
        Odd side in pixels of the square.

    Returns
    -------
    (H, W, 3) float32 of the same kind, at most the largest value of ``base`` in each channel.

    Notes
    -----
    The rank opening is ``dilate(Q(base))``, ``Q`` the :data:`FLOOR_QUANTILE` quantile over the
    square (:func:`_quantile_filter`).  An image whose larger side is at least twice
    :data:`_RANK_SIDE` is shrunk by the integer factor ``f = side // _RANK_SIDE`` (area) for it, with
    the square's side divided by ``f``, and the result brought back (bilinear); the plain opening,
    at full resolution, keeps the floor exact at the edges of the surfaces wider than the window.
    """
    xp = namespace(base)
    opened = _imageops.dilate(_imageops.erode(base, window), window)
    f = max(base.shape[:2]) // _RANK_SIDE
    if f < 2:
        ranked = _imageops.dilate(_quantile_filter(base, window, FLOOR_QUANTILE), window)
    else:
        k = max(int(round(window / f)) // 2 * 2 + 1, 3)
        ranked = _imageops.shrunk(base, f, lambda small: _imageops.dilate(_quantile_filter(small, k, FLOOR_QUANTILE), k))
    return xp.maximum(opened, ranked)


def _quantile_filter(a: Any, k: int, q: float) -> Any:
    """The ``q`` quantile of each channel over the ``k x k`` square around each pixel, (H, W, 3) as ``a``.

    From the share of the square below each of :data:`_LEVELS` thresholds spread over the channel's
    range, and the sum of those values (box filters, border reflected as
    :func:`polcam._imageops.box`): the quantile lies between the last threshold whose share is
    under ``q`` and the first at or above it, and is taken as the mean of the square's values
    between the two: exact on a plateau (a uniform surface between darker features), within one
    level elsewhere.
    """
    xp = namespace(a)
    lo = xp.amin(a, axis=(0, 1))
    step = (xp.amax(a, axis=(0, 1)) - lo) / float(_LEVELS - 1)
    below = xp.zeros(a.shape, like=a)
    below_sum = below
    est = below + (lo + step * float(_LEVELS - 1))           # the channel's largest value (a constant channel's)
    done = below > 0.0                                       # all False
    for j in range(1, _LEVELS + 1):
        under = xp.astype(a < lo + step * (float(j) - 0.5), xp.float32)
        share = _imageops.box(under, k)
        total = _imageops.box(a * under, k)
        new = (share >= q) & ~done
        est = xp.where(new, (total - below_sum) / xp.maximum(share - below, 1e-6), est)
        done = done | new
        below, below_sum = share, total
    return xp.astype(est, xp.float32)
