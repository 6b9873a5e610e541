"""polarized-residual's step 4: what is removed is a multiple of the illuminant's colour ``G``.

docs/methods/polarized-residual.md, "Colour stacks, as implemented", step 4 (with its blind
channels: a colour channel whose mean over the four polarizer angles is at the white level).  One
implementation for numpy and PyTorch (:mod:`polcam._xp`).
"""

from __future__ import annotations

from typing import Any

from polcam._xp import namespace
from polcam.separation._common import min3, sum3
from polcam.separation._diffuse_polarization import specular_part

__all__ = ["LIGHT_GUARD", "PER_CHANNEL_SHARE", "one_specular_colour"]

#: Least light (channel sum) by which a removed share is divided: far below one 8-bit code value, so it
#: only keeps black pixels from dividing by zero.
LIGHT_GUARD = 1e-6
#: Step 4: the share of a pixel's light that polarization removes over which the per-channel removal
#: takes the place of the one-colour one (a ramp from the first to the second).  A sweep on 400 scenes of
#: the validation split (0.2-0.5: 27.85 dB, best or within 0.3 dB 82 %; 0.3-0.6: 27.91, 82 %; 0.4-0.8:
#: 27.97, 81 %; 0.5-1.0: 27.97, 80 %; none: 27.92, 78 %); the share itself as the weight (27.97, 82 %)
#: coloured the real stacks' specular layers (spread 0.049 against 0.025).
PER_CHANNEL_SHARE = (0.4, 0.8)


def one_specular_colour(diffuse: Any, ic: Any, gx: Any, weight: float, coherent: Any,
                        blind: Any = None) -> Any:
    """Step 4: what is removed is a multiple of ``G``, between two readings of the removal.

    ``a_min``, the largest multiple of ``G`` under every channel's removal, keeps all of the
    polarized light of the body's colour beyond it (the diffuse light's own), and is never more than
    the specular part of the two-colour fit of the removal (:func:`polcam.separation._diffuse_polarization.specular_part`: polarized light
    of the body's own colour, such as a uniform surface's diffuse polarization, is not removed as
    specular light, however much of it lies along ``G`` in every channel); ``a_G``, the
    least-squares projection of the removal on ``G``, reads it all as specular light and is not
    biased low by one channel's demosaicing error at a highlight; where the fit's body-coloured
    term carries more of the removal than its ``G``-coloured one (a contour's polarized diffuse
    light), ``a_G`` is no more than the fit's specular part either.  Where coherent polarized light
    marks a highlight (``coherent``, (H, W) in [0, 1]) they are weighed by the image's
    diffuse-like share ``weight`` in [0, 1]; elsewhere (noise, a matte surface) ``a_min`` alone:

        a = a_min + coherent (1 - weight) max(a_G - a_min, 0),   D1 = max(Ic - a G, 0).

    Where polarization removes most of a pixel's light the removal is specular light, and each
    channel's own reading of it carries that channel's demosaicing and noise error, which the
    one-colour removal would leave behind; there the per-channel removal ``diffuse`` is kept, by
    the share ``f = sum_c max(R_c, 0) / sum_c Ic_c`` the pixel loses:
    ``D = D1 + beta (diffuse - D1)``, ``beta`` a ramp over :data:`PER_CHANNEL_SHARE`.

    ``blind`` ((H, W, 3) bool or None): the blind channels, whose mean over the four angles is at
    the white level (every sample within 0.08 of full scale; step 6 and the learned stage use the
    same definition).  Such a channel shows no polarization worth reading, so its removal (0, or
    the clipping's remnant) says nothing of the specular light; where a pixel has
    both blind and seeing channels, ``a_min`` and ``a_G`` are read on the seeing channels alone
    (with no two-colour fit: two channels cannot tell two colours apart), and the blind channel
    loses the same multiple of ``G``; where a blind channel measures less than a seeing one per
    unit of ``G`` (``min_blind Ic_c / G_c < min_seeing Ic_s / G_s``) the pixel is left at ``Ic``.
    """
    xp = namespace(diffuse)
    removed = ic - diffuse
    a_g = sum3(removed * gx) / float((gx * gx).sum())
    spec, dominant = specular_part(removed, diffuse, gx, a_g, body_dominant=True)
    a_min = xp.minimum(xp.maximum(min3(removed / gx), 0.0), spec)
    a_g = xp.where(dominant, xp.minimum(a_g, spec), a_g)
    if blind is not None and not bool(blind.any()):
        blind = None
    if blind is not None:
        seen = ~blind
        part = blind.any(axis=-1) & seen.any(axis=-1)   # (H, W): some channel blind, some seeing
        least = min3(xp.where(seen, removed / gx, float("inf")))
        a_min = xp.where(part, xp.maximum(least, 0.0), a_min)
        g_seen = xp.where(seen, gx, 0.0)
        a_seen = sum3(removed * g_seen) / xp.maximum(sum3(g_seen * g_seen), LIGHT_GUARD)
        a_g = xp.where(part, xp.maximum(a_seen, 0.0), a_g)
    a = a_min + coherent * (1.0 - weight) * xp.maximum(a_g - a_min, 0.0)
    one = xp.maximum(ic - a[..., None] * gx, 0.0)
    lo, hi = PER_CHANNEL_SHARE
    lost = sum3(xp.maximum(removed, 0.0)) / xp.maximum(sum3(ic), LIGHT_GUARD)
    beta = xp.clip((lost - lo) / (hi - lo), 0.0, 1.0)[..., None]
    if blind is None:
        return one + beta * (diffuse - one)
    # a blind channel has no reading of its own: it loses the one multiple of G.  Measured below a
    # seeing channel per unit of G, it was cut by the clipping more than the pixel's colour shows,
    # and that multiple (read on the seeing channels, misread high near the clipping where one of
    # them sees under a weak illuminant component) would take it to a dark pit: such a pixel is
    # left as measured
    out = one + beta * (xp.where(blind, one, diffuse) - one)
    hidden = min3(xp.where(blind, ic / gx, float("inf"))) < min3(xp.where(blind, float("inf"), ic / gx))
    return xp.where((part & hidden)[..., None], ic, out)
