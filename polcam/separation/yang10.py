"""``yang10``: highlight removal by bilateral filtering of the maximum chromaticity.

Q. Yang, S. Wang and N. Ahuja, "Real-time specular highlight removal using
bilateral filtering", ECCV 2010, LNCS 6314, pp. 87-100.

Model: dichromatic reflection under a white illuminant, ``I_c = m_d Lambda_c +
m_s / 3`` (input white-balanced).  Notation: ``sigma_c = I_c / sum I`` the
chromaticity, ``sigma_max``/``sigma_min`` its largest/smallest channel,
``Lambda_max`` the maximum diffuse chromaticity.

Steps as implemented:

1. ``sigma_max = max_c I_c / sum I``.
2. Approximate ``Lambda_max`` by the maximum chromaticity of the minimal
   specular-free image, ``lambda_max = max_c (sigma_c - sigma_min) /
   (1 - 3 sigma_min)`` (paper Sec. 3.2; 1/3 where ``1 - 3 sigma_min = 0``).
3. Repeat: ``sigma_F = JBF[sigma_max]`` guided by ``lambda_max`` (joint bilateral
   filter, spatial and range Gaussians); ``sigma_max <- max(sigma_max, sigma_F)``;
   stop when no pixel changed by more than ``threshold`` (0.03, paper).
4. With ``Lambda_max = sigma_max``, the specular term per channel is
   ``(max_c I - Lambda_max sum I) / (1 - 3 Lambda_max)`` (paper eq. 5; see
   :func:`polcam.separation._common.diffuse_from_max_chromaticity`) and the
   diffuse layer is the input minus it.

Defaults and their sources: ``sigma_spatial = 0.25`` of the smaller image
side, ``sigma_range = 0.04`` and ``threshold = 0.03`` (the paper's values, as
its constant-time bilateral filter is described; the authors' released code uses the same
spatial sigma and threshold, and the SIHR toolbox's reproduction, V. S. Ramos,
Zenodo 3381328, all three);
``dark = 20/255`` (the authors' released code, ``QX_DEF_DARK_PIXEL``: pixels whose
largest channel is at most this are excluded from the filter and returned
unchanged, their chromaticity being noise).  The filter is the constant-time
approximation of :mod:`polcam.filters` (range levels spaced at most
``sigma_range`` apart; the authors' code uses 10 levels over the guide's span).

Departures: the filter splats every pixel onto its coarse grid (the authors'
code point-subsamples); dark pixels get weight 0 in the filter (the authors'
code feeds them in with guide 0, never updating them); ``max_iter`` (default
50) bounds the loop (the paper iterates to convergence; ``info['converged']``
says whether it did); on an achromatic estimate (``3 Lambda_max - 1 <= 1e-6``)
nothing is removed (the split is undetermined there; the authors' code also
keeps the input where its denominator vanishes).

The range sigma: the authors' code applies 10/255 to ``lambda_max`` rescaled
from [1/3, 1] to [0, 1], i.e. ``sigma_range = 0.04 / 1.5`` here, with 10
levels; those settings reproduce the paper's own PSNR figures on Shen &
Zheng's images (docs/methods/yang10.md), the default reproduces the
SIHR toolbox's.  Both are within 1 dB of either.

Backends: the method is written over the array namespace of
:mod:`polcam._xp`, as its filter and helpers are.  A numpy image is the
registered method; a ``torch.Tensor`` runs every step on its device in
float64 and returns a tensor there (the tensor method's initial diffuse with
``device=``; equal to the numpy result to rounding, tested).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.filters import JointBilateral
from polcam.separation._common import (
    as_rgb_image,
    channel_max,
    channel_sum,
    diffuse_from_max_chromaticity,
    safe_divide,
    specular_free_chromaticity,
)
from polcam.separation._registry import register

REFERENCE = (
    "Q. Yang, S. Wang and N. Ahuja, Real-time specular highlight removal using bilateral "
    "filtering, ECCV 2010, LNCS 6314, pp. 87-100"
)

__all__ = ["REFERENCE", "separate_yang10", "max_diffuse_chromaticity"]


def max_diffuse_chromaticity(
    image: np.ndarray,
    *,
    sigma_spatial: float | None = None,
    sigma_range: float = 0.04,
    threshold: float = 0.03,
    dark: float = 20.0 / 255.0,
    levels: int | None = None,
    max_iter: int = 50,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Yang et al.'s estimate of the maximum diffuse chromaticity.

    Parameters
    ----------
    image
        (H, W, 3) float64 in [0, 1] (numpy array or torch tensor).
    sigma_spatial, sigma_range, threshold, dark, levels, max_iter
        See :func:`separate_yang10`.

    Returns
    -------
    lam : numpy.ndarray or torch.Tensor
        (H, W) estimate of ``Lambda_max`` in [1/3, 1] (the filtered
        ``sigma_max``; dark pixels keep their own ``sigma_max``), of the
        image's kind.
    bright : numpy.ndarray or torch.Tensor
        (H, W) bool, the pixels processed (not dark).
    info : dict
        ``iterations``, ``converged``.
    """
    xp = namespace(image)
    h, w, _ = image.shape
    i_max = channel_max(image)
    sigma_max = safe_divide(i_max, channel_sum(image), fill=1.0 / 3.0)
    bright = i_max > dark
    if not bool(bright.any()):
        return sigma_max, bright, {"iterations": 0, "converged": True}
    lam_guide = channel_max(specular_free_chromaticity(image))
    if sigma_spatial is None:
        sigma_spatial = 0.25 * min(h, w)
    filt = JointBilateral(
        lam_guide,
        sigma_spatial=sigma_spatial,
        sigma_range=sigma_range,
        levels=levels,
        weights=xp.astype(bright, xp.float64),
    )
    converged = False
    iterations = 0
    while iterations < max_iter:
        filtered = filt(sigma_max)
        iterations += 1
        changed = bool(((filtered - sigma_max > threshold) & bright).any())
        sigma_max = xp.where(bright, xp.maximum(sigma_max, filtered), sigma_max)
        if not changed:
            converged = True
            break
    return sigma_max, bright, {"iterations": iterations, "converged": converged}


@register("yang10", kind="single", reference=REFERENCE)
def separate_yang10(
    image: np.ndarray,
    *,
    sigma_spatial: float | None = None,
    sigma_range: float = 0.04,
    threshold: float = 0.03,
    dark: float = 20.0 / 255.0,
    levels: int | None = None,
    max_iter: int = 50,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer by Yang, Wang & Ahuja (ECCV 2010).

    Parameters
    ----------
    image
        (H, W, 3) float in [0, 1], linear RGB under a white (or
        white-balanced) illuminant: a numpy array, or a ``torch.Tensor``
        (any float dtype) to run on its device.
    sigma_spatial
        Spatial sigma of the joint bilateral filter in pixels (None: 0.25 of
        the smaller image side, the paper's value).
    sigma_range
        Range sigma on ``lambda_max`` (0.04, the paper's value).
    threshold
        Stop when no pixel's ``sigma_max`` rises by more than this (0.03).
    dark
        Pixels with ``max_c I <= dark`` are left unchanged (20/255, the
        authors' code); 0 processes every pixel with a non-zero channel.
    levels
        Range levels of the constant-time filter (None: automatic).
    max_iter
        Bound on the iterations.

    Returns
    -------
    diffuse : numpy.ndarray or torch.Tensor
        (H, W, 3) float64 with ``0 <= diffuse <= image``, of the image's
        kind (a tensor on the image's device).
    info : dict
        ``iterations`` and ``converged``.

    Raises
    ------
    MethodError
        Bad image or options.
    """
    image = as_rgb_image(image, method="yang10")
    for name, val in (("sigma_range", sigma_range), ("threshold", threshold)):
        if not (np.isfinite(val) and val > 0):
            raise MethodError(f"yang10: {name}={val!r}: expected a positive number")
    if sigma_spatial is not None and not (np.isfinite(sigma_spatial) and sigma_spatial > 0):
        raise MethodError(f"yang10: sigma_spatial={sigma_spatial!r}: expected a positive number of pixels")
    if not (np.isfinite(dark) and 0 <= dark < 1):
        raise MethodError(f"yang10: dark={dark!r}: expected an intensity in [0, 1)")
    if int(max_iter) != max_iter or max_iter < 1:
        raise MethodError(f"yang10: max_iter={max_iter!r}: expected an integer >= 1")
    lam, bright, info = max_diffuse_chromaticity(
        image,
        sigma_spatial=sigma_spatial,
        sigma_range=sigma_range,
        threshold=threshold,
        dark=dark,
        levels=levels,
        max_iter=int(max_iter),
    )
    diffuse = diffuse_from_max_chromaticity(image, lam)
    diffuse = namespace(image).where(bright[..., None], diffuse, image)
    return diffuse, info
