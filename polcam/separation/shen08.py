"""``shen08``: chromaticity-based separation of Shen, Zhang, Shao & Xin.

H.-L. Shen, H.-G. Zhang, S.-J. Shao and J. H. Xin, "Chromaticity-based
separation of reflection components in a single image", Pattern Recognition
41(8), pp. 2461-2469, 2008.

Model: dichromatic reflection under a white (white-balanced) illuminant,
``I = m_d B + m_s (1, 1, 1)`` with ``B`` the body (diffuse) colour.
Notation: ``I_min = min_c I_c``, ``I_max = max_c I_c``.

Equations as implemented:

1. Modified specular-free (MSF) image: ``V = I - I_min + tau`` with ``tau``
   the mean of ``I_min`` over the image.  The specular term is removed with
   ``I_min``; the offset keeps the MSF chromaticity ``c = V / sum_c V`` away
   from the unstable region near zero (the point of the paper's error
   analysis of chromaticity: the error that noise causes in a ratio shrinks
   as its denominator grows).  ``c`` does not depend on the specular part
   (it still varies with the shading, through the offset).
2. Pixel classes: ``I_min - tau > tau`` (in every channel; ``I - V`` is the
   same in each) marks a pixel with both reflection components ("combined");
   ``I_min - tau < tau`` with ``I_max > dark_threshold`` marks a diffuse
   pixel; the rest (dark) is left unchanged.
3. Iterative clustering, diffuse pixels first: among the unprocessed diffuse
   pixels take the one with the largest ``I_max`` (the least affected by
   noise) as body colour ``B``; every unprocessed pixel (diffuse or combined)
   whose MSF chromaticity is within ``chroma_threshold`` of its own (L1
   distance) joins the cluster.  Each member is decomposed by least squares,
   ``I = alpha B + beta (1, 1, 1)``; where ``beta < 0`` the pixel is refit
   with ``beta = 0``.  The diffuse part is ``alpha B``.  Repeat until no
   unprocessed diffuse pixel is left.
4. Remaining combined pixels (their colour is seen in no diffuse pixel): take
   the first one, find the diffuse pixel whose MSF chromaticity is closest
   (distance ``d``), use that pixel's diffuse estimate as ``B`` and decompose
   every unprocessed pixel within ``d + 0.1 chroma_threshold`` of the
   diffuse pixel's chromaticity (no ``beta < 0`` refit).  Repeat.

Defaults and their sources: ``chroma_threshold = 0.03`` (L1 distance),
``dark_threshold = 20/255``, ``tau`` = mean of ``I_min`` and the
``d + 0.1 chroma_threshold`` rule of step 4 are those of the authors'
released MATLAB code (distributed with the paper and in the SIHR toolbox,
V. S. Ramos, Zenodo 3381328, whose results are the reference table of
polcam's SIHR benchmark).

Departures: pixels are visited in row-major order (the authors' MATLAB code
uses column-major order; this only breaks ties among equally bright diffuse
pixels and picks the first remaining combined pixel; measured: 34.13 / 37.51
/ 38.06 / 32.05 dB row-major against 34.17 / 37.52 / 38.03 / 32.12 dB
column-major on animals / cups / fruit / masks, reference 34.2 / 37.5 / 38.0
/ 32.1).  When the image has no diffuse pixel at all the combined pixels are
returned unchanged (the released code then uses an arbitrary pixel as body
colour).  Where the body colour is achromatic (channel spread below 1e-9 of
its sum) the two-colour fit is undetermined; nothing is removed there
(``beta = 0``; the released code's pseudo-inverse then returns the
minimum-norm split, which darkens a grey surface of level ``g`` to
``g^2 / (1 + g^2)`` of its value).  The
result is clipped to ``[0, I]``; the least-squares diffuse part can exceed
the input in a channel when a member's hue differs slightly from the body
colour's, and this clip (polcam's contract, applied by the dispatcher in any
case) raises the PSNR on the Shen & Zheng images from 34.1 / 37.5 / 38.1 /
32.1 dB to 36.0 / 38.2 / 38.0 / 32.7 dB.

``info`` holds ``iterations`` (clusters formed), ``unprocessed`` (combined
pixels left unchanged) and ``converged`` (True when every pixel of the two
classes was processed).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam.errors import MethodError
from polcam.separation._common import (
    as_rgb_image,
    channel_max,
    channel_min,
    finish_diffuse,
    is_finite_number,
)
from polcam.separation._registry import register

REFERENCE = (
    "H.-L. Shen, H.-G. Zhang, S.-J. Shao and J. H. Xin, Chromaticity-based separation of "
    "reflection components in a single image, Pattern Recognition 41(8), pp. 2461-2469, 2008"
)

__all__ = ["REFERENCE", "separate_shen08", "modified_specular_free"]

_WHITE = np.ones(3)
# Relative channel spread below which a body colour counts as achromatic.
_ACHROMATIC = 1e-9
#: Step 4's cluster reaches this share of ``chroma_threshold`` beyond the nearest diffuse colour's
#: distance ``d`` (the authors' released code).
_MARGIN = 0.1


def modified_specular_free(image: np.ndarray, offset: float | None = None) -> np.ndarray:
    """Shen et al.'s modified specular-free image ``I - I_min + tau``.

    Parameters
    ----------
    image
        (..., 3) float in [0, 1].
    offset
        ``tau``; None: the mean of ``I_min`` over the image.

    Returns
    -------
    numpy.ndarray
        (..., 3) float64, each channel >= ``tau``.
    """
    image = np.asarray(image, dtype=np.float64)
    i_min = channel_min(image)
    tau = float(i_min.mean()) if offset is None else float(offset)
    return image - i_min[..., None] + tau


def _fit(pixels: np.ndarray, body: np.ndarray, *, refit_negative: bool) -> np.ndarray:
    """Least-squares ``alpha`` of ``pixels ~ alpha body + beta white``.

    Parameters
    ----------
    pixels
        (n, 3) float64.
    body
        (3,) body colour.
    refit_negative
        Where ``beta < 0``, refit with ``beta = 0``.

    Returns
    -------
    numpy.ndarray
        (n,) ``alpha``.
    """
    norm2 = float(body @ body)
    if norm2 <= 0.0:
        return np.zeros(pixels.shape[0])
    spread = float(body.max() - body.min())
    if spread <= _ACHROMATIC * float(body.sum()):
        # Body colour collinear with the illuminant: the split is undetermined;
        # remove nothing (beta = 0).
        return pixels @ body / norm2
    basis = np.stack([body, _WHITE], axis=1)  # (3, 2)
    coef = pixels @ np.linalg.pinv(basis).T  # (n, 2)
    alpha = coef[:, 0]
    if refit_negative:
        neg = coef[:, 1] < 0.0
        if neg.any():
            alpha = alpha.copy()
            alpha[neg] = pixels[neg] @ body / norm2
    return alpha


@register("shen08", kind="single", reference=REFERENCE)
def separate_shen08(
    image: np.ndarray,
    *,
    chroma_threshold: float = 0.03,
    dark_threshold: float = 20.0 / 255.0,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer by Shen et al.'s MSF-chromaticity clustering.

    Parameters
    ----------
    image
        (H, W, 3) float64 RGB in [0, 1], white-balanced (specular colour
        white).
    chroma_threshold
        L1 distance of MSF chromaticities within which pixels join a
        cluster, in (0, 2].
    dark_threshold
        Pixels whose largest channel is at most this are not diffuse
        candidates (they are left unchanged unless classed combined).

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) float64 with ``0 <= diffuse <= image``.
    info : dict
        ``iterations``, ``unprocessed``, ``converged``.

    Raises
    ------
    MethodError
        Bad image or option values.
    """
    img = as_rgb_image(image, method="shen08")
    if not (is_finite_number(chroma_threshold) and 0.0 < chroma_threshold <= 2.0):
        raise MethodError(
            f"method 'shen08': chroma_threshold={chroma_threshold!r}: expected a number in (0, 2]"
        )
    if not (is_finite_number(dark_threshold) and 0.0 <= dark_threshold <= 1.0):
        raise MethodError(
            f"method 'shen08': dark_threshold={dark_threshold!r}: expected a number in [0, 1]"
        )
    h, w, _ = img.shape
    flat = img.reshape(h * w, 3)
    chroma, combined, diffuse_px = _classes(flat, dark_threshold)
    out = flat.copy()
    pending = np.flatnonzero(combined | diffuse_px)  # unprocessed, row-major order
    pending, clusters = _diffuse_clusters(flat, out, chroma, diffuse_px, pending, chroma_threshold)
    pending, more = _combined_clusters(flat, out, chroma, np.flatnonzero(diffuse_px), pending, chroma_threshold)
    info = {
        "iterations": clusters + more,
        "unprocessed": int(pending.size),
        "converged": pending.size == 0,
    }
    return finish_diffuse(out.reshape(h, w, 3), img), info


def _classes(flat: np.ndarray, dark_threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 1-2: MSF chromaticity (n, 3), and the combined and diffuse pixels (n,) bool."""
    n = flat.shape[0]
    i_min = channel_min(flat)
    i_max = channel_max(flat)
    tau = float(i_min.mean())
    msf = flat - i_min[:, None] + tau
    total = msf.sum(axis=1)
    chroma = np.full((n, 3), 1.0 / 3.0)
    np.divide(msf, total[:, None], out=chroma, where=total[:, None] > 0.0)
    combined = (i_min - tau) > tau
    diffuse_px = ((i_min - tau) < tau) & (i_max > dark_threshold)
    return chroma, combined, diffuse_px


def _diffuse_clusters(flat: np.ndarray, out: np.ndarray, chroma: np.ndarray, diffuse_px: np.ndarray,
                      pending: np.ndarray, chroma_threshold: float) -> tuple[np.ndarray, int]:
    """Step 3: clusters seeded by the brightest unprocessed diffuse pixel; ``out`` updated in place.

    Returns the pixels still unprocessed and the number of clusters.
    """
    i_max = channel_max(flat)
    clusters = 0
    while pending.size:
        cand = pending[diffuse_px[pending]]
        if cand.size == 0:
            break
        seed = cand[np.argmax(i_max[cand])]
        body = out[seed].copy()
        dist = np.abs(chroma[pending] - chroma[seed]).sum(axis=1)
        members = pending[dist < chroma_threshold]
        alpha = _fit(flat[members], body, refit_negative=True)
        out[members] = alpha[:, None] * body
        clusters += 1
        keep = np.ones(pending.size, dtype=bool)
        keep[dist < chroma_threshold] = False
        pending = pending[keep]
    return pending, clusters


def _combined_clusters(flat: np.ndarray, out: np.ndarray, chroma: np.ndarray, diffuse_idx: np.ndarray,
                       pending: np.ndarray, chroma_threshold: float) -> tuple[np.ndarray, int]:
    """Step 4: combined pixels whose colour no diffuse pixel shows, each cluster around the nearest diffuse colour.

    A cluster takes every unprocessed pixel within ``d + _MARGIN chroma_threshold`` of that
    diffuse pixel's chromaticity.  Returns the pixels still unprocessed (all of them when no pixel
    is diffuse) and the number of clusters.
    """
    clusters = 0
    if not diffuse_idx.size:
        return pending, clusters
    while pending.size:
        first = pending[0]
        d = np.abs(chroma[diffuse_idx] - chroma[first]).sum(axis=1)
        k = int(np.argmin(d))
        ref = diffuse_idx[k]
        body = out[ref].copy()
        dist = np.abs(chroma[pending] - chroma[ref]).sum(axis=1)
        sel = dist < d[k] + _MARGIN * chroma_threshold
        members = pending[sel]
        alpha = _fit(flat[members], body, refit_negative=False)
        out[members] = alpha[:, None] * body
        clusters += 1
        pending = pending[~sel]
    return pending, clusters
