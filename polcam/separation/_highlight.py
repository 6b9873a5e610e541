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

__all__ = ["EVIDENCE_MEDIAN", "peak_excess"]

#: Side of the median filter its callers take before the opening: it keeps demosaicing's one- or
#: two-pixel overshoot at edges out of both the pixel's level and its surroundings' floor.
EVIDENCE_MEDIAN = 5


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
        Odd side of the Gaussian applied before the opening.

    Returns
    -------
    (H, W) float32 >= 0, in units of ``g``, of the same kind as ``ic``.
    """
    xp = namespace(ic)
    base = _imageops.median(ic, smooth)
    floor = _imageops.dilate(_imageops.erode(base, window), window)
    excess = min3((xp.minimum(ic, base) - floor) / g)
    return xp.astype(xp.maximum(excess, 0.0), xp.float32)
