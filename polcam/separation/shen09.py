"""``shen09``: specularity removal with a modified specular-free image.

H.-L. Shen and Q.-Y. Cai, "Simple and efficient method for specularity
removal in an image", Applied Optics 48(14), 2711-2719, 2009.

Model: dichromatic reflection under a white illuminant, ``I_c = m_d Lambda_c +
m_s / 3``.  Subtracting ``I_min = min_c I`` removes the specular term (and part
of the diffuse one); adding back an offset gives the modified specular-free
(MSF) image, whose chromaticity approximates the diffuse chromaticity.  The
offset is a threshold on ``I_min`` that separates highlight pixels from
diffuse ones, and the amount of specular light removed is then scaled so
that colours change smoothly across the boundary of the highlight.

Steps as implemented:

1. ``T = mean(I_min) + nu std(I_min)`` over the image (``nu = 0.5``, the
   paper's value "for most materials").
2. Pseudo specular component ``beta = I_min - T`` where ``I_min > T``, else 0:
   the MSF image is ``I - beta`` (``I - I_min + T`` at highlight pixels, ``I``
   elsewhere).
3. Highlight region: pixels where ``beta / max(beta) > region_threshold``
   (0.1); the dominant region is its largest 8-connected component, and its
   surround the ring added by a ``ring x ring`` (5 x 5) square dilation.
4. Smooth transition across the boundary: the diffuse layer ``I - k beta`` of
   the dominant region should have the mean colour of its surround, which
   gives per channel ``k_c = (mean_dom I_c - mean_sur I_c) / (mean_dom beta -
   mean_sur beta)`` (the least-squares solution for a single region pair);
   ``k = min_c k_c`` (the specular light is white: one scale for all
   channels; the smallest keeps every channel non-negative longest).
5. Diffuse = ``I - k beta`` clipped to ``[0, I]``.

Defaults and their sources: ``nu = 0.5`` (paper); ``region_threshold = 0.1``
and ``ring = 5`` follow the SIHR toolbox's implementation of this paper
(V. S. Ramos, Zenodo 3381328), which reproduces the paper's PSNR figures.

Failure points: no highlight (``beta`` all 0), an empty surround (the
region fills the image), or a scale that is not finite and positive: ``k``
falls back to 1, the unscaled MSF estimate (a departure: the paper does not
discuss these cases).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import ndimage

from polcam.errors import MethodError
from polcam.separation._common import as_rgb_image, channel_min, finish_diffuse
from polcam.separation._registry import register

REFERENCE = (
    "H.-L. Shen and Q.-Y. Cai, Simple and efficient method for specularity removal in an "
    "image, Applied Optics 48(14), 2711-2719, 2009"
)

__all__ = ["REFERENCE", "separate_shen09"]

_EIGHT = np.ones((3, 3), dtype=bool)


@register("shen09", kind="single", reference=REFERENCE)
def separate_shen09(
    image: np.ndarray,
    *,
    nu: float = 0.5,
    region_threshold: float = 0.1,
    ring: int = 5,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer by Shen & Cai (Applied Optics 2009).

    Parameters
    ----------
    image
        (H, W, 3) float in [0, 1], linear RGB under a white (or
        white-balanced) illuminant.
    nu
        Specular degree in the threshold ``T = mean + nu std`` of ``I_min``.
    region_threshold
        Fraction of ``max(beta)`` above which a pixel belongs to the
        highlight region, in [0, 1).
    ring
        Side of the square structuring element whose dilation gives the
        surround of the dominant highlight region (odd, >= 3).

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) float64 with ``0 <= diffuse <= image``.
    info : dict
        ``threshold`` (T), ``k`` (the specular scale) and ``fallback`` (True
        when k fell back to 1).

    Raises
    ------
    MethodError
        Bad image or options.
    """
    image = as_rgb_image(image, method="shen09")
    if not (np.isfinite(nu) and nu >= 0):
        raise MethodError(f"shen09: nu={nu!r}: expected a non-negative number")
    if not (np.isfinite(region_threshold) and 0 <= region_threshold < 1):
        raise MethodError(f"shen09: region_threshold={region_threshold!r}: expected a number in [0, 1)")
    if int(ring) != ring or ring < 3 or ring % 2 == 0:
        raise MethodError(f"shen09: ring={ring!r}: expected an odd integer >= 3")
    i_min = channel_min(image)
    t = float(i_min.mean() + nu * i_min.std())
    beta = np.maximum(i_min - t, 0.0)
    k = 1.0
    fallback = True
    b_max = float(beta.max())
    if b_max > 0:
        region = beta > region_threshold * b_max
        labels, n = ndimage.label(region, structure=_EIGHT)
        if n:
            sizes = np.bincount(labels.ravel())
            sizes[0] = 0
            dominant = labels == int(np.argmax(sizes))
            grown = ndimage.binary_dilation(dominant, structure=np.ones((int(ring), int(ring)), dtype=bool))
            surround = grown & ~dominant
            if surround.any():
                d_beta = float(beta[dominant].mean() - beta[surround].mean())
                d_int = image[dominant].mean(axis=0) - image[surround].mean(axis=0)
                if d_beta > 1e-12:
                    k_c = float(np.min(d_int / d_beta))
                    if np.isfinite(k_c) and k_c > 0:
                        k, fallback = k_c, False
    diffuse = finish_diffuse(image - k * beta[..., None], image)
    return diffuse, {"threshold": t, "k": k, "fallback": fallback}
