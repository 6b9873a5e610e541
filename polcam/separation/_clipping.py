"""Clipped samples: rebuilt from the unclipped angles; clipped highlights filled from their border.

Used by ``polarized-residual`` (docs/methods/polarized-residual.md: declipping before step 1,
and the clipped highlights' fill of step 7).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.separation._common import LIT, max3, sum3
from polcam.separation._illuminant import SATURATED

__all__ = ["declipped", "fill_clipped_highlights", "smooth_fill"]

#: A clipped region is filled as a highlight in proportion to the share of its unclipped border
#: that shows coherent polarized specular light: not at all below _RING_SHARE - _RING_RAMP / 2,
#: wholly above _RING_SHARE + _RING_RAMP / 2.  Without the vote (every region weighted 1) the first 400
#: validation scenes score the same (28.50 dB against 28.49) and the relit real stacks' specular colour
#: spread doubles (0.027 to 0.051): overexposed surfaces that are not highlights get filled.
_RING_SHARE = 0.3
_RING_RAMP = 0.4
#: Chromaticity spread (intensity-weighted RMS) of a clipped region's border under which the border is
#: one material, and so says what colour is under the clipping; none is filled from twice it.  On the
#: first 400 validation scenes (docs/methods/polarized-residual.md, step 6): 0.01-0.02 within 0.02 dB
#: of the best, no fill 0.02 dB under, any border 0.9 dB under.
_ONE_MATERIAL = 0.02


def _channels(a: Any, how: str) -> Any:
    """Largest (``how="max"``) or sum (``"sum"``) over the last axis of (..., C): elementwise for C = 3."""
    if a.shape[-1] == 3:
        return max3(a) if how == "max" else sum3(a)
    xp = namespace(a)
    return xp.amax(a, axis=-1) if how == "max" else a.sum(axis=-1)


def declipped(stack: Any) -> Any:
    """The stack with clipped samples rebuilt from the unclipped ones where the physics allows.

    ``stack`` is (4, H, W, C) float32 (angles 0, 45, 90, 135; C = 3 colours, or 1 for mono),
    numpy or torch (the result is of the same kind, on the same device).
    A sample at or above the white level (``SATURATED``) holds less than the light that fell
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
    clipped = stack >= SATURATED                                  # (4, H, W, C)
    n = clipped.sum(axis=0)
    if not bool(n.any()):
        return s
    # pixels with a channel clipped at three or four angles are left whole: that channel is not
    # measured, and the clipped highlights' fill (from the neighbours) handles them
    n[_channels(n, "max") >= 3] = 0
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
        qq = _channels(0.5 * (stack[0] - stack[2]) * free, "sum")
        uu = _channels(0.5 * (stack[1] - stack[3]) * free, "sum")
        # where no channel of the pixel is free, the AoLP of the free channels around it: the nearest of
        # the 7 x 7, 15 x 15 and 31 x 31 neighbourhoods that has any (a highlight's AoLP varies smoothly)
        have = _channels(free, "max")
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


def smooth_fill(img: np.ndarray, mask: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Fill ``img`` ((H, W, C) float32) where ``mask`` ((H, W) bool) smoothly from its surroundings.

    Push-pull interpolation (Gortler et al., SIGGRAPH 1996, "pull-push"): the known pixels (weight
    1, the masked ones 0) are reduced level by level with a Gaussian pyramid (weighted values and
    weights alike) until the mask is covered, then each level takes its own weighted mean where its
    weight is whole and the next coarser level's estimate, expanded, in proportion to its missing
    weight.  Known pixels keep their values exactly; the fill is a smooth (Gaussian-expanded)
    surface with the surroundings' colour, with no facets or seams (fast marching drew the
    X-shaped "pyramids" of its marching order in large regions).  ``weights`` ((H, W) in [0, 1],
    0 inside ``mask``), when given, replaces the known pixels' weight 1: the fill then draws on
    each pixel in proportion.  Returns (H, W, C) float32.
    """
    img = np.asarray(img, np.float32)
    known = (~np.asarray(mask, bool)).astype(np.float32)
    if weights is not None:
        known = np.where(mask, 0.0, np.clip(weights, 0.0, 1.0)).astype(np.float32)
    vals = [img * known[..., None]]
    wts = [known]
    while min(wts[-1].shape) > 1 and float(wts[-1].min()) <= 0.0:
        vals.append(np.atleast_3d(cv2.pyrDown(vals[-1])))
        wts.append(cv2.pyrDown(wts[-1]))
    est = vals[-1] / np.maximum(wts[-1], 1e-12)[..., None]
    for v, wt in zip(vals[-2::-1], wts[-2::-1]):
        up = np.atleast_3d(cv2.pyrUp(est, dstsize=(wt.shape[1], wt.shape[0])))
        alpha = np.clip(wt, 0.0, 1.0)[..., None]
        est = alpha * (v / np.maximum(wt, 1e-12)[..., None]) + (1.0 - alpha) * up
    return np.where(mask[..., None], est, img).astype(np.float32)


def _material_colour(px: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """The body chromaticity of the border pixels ``px`` ((N, 3) >= 0), its spread, and each pixel's weight.

    Near a highlight the border still holds some specular light, which pulls its chromaticity
    toward the illuminant's ``g``: the body colour is that of the pixels farthest from ``g``'s
    chromaticity.  Each lit pixel is weighted by a ramp of that distance from its median
    (weight 0) to its 0.9 quantile (weight 1), so that no pixel's vote switches under a small change.
    Returns the intensity- and ramp-weighted mean chromaticity ((3,), sum 1), the weighted RMS
    distance of theirs from it (inf for fewer than 4 lit pixels), and the weights ((N,) in [0, 1]).
    """
    tot = px.sum(axis=-1)
    lit = tot > LIT
    wts = np.zeros(px.shape[0])
    if int(lit.sum()) < 4:
        return np.full(3, 1.0 / 3.0), float("inf"), wts
    c = px[lit] / tot[lit, None]
    dist = np.linalg.norm(c - g / g.sum(), axis=-1)
    lo, hi = np.quantile(dist, [0.5, 0.9])
    # (all of them alike when their distances are: one colour, no highlight light in the band)
    ramp = np.clip((dist - lo) / (hi - lo), 0.0, 1.0) if hi - lo > 1e-6 else np.ones_like(dist)
    wts[lit] = ramp
    t = tot[lit] * ramp
    if float(t.sum()) <= 0:
        return np.full(3, 1.0 / 3.0), float("inf"), wts
    mean = (c * t[:, None]).sum(axis=0) / t.sum()
    return mean, float(np.sqrt((((c - mean) ** 2).sum(axis=-1) * t).sum() / t.sum())), wts


def fill_clipped_highlights(diffuse: Any, measured: Any, spec: Any, g: Any,
                            light: Any = None, *, colour_seen: bool = True, blind: Any = None) -> tuple[Any, dict[str, int]]:
    """``polarized-residual``'s last step: clipped highlights filled smoothly with their own material's diffuse.

    ``diffuse`` and ``measured`` (the mean over angles as measured) are (H, W, 3), ``spec`` (H, W)
    bool or float in [0, 1] (how far each pixel shows specular light), ``light`` None or (H, W)
    >= 0 (each border pixel's weight in the share, its intensity: dim pixels' votes are noise);
    numpy or torch.  ``blind`` ((H, W, 3) bool) marks the channels clipped at all four angles;
    by default those whose mean ``measured`` is at the white level (polarized-residual passes the
    same mask its step 4 read).  Returns the layer, of the same kind,
    and counts of the pixels with a channel clipped at all four angles: ``clipped_pixels``,
    ``clipped_filled`` (filled in part or whole), ``clipped_as_measured`` (not filled, every channel
    clipped: left as measured) and ``clipped_seen`` (not filled, some channel still measured: the
    layer ``diffuse`` kept, which polarized-residual's step 4 separated on those channels, or left
    as measured where a clipped channel measures less than a seeing one per unit of ``G``).

    At such a pixel that channel is not measured at all, so nothing under the clipping is known
    from the pixel itself.  Each 8-connected clipped region is filled only when its surroundings
    say what is under it:

    * it is a highlight: the share of its unclipped border (a 2-pixel ring) that shows coherent
      polarized specular light, on a ramp from none below ``_RING_SHARE - _RING_RAMP / 2`` to
      whole above ``_RING_SHARE + _RING_RAMP / 2`` (an overexposed matte surface has none);
    * the border is one material: the intensity-weighted RMS spread of its diffuse chromaticity,
      on a ramp from whole at ``_ONE_MATERIAL`` to none at twice it.  With ``colour_seen=False``
      (a mono stack taken as a grey one) the chromaticity was not measured, so no border shows
      one material and every region is left as measured.

    The fill is the border's diffuse interpolated smoothly into the region (:func:`smooth_fill`),
    so it has the colour of its own material, never above the measurement in any channel; a
    region's weight blends it with what the region holds unfilled, and a region with weight 0 is
    left so: the measured light where every channel is clipped (its specular layer is 0 there), the
    layer ``diffuse`` where some channel is still measured.  The labelling and the pyramid run on the host
    (numpy and OpenCV); a torch array's masks and layer are copied there and back, only when a
    pixel is clipped.
    """
    xp = namespace(diffuse)
    if blind is None:
        blind = measured >= SATURATED
    sat_px = blind.any(axis=-1)       # a channel clipped at all four angles
    n_sat = int(sat_px.sum())
    all_blind = blind.all(axis=-1)     # every channel clipped at all four angles
    n_blind = int(all_blind.sum())
    stats = {"clipped_pixels": n_sat, "clipped_filled": 0, "clipped_as_measured": n_blind,
             "clipped_seen": n_sat - n_blind}
    if n_sat == 0:
        return diffuse, stats
    if not colour_seen:
        return xp.where(sat_px[..., None], measured, diffuse), {**stats, "clipped_as_measured": n_sat,
                                                                "clipped_seen": 0}
    sat_h = xp.to_numpy(sat_px)
    dif_h = xp.to_numpy(diffuse).astype(np.float32)
    mea_h = xp.to_numpy(measured).astype(np.float32)
    g_h = np.asarray(xp.to_numpy(g), np.float64)
    n_cc, lab, boxes, _ = cv2.connectedComponentsWithStats(sat_h.astype(np.uint8), connectivity=8)
    lw = np.ones(sat_h.shape) if light is None else xp.to_numpy(light).astype(np.float64)
    weight = _highlight_votes(lab, n_cc, sat_h, xp.to_numpy(spec).astype(np.float64), lw)
    # unfilled clipped pixels: as measured where every channel is blind; where some channel still
    # sees, the layer (its polarized light removed on the seeing channels, step 4)
    blind_h = xp.to_numpy(all_blind)
    out = np.where(blind_h[..., None], mea_h, dif_h)
    stats_filled = filled_blind = 0
    for k in np.flatnonzero(weight > 0):
        reg, window = _fill_region(out, dif_h, mea_h, g_h, lab, k, boxes[k], sat_h, float(weight[k]))
        if reg is not None:
            stats_filled += int(reg.sum())
            filled_blind += int((reg & blind_h[window]).sum())
    stats["clipped_filled"] = stats_filled
    stats["clipped_as_measured"] = n_blind - filled_blind
    stats["clipped_seen"] = n_sat - n_blind - (stats_filled - filled_blind)
    return xp.asarray(out, like=diffuse), stats


def _highlight_votes(lab: np.ndarray, n_cc: int, sat: np.ndarray, spec: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Each labelled clipped region's weight in [0, 1] from its 2-pixel border's vote ((n_cc,); 0 for
    the background label): the light-weighted share of the border marked as specular light ``spec``,
    on a ramp from none below ``_RING_SHARE - _RING_RAMP / 2`` to whole above ``_RING_SHARE +
    _RING_RAMP / 2``."""
    lab_d = cv2.dilate(lab.astype(np.float32), np.ones((5, 5), np.uint8)).astype(np.int64)
    ring = (lab_d > 0) & ~sat
    hits = np.bincount(lab_d[ring], weights=spec[ring] * light[ring], minlength=n_cc)
    tot = np.bincount(lab_d[ring], weights=light[ring], minlength=n_cc)
    weight = np.clip((hits / np.maximum(tot, 1e-12) - _RING_SHARE) / _RING_RAMP + 0.5, 0.0, 1.0)
    weight[0] = 0.0
    return weight


def _fill_region(out: np.ndarray, dif: np.ndarray, mea: np.ndarray, g: np.ndarray, lab: np.ndarray, k: int,
                 box: np.ndarray, sat: np.ndarray, vote: float) -> tuple[np.ndarray | None, tuple[slice, slice]]:
    """Fill clipped region ``k`` of ``lab`` in ``out`` (in place) when its band is one material.

    The band around the region is as wide as its radius; its body colour and spread come from
    :func:`_material_colour`, and the region's weight is ``vote`` times the one-material ramp.  The
    fill (the band's body-colour intensity interpolated by :func:`smooth_fill`, times the body
    colour, never above ``mea``) is blended with what ``out`` holds there.  Returns the region's
    mask in its window and the window ((None, window) where its weight is 0: left unfilled).
    """
    h, w = sat.shape
    x0, y0, bw, bh, area = (int(v) for v in box)
    r = max(4, int(np.ceil(np.sqrt(area / np.pi))))      # the band: as wide as the region's radius
    window = (slice(max(y0 - r - 2, 0), min(y0 + bh + r + 2, h)), slice(max(x0 - r - 2, 0), min(x0 + bw + r + 2, w)))
    reg = lab[window] == k
    band = (cv2.dilate(reg.astype(np.uint8), np.ones((2 * r + 5, 2 * r + 5), np.uint8)) > 0) & ~sat[window]
    colour, spread, body = _material_colour(dif[window][band], g)
    wk = vote * float(np.clip(2.0 - spread / _ONE_MATERIAL, 0.0, 1.0))
    if wk <= 0:
        return None, window
    # the intensity under the region: interpolated from the border's body-colour pixels only (the
    # others still hold some of the highlight's specular light)
    known = np.zeros(band.shape, np.float32)
    known[band] = body
    lum = smooth_fill(dif[window].sum(axis=-1, keepdims=True), reg, known)[..., 0]
    fill = np.clip(lum[reg][:, None] * colour[None], 0.0, mea[window][reg])
    sub = out[window]
    sub[reg] = wk * fill + (1.0 - wk) * sub[reg]
    return reg, window
