"""``lmmse-eari``: a per-pixel blend of ``lmmse`` and ``eari`` driven by their local disagreement.

The two methods fail in different places.  ``eari`` (residual interpolation with
an edge-aware guide, and a colour-ratio rule between cells) follows smooth
polarization and aliased fine detail such as a zone plate, but its colour-ratio
rule is wrong for about one cell on each side of a colour edge and wherever the
colours of a pixel do not share one polarization.  ``lmmse`` (a learned linear
filter bank and a polarization-ratio stage) handles colour edges and
colour-dependent polarization, but a fixed linear filter cannot follow aliased
detail and its ratio stage bends smoothly varying polarization.  Where one of
them fails, the two disagree by much more than where both are right, and the
failures of ``eari`` that matter are the large ones (colour edges).  So:

* ``d`` = the sum over angles and colours of ``(lmmse - eari)^2``, and ``m`` =
  ``lmmse``'s S0 averaged over the colours, both blurred by a Gaussian of
  ``sigma`` pixels;
* the weight of ``lmmse`` is ``w = clip(d / (tau (m^2 + f)), 0, 1)`` (``f`` =
  ``(floor x the mosaic's mean)^2`` keeps dark areas from dividing by 0);
* the result is ``eari + w (lmmse - eari)``.

``d / m^2`` is a local relative disagreement, computed from the raw mosaic alone
(both estimates are functions of it).  Both methods keep the measured samples
and recover uniform and affine scenes exactly, so the blend does too.  ``tau``
and ``sigma`` were chosen on polcam's validation set
(:mod:`polcam.bench.demosaic_validation`); docs/methods/demosaic-lmmse-eari.md gives the table.
"""

from __future__ import annotations

import cv2
import numpy as np

from polcam.demosaicing._lattice import bilinear_cells, run_jobs
from polcam.demosaicing._registry import register
from polcam.demosaicing.eari import eari
from polcam.demosaicing.lmmse import lmmse
from polcam.mosaic import Layout

__all__ = ["BLEND_PARAMS", "REFERENCE", "blend_weight", "lmmse_eari", "run_blend"]

REFERENCE = ("a per-pixel blend of polcam's lmmse and eari, weighted by their local relative "
             "disagreement (docs/methods/demosaic-lmmse-eari.md)")

#: Parameters of the blend (docs/methods/demosaic-lmmse-eari.md says how they were chosen).
BLEND_PARAMS: dict[str, float] = {
    # lmmse takes over where the relative disagreement d / m^2 reaches tau
    "tau": 0.02,
    # Gaussian of the local averages, pixels
    "sigma": 4.0,
    # dark floor of m, relative to the mosaic's mean
    "floor": 0.03,
}


_ROWS = 128  # rows per strip of the thread pool


def blend_weight(a: np.ndarray, e: np.ndarray, *, mean: float, tau: float, sigma: float,
                 floor: float) -> np.ndarray:
    """The weight of ``a`` (lmmse) against ``e`` (eari), (H, W) float32 in [0, 1].

    Parameters
    ----------
    a, e
        (4, H, W, C) float32 stacks (C = 3 colour, 1 mono).
    mean
        The mosaic's mean (scale of the dark floor).
    tau, sigma, floor
        See :data:`BLEND_PARAMS`.
    """
    h, w = a.shape[1:3]
    d = np.empty((h, w), np.float32)
    m = np.empty((h, w), np.float32)
    scale = np.float32(0.5 / a.shape[3])

    ones = np.ones((1, a.shape[3]), np.float32)

    def job(y0: int, y1: int) -> None:
        dd, mm = d[y0:y1], m[y0:y1]
        dd[...] = 0
        mm[...] = 0
        for k in range(4):
            ak, ek = a[k, y0:y1], e[k, y0:y1]
            t = ak - ek
            t *= t
            # the sum over colours (OpenCV's channel transform, outside the GIL)
            dd += cv2.transform(t, ones).reshape(dd.shape) if t.shape[2] > 1 else t[..., 0]
            mm += cv2.transform(ak, ones).reshape(mm.shape) if ak.shape[2] > 1 else ak[..., 0]
        mm *= scale

    run_jobs([lambda y0=y0: job(y0, min(h, y0 + _ROWS)) for y0 in range(0, h, _ROWS)])
    d = cv2.GaussianBlur(d, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    m = cv2.GaussianBlur(m, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    f = np.float32((floor * max(mean, 1e-6)) ** 2)
    m *= m
    m += f
    m *= np.float32(tau)
    d /= m
    return np.clip(d, 0, 1, out=d)


def lmmse_eari(img: np.ndarray, lay: Layout) -> np.ndarray:
    """Blend of :func:`~polcam.demosaicing.lmmse.lmmse` and :func:`~polcam.demosaicing.eari.eari`
    on a float32 (H, W) mosaic, with :data:`BLEND_PARAMS`.

    Returns
    -------
    numpy.ndarray
        float32 (4, H, W) for a mono layout, (4, H, W, 3) for a colour one.
    """
    return run_blend(img, lay, params=BLEND_PARAMS)


def run_blend(img: np.ndarray, lay: Layout, *, params: dict[str, float]) -> np.ndarray:
    """:func:`lmmse_eari` with given blend parameters (the keys of :data:`BLEND_PARAMS`): what
    the selection of :mod:`polcam.bench.demosaic_validation` runs.

    Returns
    -------
    numpy.ndarray
        float32 (4, H, W) for a mono layout, (4, H, W, 3) for a colour one.
    """
    a = lmmse(img, lay)
    e = eari(img, lay)
    if not lay.is_color:
        a, e = a[..., None], e[..., None]
    w = blend_weight(a, e, mean=float(np.mean(img, dtype=np.float64)), tau=float(params["tau"]),
                     sigma=float(params["sigma"]), floor=float(params["floor"]))
    h = img.shape[0]

    def job(y0: int, y1: int) -> None:
        da = a[:, y0:y1]
        da -= e[:, y0:y1]
        da *= w[None, y0:y1, :, None]
        e[:, y0:y1] += da

    run_jobs([lambda y0=y0: job(y0, min(h, y0 + _ROWS)) for y0 in range(0, h, _ROWS)])
    return e if lay.is_color else np.ascontiguousarray(e[..., 0])


register("lmmse-eari", cell=bilinear_cells, reference=REFERENCE)(lmmse_eari)
