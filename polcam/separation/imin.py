"""``imin``: the polarization minimum as the diffuse layer.

A polarizer at angle t passes ``Ic + Isv cos(2t - 2 phi)`` (polcam.polarimetry); the
light that no polarizer orientation removes, ``Imin = Ic - Isv``, is taken as
the diffuse layer, per channel.  This is the classic polarization-difference
separation (e.g. Wolff & Boult 1991, Nayar, Fang & Boult 1997) under the
assumption that diffuse reflection is unpolarized and specular reflection
fully polarized; partially polarized specular light leaves ``Ic - Isv`` of it
in the diffuse layer.

Scale: the diffuse layer is on the scale of one polarization image (the mean
over the four angles is ``Ic``), so ``specular = Ic - Imin = Isv``.  polanalyser
defines diffuse as Imin and specular as ``Imax - Imin = 2 Isv``: a factor 2 on
the specular layer against polcam's contract.
"""

from __future__ import annotations

import numpy as np

from polcam.polarimetry import imin as _imin
from polcam.separation._registry import register

REFERENCE = "L. B. Wolff and T. E. Boult, Constraining object features using a polarization reflectance model, IEEE TPAMI 13(7), 1991"


@register("imin", kind="stack", mono=True, reference=REFERENCE)
def separate_imin(stack: np.ndarray) -> np.ndarray:
    """Diffuse layer ``Ic - Isv``.

    Parameters
    ----------
    stack
        (4, H, W) or (4, H, W, 3) float in [0, 1], angles 0, 45, 90, 135.

    Returns
    -------
    numpy.ndarray
        (H, W) or (H, W, 3), in [0, mean over angles].
    """
    return np.maximum(_imin(stack), 0.0)
