"""Clipped samples: rebuilt from the unclipped angles, or filled from the neighbours.

Used by ``polarized-residual`` (docs/algorithm.md, polarized-residual: declipping before step 1,
and the clipped highlights' fill of step 7).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.separation._illuminant import _SATURATED

__all__ = ["declipped", "fill_clipped_highlights", "inpaint"]

#: A clipped region is filled as a highlight in proportion to the share of its unclipped border
#: that shows coherent polarized specular light: not at all below _RING_SHARE - _RING_RAMP / 2,
#: wholly above _RING_SHARE + _RING_RAMP / 2.
_RING_SHARE = 0.3
_RING_RAMP = 0.4


def declipped(stack: Any) -> Any:
    """The stack with clipped samples rebuilt from the unclipped ones where the physics allows.

    ``stack`` is (4, H, W, C) float32 (angles 0, 45, 90, 135; C = 3 colours, or 1 for mono),
    numpy or torch (the result is of the same kind, on the same device).
    A sample at or above the white level (``_SATURATED``) holds less than the light that fell
    on it.  Per pixel and channel:

    * one clipped sample: every ideal polarizer stack has ``I0 + I90 = I45 + I135`` (both S0),
      so the clipped one is the sum of its two neighbours' angles less the opposite one;
    * two clipped samples: the two others give ``Ic`` and the amplitude ``A`` of
      ``I(t) = Ic + A cos(2t - 2 phi)`` once the AoLP ``phi`` is known, taken from the pixel's
      channels that have no clipped sample (a specular highlight's polarization is common to
      the channels, or from the nearest unclipped pixels within 15 pixels); skipped where none
      is found.  The 2 x 2 system's conditioning ``|det|`` weights the correction: none below
      0.15, all of it from 0.25, in proportion between (a cut at 0.2 made the rebuilt sample
      jump by the whole correction under a 1e-7 change of the others).

    A rebuilt value replaces the sample only when it is at least the clipped value (otherwise
    the measurement contradicts the model and is kept).  Pixels with a channel clipped at three
    or four angles are left as they are (the clipped highlights' fill handles them).
    """
    xp = namespace(stack)
    s = xp.copy(stack)
    clipped = stack >= _SATURATED                                  # (4, H, W, C)
    n = clipped.sum(axis=0)
    if not bool(n.any()):
        return s
    # pixels with a channel clipped at three or four angles are left whole: that channel is not
    # measured, and the clipped highlights' fill (from the neighbours) handles them
    n[(n >= 3).any(axis=-1)] = 0
    # one clipped sample (sparse: only those pixels and channels are touched)
    yy, xx, cc = xp.nonzero(n == 1)
    if yy.shape[0]:
        v = stack[:, yy, xx, cc]                                   # (4, N)
        k = xp.argmax(clipped[:, yy, xx, cc], axis=0)
        cols = xp.arange(yy.shape[0], like=v)
        est = v[(k + 1) % 4, cols] + v[(k + 3) % 4, cols] - v[(k + 2) % 4, cols]
        keep = est >= v[k, cols]
        s[k[keep], yy[keep], xx[keep], cc[keep]] = est[keep]
    yy, xx, cc = xp.nonzero(n == 2)
    if yy.shape[0]:
        free = ~clipped.any(axis=0)                                # (H, W, C) channels with no clipped sample
        qq = (0.5 * (stack[0] - stack[2]) * free).sum(axis=-1)
        uu = (0.5 * (stack[1] - stack[3]) * free).sum(axis=-1)
        # where no channel of the pixel is free, the AoLP of the free channels around it: the nearest of
        # the 7 x 7, 15 x 15 and 31 x 31 neighbourhoods that has any (a highlight's AoLP varies smoothly)
        have = free.any(axis=-1)
        for side in (7, 15, 31):
            if bool(have[yy, xx].all()):
                break
            qn = _imageops.box(xp.astype(qq, xp.float32), side, normalize=False)
            un = _imageops.box(xp.astype(uu, xp.float32), side, normalize=False)
            found = ~have & (xp.hypot(qn, un) > 0)
            qq = xp.where(found, qn, qq)
            uu = xp.where(found, un, uu)
            have = have | found
        phi = 0.5 * xp.arctan2(uu[yy, xx], qq[yy, xx])             # (N,)
        ok = xp.hypot(qq[yy, xx], uu[yy, xx]) > 0
        angles = xp.asarray(np.deg2rad(np.array([0.0, 45.0, 90.0, 135.0])), like=phi, dtype=xp.float64)
        cosk = xp.cos(2 * angles[:, None] - 2 * phi[None])          # (4, N)
        v = stack[:, yy, xx, cc]                                   # (4, N)
        cl = clipped[:, yy, xx, cc]
        order = xp.argsort(xp.astype(cl, xp.float32), axis=0, stable=True)   # unclipped first
        a, b = order[0], order[1]
        cols = xp.arange(yy.shape[0], like=v)
        det = cosk[b, cols] - cosk[a, cols]
        # trusted in full from |det| = 0.25, not at all below 0.15, in proportion between (a hard cut
        # made the rebuilt sample jump by the whole correction under a change of 1e-7 in the others)
        trust = xp.clip((abs(det) - 0.15) / 0.1, 0.0, 1.0)
        ok &= trust > 0
        amp = (v[b, cols] - v[a, cols]) / xp.where(ok, det, 1.0)
        icx = v[a, cols] - amp * cosk[a, cols]
        for j in (2, 3):
            k = order[j]
            est = v[k, cols] + trust * (icx + amp * cosk[k, cols] - v[k, cols])
            keep = ok & (est >= v[k, cols])
            s[k[keep], yy[keep], xx[keep], cc[keep]] = xp.astype(est[keep], s.dtype)
    return s


def inpaint(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Fill ``img`` ((H, W, C) float >= 0) where ``mask`` ((H, W) bool) from its surroundings.

    Telea's fast-marching method (J. Graphics Tools 9(1), 2004; OpenCV's ``INPAINT_TELEA``) per
    channel on 16-bit values (``img`` clipped to [0, 1]), radius 3 pixels (its cost grows with the
    radius squared: a fiftieth of the side took seconds on a full-resolution frame).
    """
    m = mask.astype(np.uint8)
    radius = 3.0
    out = np.empty_like(img, dtype=np.float32)
    for c in range(img.shape[-1]):
        # in 16 bits: OpenCV's float inpainting returns values outside its input's range
        x = np.round(np.clip(img[..., c], 0.0, 1.0) * 65535.0).astype(np.uint16)
        out[..., c] = cv2.inpaint(x, m, radius, cv2.INPAINT_TELEA).astype(np.float32) / 65535.0
    return out


def fill_clipped_highlights(diffuse: Any, measured: Any, ic: Any, spec: Any, g: Any) -> Any:
    """``polarized-residual``'s step 7: clipped highlights filled from their neighbours' diffuse by a multiple of ``g``.

    ``diffuse``, ``measured`` (the mean over angles as measured) and ``ic`` (after declipping) are
    (H, W, 3), ``spec`` (H, W) bool (coherent polarized specular light, step 3), ``g`` the (3,)
    illuminant; numpy or torch.  Returns the layer, of the same kind.

    Saturated pixels (a channel at the white level in all four angles): that channel's polarization
    sinusoid is not measured at all there, so its polarized light cannot be removed; the diffuse
    is filled in from the neighbours (Telea's fast-marching inpainting) as far as a single
    specular colour allows.  Only clipped highlights: a clipped region is filled in proportion
    to the share of its unclipped border (a 2-pixel ring) that shows coherent polarized specular
    light (``spec``, step 3), a ramp from none below 10 % to wholly above 50 % (``_RING_SHARE``,
    ``_RING_RAMP``); an overexposed diffuse surface has none around it and is left as measured.
    The labelling and the fast marching are sequential and run on the host (numpy and OpenCV); a
    torch array's masks and layer are copied there and the filled layer back, only when a pixel
    is clipped.
    """
    xp = namespace(diffuse)
    sat_px = xp.amax(measured, axis=-1) >= _SATURATED       # a channel clipped at all four angles
    if not bool(sat_px.any()):
        return diffuse
    sat_h = xp.to_numpy(sat_px)
    spec_h = xp.to_numpy(spec)
    n_cc, lab = cv2.connectedComponents(sat_h.astype(np.uint8), connectivity=8)
    lab_d = cv2.dilate(lab.astype(np.float32), np.ones((5, 5), np.uint8)).astype(np.int64)
    ring = (lab_d > 0) & ~sat_h
    hits = np.bincount(lab_d[ring], weights=spec_h[ring].astype(np.float64), minlength=n_cc)
    tot = np.bincount(lab_d[ring], minlength=n_cc)
    # how far each region is a highlight: a ramp of its border's polarized share over
    # _RING_SHARE +- _RING_RAMP / 2, not a switch (the share of a clipped ear moved across 0.3 between
    # two noise draws and its whole diffuse jumped by 0.5; docs/algorithm.md, tenth round)
    weight = np.clip((hits / np.maximum(tot, 1) - _RING_SHARE) / _RING_RAMP + 0.5, 0.0, 1.0)
    weight[0] = 0.0
    w_px = weight[lab]
    sat_h = w_px > 0
    if not 0 < int(sat_h.sum()) < sat_h.size // 2:
        return diffuse
    # the multiple t of the illuminant's colour (either sign) that brings the pixel nearest to
    # its neighbours' diffuse (least squares over the channels), within 0 <= diffuse <= I
    fill = xp.asarray(inpaint(xp.to_numpy(diffuse), sat_h), like=diffuse)
    wpx = xp.asarray(w_px.astype(np.float32), like=diffuse)[..., None]
    t = ((diffuse - fill) @ g) / float(g @ g)
    return diffuse + wpx * (xp.clip(diffuse - t[..., None] * g, 0.0, ic) - diffuse)
