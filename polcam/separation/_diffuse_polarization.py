"""Which part of the polarized light is the diffuse light's own: its AoLP against the image's edges,
its colour against the illuminant's.

Used by ``polarized-residual`` (docs/methods/polarized-residual.md, step 3); the two-colour fit
(polarized light as the illuminant's colour plus the body's) by its step 4 and its optional steps.
"""

from __future__ import annotations

from typing import Any

from polcam import _imageops
from polcam._xp import namespace
from polcam.separation._common import sum3

__all__ = ["MIN_SINE", "body_dominates", "diffuse_like_share", "edge_axis", "radial_share", "specular_part",
           "two_colour_fit"]

#: The body colour ``e`` is told apart from ``G`` (the two-colour fit is well conditioned) where the sine
#: of the angle between them exceeds this.
MIN_SINE = 0.2


def radial_share(q: Any, u: Any, axis: tuple[Any, Any, Any]) -> Any:
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
    structure tensor ``J`` of the intensity (:func:`edge_axis`: Sobel gradients, products
    Gaussian-smoothed): 1 on a straight edge, near 0 where the gradient's direction is noise, so
    that flat regions keep no share they cannot justify.  AoLP is counter-clockwise from the image
    x axis on the displayed image (y up), while the Sobel y gradient runs down the rows: the
    gradient's doubled angle is ``(gx^2 - gy^2, -2 gx gy)``.

    Parameters
    ----------
    q, u
        (H, W, C) float32 Stokes components ``(I0 - I90) / 2``, ``(I45 - I135) / 2`` (numpy or torch).
    axis
        ``edge_axis(lum, smooth)``: the intensity gradient's axis and its coherence.

    Returns
    -------
    (H, W, C) float32 in [0, 1], of the same kind as ``q``.
    """
    xp = namespace(q)
    c2, s2, coh = axis
    par = q * c2[..., None] + u * s2[..., None]
    amp = xp.hypot(q, u)
    share = xp.clip(par / xp.maximum(amp, 1e-12), 0.0, 1.0) * xp.clip(coh, 0.0, 1.0)[..., None]
    return xp.astype(share, xp.float32)


def diffuse_like_share(q: Any, u: Any, axis: tuple[Any, Any, Any]) -> float:
    """Share of the image's edge-coherent polarization that lies along the edge normals: the diffuse-like part.

    Diffuse polarization runs along the normal's azimuth (the gradient's axis at a contour),
    specular polarization across it (:func:`radial_share`).  Over the image, the polarized
    amplitude projected on each pixel's gradient axis, weighted by the axis' coherence,

        P = coh (q cos 2 psi + u sin 2 psi),   w = sum max(P, 0) / (sum max(P, 0) + sum max(-P, 0))

    weighs the evidence for the two: ``w`` near 1 where the polarization follows the edges
    (polarized diffuse light at contours), near 0 where it crosses them (highlights), 0.5 with no
    preference.  ``polarized-residual`` gives the diffuse polarization back in that proportion
    (docs/methods/polarized-residual.md, "Diffuse-like share").  No constant is set: the two
    sides are weighed as measured.

    Parameters
    ----------
    q, u
        (H, W) float32 Stokes components of the polarized light (for colour: each channel over the
        illuminant, summed), smoothed over the coherent kernel (numpy or torch).
    axis
        ``edge_axis(lum, smooth)``, as for :func:`radial_share`.

    Returns
    -------
    float in [0, 1]; 1.0 when no polarization lies on a coherent edge axis.
    """
    xp = namespace(q)
    c2, s2, coh = axis
    par = (q * c2 + u * s2) * xp.clip(coh, 0.0, 1.0)
    along = float(xp.maximum(par, 0.0).sum())
    across = float(xp.maximum(-par, 0.0).sum())
    return along / (along + across) if along + across > 0 else 1.0


#: Coherence under which the structure tensor has no axis: float32 rounding of its components (about
#: 1e-7 of their size) leaves a coherence of that order where the tensor is isotropic.
_NO_AXIS = 1e-5


def edge_axis(lum: Any, smooth: int) -> tuple[Any, Any, Any]:
    """The gradient's doubled-angle axis ``(cos 2 psi, sin 2 psi)`` and its coherence, each (H, W).

    The structure tensor of ``lum`` (Sobel gradients, products Gaussian-smoothed over ``smooth``
    pixels); AoLP convention as in :func:`radial_share`.  Where the coherence is under
    :data:`_NO_AXIS` (the tensor isotropic to rounding error, as at the centre of a symmetric
    highlight) there is no axis: ``(0, 0)``, rather than a direction the rounding of each backend
    draws differently.
    """
    xp = namespace(lum)
    gx = _imageops.sobel(lum, 1, 0)
    gy = _imageops.sobel(lum, 0, 1)
    jxx = _imageops.gaussian(gx * gx, smooth)
    jyy = _imageops.gaussian(gy * gy, smooth)
    jxy = _imageops.gaussian(gx * gy, smooth)
    c = jxx - jyy
    s = -2.0 * jxy
    n = xp.hypot(c, s)
    coh = n / xp.maximum(jxx + jyy, 1e-20)
    safe = coh > _NO_AXIS
    c2 = xp.where(safe, c / xp.where(safe, n, 1.0), 0.0)
    s2 = xp.where(safe, s / xp.where(safe, n, 1.0), 0.0)
    return c2, s2, coh


def two_colour_fit(xg: Any, xe: Any, gg: Any, ge: Any, ee: Any, det: Any) -> tuple[Any, Any]:
    """Least squares ``x = alpha G + beta e`` per pixel, from the dot products alone: ``(alpha, beta)``.

    ``xg = x.G``, ``xe = x.e``, ``gg = G.G``, ``ge = G.e``, ``ee = e.e`` (scalars or (H, W) arrays)
    and ``det = gg ee - ge^2`` (nonzero where the result is used) solve the normal equations

        [gg  ge] [alpha]   [xg]
        [ge  ee] [beta ] = [xe].
    """
    return (ee * xg - ge * xe) / det, (gg * xe - ge * xg) / det


def body_dominates(alpha: Any, beta: Any, gg: float, ee: Any) -> Any:
    """Where the fit's body-coloured term carries more of ``x`` than its ``G``-coloured one: ``|beta| |e| > |alpha| |G|``.

    ``alpha``, ``beta`` from :func:`two_colour_fit`, ``gg = G.G`` and ``ee = e.e``; (H, W) bool.
    """
    xp = namespace(beta)
    return abs(beta) * xp.sqrt(ee) > abs(alpha) * gg ** 0.5


def specular_part(removed: Any, body: Any, gx: Any, a_g: Any, *, body_dominant: bool = False) -> Any:
    """The multiple of ``G`` in the removed polarized light once its body-coloured part is set apart, (H, W).

    Polarized light has two colours: a specular reflection's is the illuminant's ``G``, diffuse
    light's (Fresnel transmission, strongest near occluding contours) the body's own.  The removal
    ``R`` (H, W, 3, >= 0) is fitted per pixel as ``R = alpha G + beta M`` by least squares, ``M`` the
    layer it leaves (``body``, the body's colour with whatever unpolarized light is in it):

        [G.G  G.M] [alpha]   [G.R]
        [G.M  M.M] [beta ] = [M.R],

    and ``max(alpha, 0)`` is the specular part.  Where ``beta < 0`` no body-coloured part is seen
    (the fit trades one colour against the other) and the removal's projection on ``G``, ``a_g``,
    stands.  Where ``M``'s colour is within ``asin(MIN_SINE)`` of ``G``'s (an achromatic body
    under ``G``: ``det < MIN_SINE^2 |G|^2 |M|^2``) the two colours are not told apart and the
    result is unbounded (1e30: the caller's other reading decides).  The fit is on magnitudes, so
    it is exact where only one of the two is polarized at a pixel; where both are, their AoLPs are
    perpendicular and they partly cancel, and the caller's ``min`` with its own reading keeps the
    removal from exceeding what it was.  With ``body_dominant`` it also returns (H, W) bool: where
    the colours are told apart and the body-coloured term carries more of the removal than the
    ``G``-coloured one (``beta > 0`` and ``beta |M| > |alpha| |G|``).
    """
    xp = namespace(removed)
    m = xp.maximum(body, 0.0)
    gg = float((gx * gx).sum())
    gm, mm = sum3(m * gx), sum3(m * m)
    gr, mr = sum3(removed * gx), sum3(removed * m)
    det = gg * mm - gm * gm
    told = det > (MIN_SINE ** 2) * gg * mm
    alpha, beta = two_colour_fit(gr, mr, gg, gm, mm, xp.where(told, det, 1.0))
    spec = xp.where(told, xp.maximum(xp.where(beta < 0, a_g, alpha), 0.0), 1e30)
    if not body_dominant:
        return spec
    return spec, told & (beta > 0) & body_dominates(alpha, beta, gg, mm)
