"""Fresnel's equations for a dielectric seen from air, and the degrees of polarization they give.

The specular light's degree of linear polarization ``(Rs - Rp) / (Rs + Rp)`` and the diffuse
(refracted) light's ``(Rs - Rp) / (2 - Rs - Rp)`` (Atkinson & Hancock, IEEE TIP 15(6) 2006), used by
the renderer (:mod:`polcam.synth.render`) and the synthetic families.
"""

from __future__ import annotations

import numpy as np

__all__ = ["diffuse_dolp", "fresnel_reflectance", "specular_dolp"]


def fresnel_reflectance(theta: np.ndarray, n: float) -> tuple[np.ndarray, np.ndarray]:
    """Fresnel power reflectances of a dielectric seen from air.

    Parameters
    ----------
    theta
        Angle of incidence in radians, in [0, pi/2] (any shape).
    n
        Refractive index, > 1.

    Returns
    -------
    rs, rp
        Reflectances for light polarized perpendicular (s) and parallel (p) to
        the plane of incidence, each in [0, 1], of ``theta``'s shape:
        ``rs = ((cos ti - n cos tt) / (cos ti + n cos tt))^2``,
        ``rp = ((cos tt - n cos ti) / (cos tt + n cos ti))^2``,
        with ``sin tt = sin ti / n`` (Snell).
    """
    th = np.clip(np.asarray(theta, dtype=np.float64), 0.0, np.pi / 2)
    ci = np.cos(th)
    n_ct = np.sqrt(np.maximum(n * n - np.sin(th) ** 2, 0.0))  # n cos(theta_t)
    ct = n_ct / n
    rs = ((ci - n_ct) / (ci + n_ct)) ** 2
    rp = ((ct - n * ci) / (ct + n * ci)) ** 2
    return rs, rp


def specular_dolp(theta: np.ndarray, n: float) -> np.ndarray:
    """Degree of linear polarization of specular reflection, ``(Rs - Rp) / (Rs + Rp)``.

    Parameters
    ----------
    theta
        Angle of incidence (radians) in [0, pi/2].
    n
        Refractive index, > 1.

    Returns
    -------
    numpy.ndarray
        float64 in [0, 1]; 1 at Brewster's angle ``atan(n)``.
    """
    rs, rp = fresnel_reflectance(theta, n)
    total = rs + rp
    return np.divide(rs - rp, total, out=np.zeros_like(total), where=total > 0)


def diffuse_dolp(theta: np.ndarray, n: float) -> np.ndarray:
    """Degree of linear polarization of diffuse (refracted) emission, ``(Rs - Rp) / (2 - Rs - Rp)``.

    Parameters
    ----------
    theta
        Emission angle (radians, between normal and viewing direction) in [0, pi/2].
    n
        Refractive index, > 1.

    Returns
    -------
    numpy.ndarray
        float64 in [0, 1); 0 at normal emission, rising towards grazing angles.
    """
    rs, rp = fresnel_reflectance(theta, n)
    return (rs - rp) / (2.0 - rs - rp)
