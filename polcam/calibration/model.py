"""The per-pixel polarizer model and its inverse (analysis and correction matrices).

Forward model of pixel k (after dark subtraction), for incident linear Stokes
parameters (S0, S1, S2)::

    I_k = g_k / 2 * (S0 + D_k * (S1 cos 2 theta_k + S2 sin 2 theta_k)) + d_k

with gain ``g`` (relative transmission times photo-response), diattenuation
``D = (Tmax - Tmin) / (Tmax + Tmin) = (ER - 1) / (ER + 1)`` (``ER`` the extinction
ratio), orientation ``theta`` of the pixel's polarizer (radians here, degrees in
the maps; measured from the image x axis towards the layout's 45-degree
polarizer, the convention of :mod:`polcam.polarimetry`) and dark level ``d``.  An
ideal pixel (g = 1, D = 1, theta nominal) reads
``(S0 + S1 cos 2t + S2 sin 2t) / 2``, so four ideal pixels at 0, 45, 90 and 135
degrees give back ``S0 = (I0 + I45 + I90 + I135) / 2``, ``S1 = I0 - I90`` and
``S2 = I45 - I135`` (:func:`polcam.polarimetry.stokes`).

Each pixel contributes one *measurement row* ``w_k = g_k / 2 [1, D_k cos 2theta_k,
D_k sin 2theta_k]``; four pixels (a 2x2 super-pixel, or the four angle values of
one demosaiced pixel) form a 4x3 matrix ``W`` and the least-squares Stokes
estimate is ``S = A x`` with the *analysis matrix* ``A = (W^T W)^-1 W^T``
(Powell & Gruev 2013, docs/guide/calibration.md).

The *correction matrix* ``M`` (4x4) maps the four measured values to the values
four ideal polarizers would have given for the estimated Stokes vector, plus
the part of the measurement the model does not explain, kept on the
``(I0 + I90) - (I45 + I135)`` axis so that :func:`polcam.polarimetry.fit_residual`
still flags noise and misregistration::

    M = V A + 1/4 s s^T diag(1/g) (I - W A)

``V`` holds the ideal rows ``[1, cos 2t_k, sin 2t_k] / 2`` at the nominal
angles ``t_k`` and ``s_k = +1`` for 0/90 degrees, ``-1`` for 45/135.  For an
ideal sensor ``M`` is the identity; for any sensor ``stokes(M x) = A x``.
"""

from __future__ import annotations

import numpy as np

from polcam.mosaic import ANGLES, Layout

__all__ = [
    "analysis_matrices",
    "cell_view",
    "correction_matrices",
    "extinction_to_diattenuation",
    "diattenuation_to_extinction",
    "forward",
    "from_cells",
    "ideal_rows",
    "measurement_rows",
    "model_from_coefficients",
    "nominal_orientation",
    "residual_signs",
]


def extinction_to_diattenuation(er: np.ndarray | float) -> np.ndarray:
    """Diattenuation ``D = (ER - 1) / (ER + 1)`` of an extinction ratio ``ER >= 1``."""
    er = np.asarray(er, dtype=np.float64)
    return (er - 1.0) / (er + 1.0)


def diattenuation_to_extinction(d: np.ndarray | float) -> np.ndarray:
    """Extinction ratio ``ER = (1 + D) / (1 - D)`` (``inf`` for D = 1) of a diattenuation in [0, 1]."""
    d = np.asarray(d, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(d < 1.0, (1.0 + d) / np.where(d < 1.0, 1.0 - d, 1.0), np.inf)


def nominal_orientation(layout: Layout, height: int, width: int) -> np.ndarray:
    """Nominal polarizer angle of every pixel of a mosaic.

    Returns
    -------
    numpy.ndarray
        (height, width) float64, degrees, values in {0, 45, 90, 135}.
    """
    return np.asarray(ANGLES, dtype=np.float64)[layout.angle_index(height, width)]


def residual_signs(angles_deg: np.ndarray) -> np.ndarray:
    """``+1`` for nominal angles 0 and 90, ``-1`` for 45 and 135 (same shape, float64)."""
    a = np.mod(np.asarray(angles_deg, dtype=np.float64), 180.0)
    return np.where(np.isclose(a % 90.0, 0.0), 1.0, -1.0)


def measurement_rows(gain: np.ndarray, diattenuation: np.ndarray, orientation_deg: np.ndarray) -> np.ndarray:
    """Rows ``g/2 [1, D cos 2theta, D sin 2theta]`` of the forward model.

    Parameters
    ----------
    gain, diattenuation, orientation_deg
        Broadcastable arrays: gain (> 0, about 1), diattenuation in [0, 1],
        orientation in degrees.

    Returns
    -------
    numpy.ndarray
        float64 array of the broadcast shape plus a trailing axis of 3.
    """
    g, d, t = np.broadcast_arrays(np.asarray(gain, dtype=np.float64),
                                  np.asarray(diattenuation, dtype=np.float64),
                                  np.deg2rad(np.asarray(orientation_deg, dtype=np.float64)))
    half = 0.5 * g
    return np.stack([half, half * d * np.cos(2 * t), half * d * np.sin(2 * t)], axis=-1)


def ideal_rows(angles_deg: np.ndarray) -> np.ndarray:
    """Rows ``[1, cos 2t, sin 2t] / 2`` of ideal polarizers at ``angles_deg`` (shape + (3,))."""
    return measurement_rows(np.ones_like(np.asarray(angles_deg, dtype=np.float64)), 1.0, angles_deg)


def forward(stokes: tuple[np.ndarray, np.ndarray, np.ndarray] | np.ndarray, gain: np.ndarray,
            diattenuation: np.ndarray, orientation_deg: np.ndarray, dark: np.ndarray | float = 0.0) -> np.ndarray:
    """The forward model ``I = g/2 (S0 + D (S1 cos 2theta + S2 sin 2theta)) + d``.

    Parameters
    ----------
    stokes
        (S0, S1, S2), each broadcastable to the maps' shape.
    gain, diattenuation, orientation_deg, dark
        Per-pixel model (broadcastable); orientation in degrees.

    Returns
    -------
    numpy.ndarray
        float64 intensities of the broadcast shape.
    """
    s0, s1, s2 = (np.asarray(s, dtype=np.float64) for s in stokes)
    rows = measurement_rows(gain, diattenuation, orientation_deg)
    return rows[..., 0] * s0 + rows[..., 1] * s1 + rows[..., 2] * s2 + np.asarray(dark, dtype=np.float64)


def model_from_coefficients(c0: np.ndarray, c1: np.ndarray, c2: np.ndarray,
                            *, source_dolp: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel model from the fit ``I(a) = c0 + c1 cos 2a + c2 sin 2a`` under a rotating polarizer.

    For light of intensity ``S0`` and degree of polarization ``p`` (the
    reference polarizer's own) at angle ``a``, the model gives
    ``c0 = g S0 / 2``, ``c1 = c0 p D cos 2theta``, ``c2 = c0 p D sin 2theta``.

    Parameters
    ----------
    c0, c1, c2
        Fitted coefficients (any shape, same units); ``c0 > 0``.
    source_dolp
        Degree of polarization ``p`` of the calibration light, in (0, 1].

    Returns
    -------
    scale, diattenuation, orientation_deg
        ``2 c0`` (the gain times S0: normalise it to get relative gains),
        ``D = hypot(c1, c2) / (p c0)`` (0 where ``c0 <= 0``) and
        ``theta = atan2(c2, c1) / 2`` in degrees, in [0, 180).
    """
    c0 = np.asarray(c0, dtype=np.float64)
    amp = np.hypot(c1, c2)
    with np.errstate(divide="ignore", invalid="ignore"):
        dia = np.where(c0 > 0, amp / (source_dolp * np.where(c0 > 0, c0, 1.0)), 0.0)
    theta = np.mod(np.rad2deg(0.5 * np.arctan2(c2, c1)), 180.0)
    theta = np.where(theta >= 180.0, 0.0, theta)
    return 2.0 * c0, dia, theta


def cell_view(mosaic: np.ndarray) -> np.ndarray:
    """The 2x2 cells of a mosaic: (H, W, ...) -> (H/2, W/2, 4, ...), cell order r0c0, r0c1, r1c0, r1c1.

    A copy for non-contiguous input; H and W must be even.
    """
    a = np.asarray(mosaic)
    h, w = a.shape[:2]
    rest = a.shape[2:]
    out = a.reshape(h // 2, 2, w // 2, 2, *rest).swapaxes(1, 2)
    return out.reshape(h // 2, w // 2, 4, *rest)


def from_cells(cells: np.ndarray) -> np.ndarray:
    """Inverse of :func:`cell_view`: (Hc, Wc, 4, ...) -> (2 Hc, 2 Wc, ...)."""
    c = np.asarray(cells)
    hc, wc = c.shape[:2]
    rest = c.shape[3:]
    out = c.reshape(hc, wc, 2, 2, *rest).swapaxes(1, 2)
    return out.reshape(2 * hc, 2 * wc, *rest)


def _inv3_sym(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of symmetric 3x3 matrices (..., 3, 3), closed form."""
    a, b, c = n[..., 0, 0], n[..., 0, 1], n[..., 0, 2]
    d, e, f = n[..., 1, 1], n[..., 1, 2], n[..., 2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    det = a * c00 + b * c01 + c * c02
    safe = np.where(np.abs(det) > 0, det, 1.0)
    inv = np.stack([np.stack([c00, c01, c02], -1),
                    np.stack([c01, c11, c12], -1),
                    np.stack([c02, c12, c22], -1)], -2) / safe[..., None, None]
    return inv, det


def analysis_matrices(rows: np.ndarray, *, fallback: np.ndarray | None = None) -> np.ndarray:
    """Least-squares analysis matrices ``A = (W^T W)^-1 W^T`` of stacked 4x3 measurement matrices.

    Parameters
    ----------
    rows
        (..., 4, 3) measurement matrices (:func:`measurement_rows` of four pixels).
    fallback
        (..., 4, 3) or (4, 3) matrices used instead where ``W`` is (nearly)
        rank deficient (e.g. a pixel of zero gain); without it such input
        raises ``ValueError``.

    Returns
    -------
    numpy.ndarray
        (..., 3, 4) float64 analysis matrices: ``S = A @ x``.
    """
    w = np.asarray(rows, dtype=np.float64)
    wt = np.swapaxes(w, -1, -2)
    inv, det = _inv3_sym(wt @ w)
    # W^T W of four unit-gain rows has determinant of order 1/64 (ideal: 1/128);
    # anything 1e-9 times smaller is treated as degenerate
    bad = ~(np.abs(det) > 1e-12)
    a = inv @ wt
    if np.any(bad):
        if fallback is None:
            raise ValueError("degenerate measurement matrix and no fallback given")
        fb = np.broadcast_to(np.asarray(fallback, dtype=np.float64), w.shape)[bad]
        fbt = np.swapaxes(fb, -1, -2)
        inv_fb, _ = _inv3_sym(fbt @ fb)
        a[bad] = inv_fb @ fbt
    return a


def correction_matrices(rows: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """4x4 matrices mapping measured values to ideal-polarizer values (module docstring).

    Parameters
    ----------
    rows
        (..., 4, 3) measurement matrices of the four pixels (or four angle
        values) of each location.
    angles_deg
        (4,) or (..., 4) nominal angles of the four entries, degrees
        (broadcast against ``rows``).

    Returns
    -------
    numpy.ndarray
        (..., 4, 4) float64 ``M``; ``M @ x`` are the ideal values.
    """
    w = np.asarray(rows, dtype=np.float64)
    ang = np.asarray(angles_deg, dtype=np.float64)
    v = ideal_rows(ang)                                    # (4, 3) or (..., 4, 3)
    s = residual_signs(ang)                                # (4,) or (..., 4)
    a = analysis_matrices(w, fallback=v)                   # (..., 3, 4)
    gain = 2.0 * w[..., 0]
    u = s * np.where(gain > 0, 1.0 / np.where(gain > 0, gain, 1.0), 0.0)   # s_k / g_k
    uw = np.einsum("...k,...ki->...i", u, w)               # u^T W
    res = u - np.einsum("...i,...ij->...j", uw, a)         # s^T diag(1/g) (I - W A)
    return v @ a + 0.25 * s[..., :, None] * res[..., None, :]
