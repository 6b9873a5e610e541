"""Which part of the polarized light is the diffuse light's own: its AoLP against the image's edges.

Used by ``polarized-residual`` (docs/methods/polarized-residual.md, step 3).
"""

from __future__ import annotations

from typing import Any

from polcam import _imageops
from polcam._xp import namespace

__all__ = ["radial_share"]


def radial_share(q: Any, u: Any, lum: Any, *, smooth: int) -> Any:
    """Share of each channel's polarized amplitude that lies along the local edge normal, (H, W, C) in [0, 1].

    Diffuse light leaving a dielectric is polarized along the azimuth of the surface normal (the
    transmission Fresnel coefficients, Atkinson & Hancock, IEEE TIP 15(6) 2006), strongly only at
    grazing emission: near occluding contours, where the normal's azimuth is the contour's normal,
    which is the axis of the image's intensity gradient there.  Specular light from the same
    surface is polarized perpendicular to its plane of incidence, which contains the normal when
    the highlight is seen (half-vector along the normal): its AoLP is perpendicular to the normal's
    azimuth (Kajiyama et al., WACV 2023, use the same 90-degree relation).  So the polarized
    amplitude is projected on the gradient's axis ``psi``:

        A_par = q cos 2 psi + u sin 2 psi,   share = coh * clip(A_par / hypot(q, u), 0, 1)

    where ``psi`` and the coherence ``coh = |J_xx - J_yy, 2 J_xy| / (J_xx + J_yy)`` come from the
    structure tensor ``J`` of ``lum`` (Sobel gradients, products Gaussian-smoothed over
    ``smooth`` pixels): 1 on a straight edge, near 0 where the gradient's direction is noise, so
    that flat regions keep no share they cannot justify.  AoLP is counter-clockwise from the image
    x axis on the displayed image (y up), while the Sobel y gradient runs down the rows: the
    gradient's doubled angle is ``(gx^2 - gy^2, -2 gx gy)``.

    Parameters
    ----------
    q, u
        (H, W, C) float32 Stokes components ``(I0 - I90) / 2``, ``(I45 - I135) / 2`` (numpy or torch).
    lum
        (H, W) float32 intensity.
    smooth
        Odd side of the Gaussian window of the structure tensor.

    Returns
    -------
    (H, W, C) float32 in [0, 1], of the same kind as ``q``.
    """
    xp = namespace(q)
    gx = _imageops.sobel(lum, 1, 0)
    gy = _imageops.sobel(lum, 0, 1)
    jxx = _imageops.gaussian(gx * gx, smooth)
    jyy = _imageops.gaussian(gy * gy, smooth)
    jxy = _imageops.gaussian(gx * gy, smooth)
    c = jxx - jyy
    s = -2.0 * jxy
    n = xp.hypot(c, s)
    coh = n / xp.maximum(jxx + jyy, 1e-20)
    safe = n > 0
    c2 = xp.where(safe, c / xp.where(safe, n, 1.0), 0.0)[..., None]
    s2 = xp.where(safe, s / xp.where(safe, n, 1.0), 0.0)[..., None]
    par = q * c2 + u * s2
    amp = xp.hypot(q, u)
    share = xp.clip(par / xp.maximum(amp, 1e-12), 0.0, 1.0) * xp.clip(coh, 0.0, 1.0)[..., None]
    return xp.astype(share, xp.float32)
