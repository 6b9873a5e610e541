"""``shen13``: real-time highlight removal using the intensity ratio.

H.-L. Shen and Z.-H. Zheng, "Real-time highlight removal using intensity
ratio", Applied Optics 52(19), 4483-4493, 2013.

Model: dichromatic reflection under a white illuminant, ``I_c = m_d Lambda_c +
m_s / 3``.  The specular term adds the same amount to every channel, so the
range ``I_range = max_c I - min_c I = m_d (Lambda_max - Lambda_min)`` does not
see it, while ``max_c I = m_d Lambda_max + m_s / 3`` does.  For the diffuse
light of one material the intensity ratio ``Q = I_max / I_range = Lambda_max /
(Lambda_max - Lambda_min)`` is a constant; specular light raises it.  Hence,
with ``Q`` estimated per material, ``m_s / 3 = I_max - Q I_range``.

Steps as implemented:

1. ``I_min``, ``I_max``, ``I_range`` per pixel; ``mu = mean over the image of
   I_min``.  Pixels with ``I_min > mu`` are processed (darker ones, which hold
   little specular light, are returned unchanged).
2. Pseudo-chromaticity of each processed pixel: the chromaticity of the
   modified specular-free image ``I - I_min + mu`` reduced to its smallest
   and largest component (the pair ``(c_min, c_max)``).
3. Clustering of the pseudo-chromaticities: pixels in raster order; an
   unassigned pixel seeds a cluster that takes every unassigned pixel within
   an L1 distance ``chroma_threshold`` (0.3) of the seed; then every pixel is
   reassigned to the nearest cluster mean (L1).
4. Per cluster, ``Q`` is the ``percentile`` (0.5: the median) of ``I_max /
   I_range`` over its pixels with ``I_range > mu`` (a small range gives an
   unreliable ratio).
5. ``m_s / 3 = max(I_max - Q I_range, 0)``; diffuse = ``I - m_s / 3`` clipped to
   ``[0, I]``.

Defaults and their sources: ``chroma_threshold = 0.3`` and ``percentile =
0.5`` and the offset ``mu`` are those of the authors' released implementation
(``sp_removal.cpp``, as documented by the SIHR toolbox, V. S. Ramos, Zenodo
3381328); the paper describes the same pipeline.

Departures: a cluster with no pixel of reliable ratio is left unchanged (in
the authors' code its ratio stays 0, which removes the whole largest channel:
black pixels); the reassignment step uses the true nearest mean (the SIHR
port starts its search from the second cluster's distance); the percentile
is taken at rank ``floor(percentile * n)`` of the n sorted ratios.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.separation._common import (
    as_rgb_image,
    channel_max,
    channel_min,
    channel_sum,
    finish_diffuse,
    safe_divide,
)
from polcam.separation._registry import register

REFERENCE = (
    "H.-L. Shen and Z.-H. Zheng, Real-time highlight removal using intensity ratio, "
    "Applied Optics 52(19), 4483-4493, 2013"
)

__all__ = ["REFERENCE", "separate_shen13", "cluster_pseudo_chromaticity", "cluster_ratios", "ratio_specular"]


def cluster_pseudo_chromaticity(pseudo: Any, threshold: float) -> Any:
    """Shen & Zheng's clustering of pseudo-chromaticities.

    Parameters
    ----------
    pseudo
        (N, 2) pseudo-chromaticities ``(c_min, c_max)`` in raster order (numpy, or a
        ``torch.Tensor`` clustered on its device).
    threshold
        L1 radius of a cluster around its seed.

    Returns
    -------
    numpy.ndarray or torch.Tensor
        (N,) int cluster labels 0..K-1, each pixel assigned to the nearest
        cluster mean.
    """
    xp = namespace(pseudo)
    n = pseudo.shape[0]
    labels = xp.zeros((n,), like=pseudo, dtype=xp.index) - 1
    remaining = xp.arange(n, like=pseudo)
    k = 0
    while remaining.shape[0]:
        seed = pseudo[remaining[0]]
        near = abs(pseudo[remaining] - seed).sum(axis=1) < threshold
        near[0] = True
        labels[remaining[near]] = k
        remaining = remaining[~near]
        k += 1
    if xp.name == "numpy":
        counts = np.bincount(labels, minlength=k).astype(np.float64)
        means = np.stack([np.bincount(labels, weights=pseudo[:, j], minlength=k) / counts for j in range(2)],
                         axis=1)
    else:  # torch: the same sums with index_add (bincount takes no 2-D weights)
        counts = xp.zeros((k,), like=pseudo).index_add(0, labels, pseudo.new_ones(n))
        means = xp.zeros((k, 2), like=pseudo).index_add(0, labels, pseudo) / counts[:, None]
    # Nearest mean by L1 distance, in chunks to bound memory.
    out = xp.zeros((n,), like=pseudo, dtype=xp.index)
    chunk = max(1, 2_000_000 // max(k, 1))
    for start in range(0, n, chunk):
        d = abs(pseudo[start:start + chunk, None, :] - means[None]).sum(axis=2)
        out[start:start + chunk] = xp.argmax(-d, axis=1)
    return out


@register("shen13", kind="single", reference=REFERENCE)
def separate_shen13(
    image: np.ndarray,
    *,
    chroma_threshold: float = 0.3,
    percentile: float = 0.5,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer by Shen & Zheng (Applied Optics 2013).

    Parameters
    ----------
    image
        (H, W, 3) float in [0, 1], linear RGB under a white (or
        white-balanced) illuminant.
    chroma_threshold
        L1 radius of a pseudo-chromaticity cluster (0.3).
    percentile
        Quantile of the intensity ratios taken as the cluster's diffuse ratio
        (0.5, the median).

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) float64 with ``0 <= diffuse <= image``.
    info : dict
        ``clusters``: the number of clusters found.

    Raises
    ------
    MethodError
        Bad image or options.
    """
    image = as_rgb_image(image, method="shen13")
    if not (np.isfinite(chroma_threshold) and chroma_threshold > 0):
        raise MethodError(f"shen13: chroma_threshold={chroma_threshold!r}: expected a positive number")
    if not (np.isfinite(percentile) and 0 <= percentile <= 1):
        raise MethodError(f"shen13: percentile={percentile!r}: expected a number in [0, 1]")
    q_map, n_clusters = cluster_ratios(image, chroma_threshold=chroma_threshold, percentile=percentile)
    return finish_diffuse(image - ratio_specular(image, q_map)[..., None], image), {"clusters": n_clusters}


def cluster_ratios(
    image: Any, *, chroma_threshold: float = 0.3, percentile: float = 0.5
) -> tuple[Any, int]:
    """Steps 1-4 of :func:`separate_shen13`: each processed pixel's cluster intensity ratio ``Q``.

    Parameters
    ----------
    image
        (H, W, 3) float RGB (checked by the caller): numpy, or a ``torch.Tensor`` (computed on
        its device, float64).
    chroma_threshold, percentile
        As :func:`separate_shen13`.

    Returns
    -------
    q_map : numpy.ndarray or torch.Tensor
        (H, W) float64: ``Q`` of the pixel's cluster; NaN where the pixel is not processed
        (``I_min <= mu``) or its cluster has no reliable ratio.
    clusters : int
        The number of clusters (0 when no pixel is processed).
    """
    i_min = channel_min(image)
    xp = namespace(i_min)
    i_max = channel_max(image)
    i_range = i_max - i_min
    mu = float(i_min.mean())
    mask = i_min > mu
    q_map = xp.zeros(image.shape[:2], like=i_min) + float("nan")
    if not bool(mask.any()):
        return q_map, 0

    pix = xp.asarray(image, dtype=xp.float64)[mask]
    msf = pix - i_min[mask][:, None] + mu
    chroma = safe_divide(msf, channel_sum(msf)[:, None], fill=1.0 / 3.0)
    pseudo = xp.stack([channel_min(chroma), channel_max(chroma)], axis=1)
    labels = cluster_pseudo_chromaticity(pseudo, float(chroma_threshold))
    n_clusters = int(labels.max()) + 1

    reliable = i_range[mask] > mu
    ratio = safe_divide(i_max[mask], i_range[mask], fill=0.0)
    q = xp.zeros((n_clusters,), like=ratio) + float("nan")
    for k in range(n_clusters):
        r = ratio[(labels == k) & reliable]
        if r.shape[0]:
            rank = min(int(percentile * r.shape[0]), r.shape[0] - 1)
            # the value of that rank in sorted order (np.partition; torch's kthvalue counts from 1)
            q[k] = np.partition(r, rank)[rank] if xp.name == "numpy" else r.kthvalue(rank + 1).values
    q_map[mask] = q[labels]
    return q_map, n_clusters


def ratio_specular(image: Any, q_map: Any) -> Any:
    """Step 5 of :func:`separate_shen13`: ``m_s / 3 = max(I_max - Q I_range, 0)``, 0 where ``Q`` is NaN.

    ``image`` is (H, W, 3), ``q_map`` (H, W) (:func:`cluster_ratios`, or a filtered copy), numpy or
    torch; returns (H, W) float64 of the same kind.
    """
    i_max = channel_max(image)
    xp = namespace(i_max)
    i_range = i_max - channel_min(image)
    ok = xp.isfinite(q_map)
    return xp.where(ok, xp.maximum(i_max - xp.where(ok, q_map, 0.0) * i_range, 0.0), 0.0)
