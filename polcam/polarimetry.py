"""Linear Stokes parameters and the polarization sinusoid from four polarizer angles.

All functions take a polarization stack ``I`` of shape ``(4, ...)`` in the
angle order 0, 45, 90, 135 degrees (any trailing shape: (H, W), (H, W, 3), ...)
holding linear intensities, and return arrays of the trailing shape.

Conventions (docs/architecture.md):

* ``S0 = (I0 + I45 + I90 + I135) / 2``, ``S1 = I0 - I90``, ``S2 = I45 - I135``.
* An ideal polarizer at angle t transmits ``I(t) = Ic + Isv cos(2t - 2 phi)`` with
  ``Ic = S0 / 2``, ``Isv = sqrt(S1^2 + S2^2) / 2`` and ``phi`` the AoLP: the
  least-squares fit of the sinusoid to the four samples has this closed form.
* DoLP ``= sqrt(S1^2 + S2^2) / S0`` in [0, 1] (0 where ``S0 <= 0``).
* AoLP ``= atan2(S2, S1) / 2`` wrapped to [0, pi), in radians, measured from the
  image x axis in the direction of the 45-degree polarizer of the layout.
* ``Imin = Ic - Isv`` and ``Imax = Ic + Isv``: the least and most light any
  polarizer orientation passes.
* The fit residual ``(I0 + I90) - (I45 + I135)`` is zero for any ideal
  measurement; its magnitude flags misregistration, demosaicing artefacts,
  noise and miscalibration.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "Stokes",
    "Sinusoid",
    "stokes",
    "dolp",
    "aolp",
    "fit_sinusoid",
    "imin",
    "imax",
    "fit_residual",
    "synthesize",
]

_ANGLES_RAD = np.deg2rad(np.array([0.0, 45.0, 90.0, 135.0]))


class Stokes(NamedTuple):
    """Linear Stokes parameters, each of the stack's trailing shape."""

    s0: np.ndarray
    s1: np.ndarray
    s2: np.ndarray


class Sinusoid(NamedTuple):
    """Fit ``I(t) = ic + isv * cos(2 t - 2 phi)`` per pixel (and channel)."""

    ic: np.ndarray
    isv: np.ndarray
    phi: np.ndarray


def _check(stack: np.ndarray) -> np.ndarray:
    arr = np.asarray(stack)
    if arr.ndim < 1 or arr.shape[0] != 4:
        raise ValueError(
            f"polarization stack of shape {arr.shape}: expected 4 angle images "
            "(0, 45, 90, 135 degrees) along the first axis"
        )
    if not np.issubdtype(arr.dtype, np.floating):
        arr = arr.astype(np.float32)
    return arr


def stokes(stack: np.ndarray) -> Stokes:
    """Linear Stokes parameters of a polarization stack.

    Parameters
    ----------
    stack
        (4, ...) intensities at 0, 45, 90, 135 degrees.

    Returns
    -------
    Stokes
        ``s0`` in [0, 2 max(I)], ``s1`` and ``s2`` in [-max(I), max(I)].
    """
    i = _check(stack)
    s0 = (i[0] + i[1] + i[2] + i[3]) * i.dtype.type(0.5)
    return Stokes(s0, i[0] - i[2], i[1] - i[3])


def _parts(stack_or_stokes: np.ndarray | Stokes) -> Stokes:
    if isinstance(stack_or_stokes, Stokes):
        return stack_or_stokes
    return stokes(stack_or_stokes)


def dolp(stack_or_stokes: np.ndarray | Stokes) -> np.ndarray:
    """Degree of linear polarization in [0, 1] (0 where S0 <= 0).

    Accepts a (4, ...) stack or a :class:`Stokes` tuple.
    """
    s = _parts(stack_or_stokes)
    lin = np.hypot(s.s1, s.s2)
    s0 = np.asarray(s.s0)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(s0 > 0, lin / np.where(s0 > 0, s0, 1), 0)
    return np.clip(d, 0, 1).astype(lin.dtype, copy=False)


def aolp(stack_or_stokes: np.ndarray | Stokes) -> np.ndarray:
    """Angle of linear polarization in radians, in [0, pi).

    Accepts a (4, ...) stack or a :class:`Stokes` tuple.
    """
    s = _parts(stack_or_stokes)
    a = 0.5 * np.arctan2(s.s2, s.s1)
    a = np.mod(a, np.pi)
    # mod can round up to exactly pi for tiny negative inputs
    return np.where(a >= np.pi, 0, a).astype(np.asarray(s.s1).dtype, copy=False)


def fit_sinusoid(stack: np.ndarray) -> Sinusoid:
    """Least-squares fit of ``I(t) = Ic + Isv cos(2t - 2 phi)`` to the four angles.

    Returns
    -------
    Sinusoid
        ``ic`` = S0 / 2, ``isv`` = sqrt(S1^2 + S2^2) / 2 >= 0, ``phi`` = AoLP in [0, pi).
    """
    s = stokes(stack)
    half = s.s0.dtype.type(0.5)
    return Sinusoid(s.s0 * half, np.hypot(s.s1, s.s2) * half, aolp(s))


def imin(stack: np.ndarray) -> np.ndarray:
    """Polarization minimum ``Ic - Isv``: the light that no polarizer angle removes."""
    f = fit_sinusoid(stack)
    return f.ic - f.isv


def imax(stack: np.ndarray) -> np.ndarray:
    """Polarization maximum ``Ic + Isv``."""
    f = fit_sinusoid(stack)
    return f.ic + f.isv


def fit_residual(stack: np.ndarray) -> np.ndarray:
    """The quality map ``(I0 + I90) - (I45 + I135)`` (zero for ideal data)."""
    i = _check(stack)
    return (i[0] + i[2]) - (i[1] + i[3])


def synthesize(ic: np.ndarray, isv: np.ndarray, phi: np.ndarray,
               angles_deg: np.ndarray | tuple[float, ...] = (0, 45, 90, 135)) -> np.ndarray:
    """Intensities ``Ic + Isv cos(2t - 2 phi)`` at the given polarizer angles.

    Parameters
    ----------
    ic, isv, phi
        Arrays of one (broadcastable) shape; ``phi`` in radians.
    angles_deg
        Polarizer angles in degrees.

    Returns
    -------
    numpy.ndarray
        (len(angles_deg), ...) stack.
    """
    ic, isv, phi = np.broadcast_arrays(np.asarray(ic), np.asarray(isv), np.asarray(phi))
    t = np.deg2rad(np.asarray(angles_deg, dtype=np.float64)).reshape((-1,) + (1,) * ic.ndim)
    out = ic[None] + isv[None] * np.cos(2 * t - 2 * phi[None])
    dtype = np.result_type(ic.dtype, np.float32)
    return out.astype(dtype, copy=False)
