"""``polarized-residual``'s optional steps for the unpolarized specular light (``unpolarized="measured"``).

Steps 2-6 of docs/methods/polarized-residual.md ("Optional steps for the unpolarized specular
light"), one function each: the polarized specular light as one multiple of the illuminant's
colour, its coherent gate, the ratio ``k`` of unpolarized to polarized specular light measured on
coloured highlights, and Shen & Zheng's colour prior on the residual.  They are off by default:
on the randomized family's validation split each of them lowers the mean object PSNR
(docs/methods/polarized-residual.md gives the figures).
The coherent gate (:func:`coherent_gate`) is used by every path.  Mono stacks with
``unpolarized="measured"`` take :func:`mono_steps` (k from the gradients, no colour).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.filters import joint_bilateral
from polcam.separation._clipping import declipped
from polcam.separation._common import LIT
from polcam.separation._diffuse_polarization import MIN_SINE, body_dominates, two_colour_fit
from polcam.separation._illuminant import SATURATED, plane_basis
from polcam.separation._polarization_noise import COHERENT_KSIG, noise_reduction, prior_removal
from polcam.separation.shen13 import cluster_ratios, ratio_specular

__all__ = ["residual_steps", "mono_steps", "coherent_gate", "gradient_ratio", "highlight_mask"]

#: Where polarized highlights measure k (unpolarized / polarized specular light) below this, the colour
#: prior is weighted down in proportion: step 2 has already removed almost all of their specular light.
_PRIOR_K = 0.5
#: Largest degree of polarization of diffuse light kept as diffuse (Atkinson & Hancock 2006, Fresnel
#: transmission: ~0.53 at grazing view for n = 1.8, below 0.4 short of 80 degrees).
_MAX_DIFFUSE_DOLP = 0.5
#: A polarized diffuse part is accepted only where the two-colour fit ``alpha G + beta e`` leaves less than
#: this share of what G alone leaves (the part off G lies along the pixel's body colour).
_DIFFUSE_FIT = 0.3


#: One 8-bit code value: the least light a display shows, and so the least amplitude or residual that
#: counts as specular light, whatever the threshold in relative terms.
_ONE_CODE = 1.0 / 255
#: Least light (channel sum or norm) by which a colour or share is divided: far below one code value, so
#: it only keeps black pixels from dividing by zero.
_LIGHT_GUARD = 1e-6
#: What ``G`` alone leaves of a pixel's amplitudes is significant beyond this many times its image median
#: (the misfit of noise and demosaicing) ...
_MISFIT_NOISE = 5.0
#: ... and beyond this share of the pixel's intensity (and one code value).
_MISFIT_SHARE = 0.01
#: Sides of the median filters of the residual's saturation: the wider gives each hue's most saturated
#: residual nearby, the narrower the pixel's own; medians are robust to colour noise without mixing the
#: colours of neighbouring materials.
_SAT_MEDIAN_WIDE = 5
_SAT_MEDIAN = 3
#: A pixel is coloured when its own saturation is at least this share of ``min_saturation`` (the most
#: saturated residual of its hue nearby must exceed ``min_saturation`` itself).
_OWN_SATURATION = 0.5
#: Fewest coloured highlight pixels (or gradient samples) that measure k; with fewer, k comes from the
#: highlights' spatial profile (or is 0).
_MIN_SAMPLES = 20
#: The local k is used where the neighbourhood's highlight weight is above this share of the image's
#: largest; the image's k elsewhere.
_LOCAL_WEIGHT = 1e-3
#: The colour prior's spatial scale (the specular-free image's ratio smoothing and the window of the
#: saturation that ramps it in), in coherent kernels ``k_s``.
_PRIOR_SCALE = 3
#: Intensity under which a pixel's gradients are left out of the gradient ratio (a silhouette is an edge
#: of both images), and the side of the erosion that keeps them away from such pixels.
_DARK = 2.0 / 255
_INNER_ERODE = 5
#: Least gradient of the coherent amplitude whose ratio is a sample of k (below: noise).
_MIN_GRADIENT = 1e-4


def _odd(n: float) -> int:
    k = max(int(round(n)), 1)
    return k if k % 2 else k + 1


def residual_steps(v: dict[str, Any], opts: dict[str, Any], keep: dict[str, Any] | None) -> tuple[Any, dict[str, Any]]:
    """Steps 2-6 on the quantities of step 1 (``v``: the names :func:`polarized_residual._colour` gives them).

    Returns the diffuse layer after the colour prior, (H, W, 3), and ``ratio``, ``ratio_source``,
    ``spec`` (step 3's mask of coherent polarized specular light) and ``floor``.
    """
    xp = namespace(v["s"])
    g, gx, ic, imin = v["g"], v["gx"], v["ic"], v["imin"]
    # 2. polarized specular light
    a, ub, resid, a_coh = _polarized_specular(v, opts)
    if keep is not None:
        keep.update(imin=xp.astype(imin, xp.float32), polarized_removed=xp.astype(resid, xp.float32))
    # 3. where coherent polarized specular light is (highlights; a_coh is specular only, step 2)
    floor, a_eff, gate, spec = highlight_mask(a_coh, ic.mean(axis=-1), v["k_small"], g,
                                              float(opts["polarized_threshold"]))
    k_ctx = _odd(opts["context"] * v["side"])
    # 4. hue and saturation of the residual
    sat_d, r_col, coloured = _residual_colour(resid, g, gx, opts, k_ctx)
    # 5. the unpolarized residual, k times the polarized specular light
    a_pix = xp.minimum(a_eff, a)                            # coherent, and no more than the pixel's own
    ratio, ratio_source, k_loc = _unpolarized_ratio(imin, gx, a_pix, gate, spec, r_col, coloured & ~v["clipped_any"],
                                                    float(opts["max_ratio"]), k_ctx)
    r = gate * k_loc * a_pix
    r = xp.minimum(r, xp.amin(resid / gx, axis=-1))         # diffuse >= 0 in every channel
    diffuse = xp.clip(resid - r[..., None] * gx, 0.0, ub)
    if keep is not None:
        keep["ratio_removed"] = xp.astype(diffuse, xp.float32)
    # 6. the colour prior on coloured materials' residual
    if opts["residual_model"] == "shen13":
        near_k = (gate, k_loc, k_ctx) if ratio_source == "coloured highlights" else None
        diffuse = _colour_prior(diffuse, resid, v, sat_d, opts, near_k)
    if keep is not None:
        keep["prior_removed"] = xp.astype(diffuse, xp.float32)
    return diffuse, {"ratio": ratio, "ratio_source": ratio_source, "spec": spec, "floor": floor}


def _polarized_specular(v: dict[str, Any], opts: dict[str, Any]) -> tuple[Any, Any, Any, Any]:
    """Step 2: the polarized specular light as the least multiple ``a`` of ``G`` that covers every channel's amplitude.

    So diffuse <= Imin with one specular colour.  Where the amplitudes are better explained by
    ``A = alpha G + beta e`` with alpha, beta of opposite signs (a diffuse part of colour ``e``
    polarized perpendicular to the specular, ``diffuse_polarization``), the specular part is
    ``|alpha| G`` and the diffuse keeps ``|beta| e`` (:func:`_diffuse_part`).  Returns ``a`` (H, W),
    the upper bound ``ub`` of the diffuse layer and the residual ``resid`` (H, W, 3) after ``a G`` is
    removed, and ``a_coh`` (H, W) with the diffuse part's coherent light taken out.
    """
    xp = namespace(v["s"])
    g, gx, ic, imin, isv, a_coh = v["g"], v["gx"], v["ic"], v["imin"], v["isv"], v["a_coh"]
    cover = xp.amax(isv / gx, axis=-1)
    esum = imin.sum(axis=-1, keepdims=True)
    e = xp.where(esum > _LIGHT_GUARD, imin / xp.maximum(esum, _LIGHT_GUARD), gx / g.sum())
    a = xp.astype(cover, xp.float32)
    b = xp.zeros(a.shape, like=a)
    if opts["diffuse_polarization"]:
        a, b, a_coh = _diffuse_part(v, e, a, a_coh)
    ub = xp.minimum(imin + b[..., None] * e, ic)            # diffuse <= Imin (+ its own polarized part)
    # the bound is met by more of the one specular colour, not by clipping channels one by one (which
    # would give the specular layer the colours of the channels' polarization errors)
    a = xp.maximum(a, xp.amax((ic - ub) / gx, axis=-1))
    a = xp.minimum(a, xp.amin(ic / gx, axis=-1))            # one specular colour: never more than the pixel has
    resid = xp.clip(ic - a[..., None] * gx, 0.0, ub)        # polarized specular light removed
    return a, ub, resid, a_coh


def _diffuse_part(v: dict[str, Any], e: Any, a: Any, a_coh: Any) -> tuple[Any, Any, Any]:
    """Step 2's two-colour fit ``alpha G + beta e``: where a polarized diffuse part of body colour ``e`` is.

    Returns ``a`` (the specular multiple of ``G``), ``b`` (``|beta|``, the diffuse part's polarized
    amplitude in units of ``e``) and ``a_coh`` with only the specular part marking a highlight, each
    (H, W) float32.
    """
    g, gx, ic, amp, amp_px = v["g"], v["gx"], v["ic"], v["amp"], v["amp_px"]
    xp = namespace(ic)
    gg = float(g @ g)
    amp_g = amp @ gx
    along = amp_g / gg
    off = xp.vnorm(amp - along[..., None] * gx, axis=-1)   # what G alone leaves unexplained
    noise = float(xp.median(off))
    ge = e @ gx
    ee = (e * e).sum(axis=-1)
    det = gg * ee - ge * ge
    well = det > (MIN_SINE ** 2) * gg * ee                # e far from G's colour
    # the decomposition from the pixel's own amplitudes: smoothing mixes the colours of neighbouring
    # pixels, which near occluding contours (where diffuse polarization is strongest) differ most
    dsafe = xp.where(well, det, 1.0)

    def fit(xg: Any, xe: Any) -> tuple[Any, Any, Any]:
        # per pixel, least squares x = alpha G + beta e; and whether the diffuse colour's term
        # dominates, |beta| |e| > |alpha| |G|
        al, be = two_colour_fit(xg, xe, gg, ge, ee, dsafe)
        return al, be, body_dominates(al, be, gg, ee)

    ga = amp_px @ gx
    al, be, dom = fit(ga, (amp_px * e).sum(axis=-1))
    # significant: beyond the typical misfit's noise, one code value and a share of the pixel's intensity
    sig_off = off > _MISFIT_NOISE * noise + xp.maximum(_MISFIT_SHARE * xp.vnorm(ic, axis=-1), _ONE_CODE)
    # and explained: what G leaves of the pixel's amplitudes lies along its own body colour e (the
    # two-colour fit leaves under _DIFFUSE_FIT of it); demosaicing's false polarization (one
    # channel's interpolation error, a neighbour's colour at an edge) points elsewhere
    off_px = xp.vnorm(amp_px - (ga / gg)[..., None] * gx, axis=-1)
    misfit = xp.vnorm(amp_px - al[..., None] * gx - be[..., None] * e, axis=-1)
    sig_off &= misfit < _DIFFUSE_FIT * off_px
    # also where the diffuse colour's term dominates the amplitudes (dom: a polarized diffuse part
    # with little or no specular light, e.g. near occluding contours): only a G term of the opposite
    # sign (perpendicular AoLP) is specular there, so the polarized diffuse light is kept
    # and physically possible: a diffuse surface's degree of polarization stays below _MAX_DIFFUSE_DOLP; a
    # larger |beta| e comes from a misfit (opposite-signed alpha and beta cancelling each other on
    # strongly polarized highlights)
    a_c = xp.where(al * be < 0, abs(al), 0.0)
    plaus = (abs(be)[..., None] * e
             <= _MAX_DIFFUSE_DOLP * xp.maximum(ic - a_c[..., None] * gx, 0.0) + _ONE_CODE).all(axis=-1)
    take = well & sig_off & ((al * be < 0) | dom) & plaus
    a = xp.astype(xp.where(take, xp.where(al * be < 0, abs(al), 0.0), a), xp.float32)
    b = xp.astype(xp.where(take, abs(be), 0.0), xp.float32)
    # for step 3, only the specular part marks a highlight: where the smoothed amplitudes' diffuse-
    # colour term dominates and what G leaves of them is beyond COHERENT_KSIG of its noise (a
    # surface's own coherent polarized light, as near occluding contours), the G term |alpha| alone
    # counts
    al_s, _, dom_s = fit(amp_g, (amp * e).sum(axis=-1))
    sig = v["sig"]
    own = well & dom_s & (off > COHERENT_KSIG * noise_reduction(v["k_small"]) * xp.sqrt((sig * sig).sum(axis=-1)))
    a_coh = xp.astype(xp.where(own, xp.minimum(abs(al_s), a_coh), a_coh), xp.float32)
    return a, b, a_coh


def highlight_mask(a_coh: Any, lum: Any, k_small: int, g: np.ndarray, threshold: float) -> tuple[float, Any, Any, Any]:
    """Step 3 for colour stacks: where coherent polarized specular light marks a highlight.

    :func:`coherent_gate` with ``a_coh`` in units of ``G`` (``g``, (3,) mean 1).  Returns its floor,
    ``a_eff`` and gate (H, W), and the mask (H, W) bool where the coherent polarized light is over
    ``threshold`` of the blurred intensity and over one code value.
    """
    xp = namespace(a_coh)
    floor, a_eff, lum_s, gate = coherent_gate(a_coh, lum, k_small, threshold, float(g.mean()))
    spec = a_eff * float(g.mean()) > xp.maximum(threshold * lum_s, _ONE_CODE)
    return floor, a_eff, gate, spec


def _residual_colour(resid: Any, g: np.ndarray, gx: Any, opts: dict[str, Any], k_ctx: int) -> tuple[Any, Any, Any]:
    """Step 4: hue and saturation of the residual around the illuminant's point of the chromaticity plane.

    Returns ``sat_d`` (H, W), the most saturated residual of the pixel's hue (or a neighbouring hue)
    within ``k_ctx``, the material's body colour; ``r_col`` (H, W), the residual specular light of
    coloured pixels in units of ``G`` (the share by which the pixel is paler than ``sat_d``); and
    ``coloured`` (H, W) bool.
    """
    xp = namespace(resid)
    h, w = resid.shape[:2]
    rsum = resid.sum(axis=-1)
    # a residual under LIT has no measurable hue: such a pixel lends no saturation to a hue (its hue
    # is that of rounding noise, ~1e-11, and would move under 1e-7 of input)
    lit = rsum > LIT
    chroma = resid / xp.maximum(rsum, _LIGHT_GUARD)[..., None]
    v = (chroma - gx / g.sum()) @ xp.asarray(plane_basis().T.astype(np.float32), like=resid)  # (H, W, 2)
    sat = xp.astype(xp.hypot(v[..., 0], v[..., 1]), xp.float32)
    sat = xp.astype(xp.where(lit, sat, 0.0), xp.float32)
    hue = xp.arctan2(v[..., 1], v[..., 0])
    nb = int(opts["hue_bins"])
    hbin = xp.astype(xp.floor((hue + np.pi) / (2 * np.pi) * nb), xp.index) % nb
    big = min(h, w) >= _SAT_MEDIAN_WIDE
    sat_m = _imageops.median(sat, _SAT_MEDIAN_WIDE) if big else sat
    sat = _imageops.median(sat, _SAT_MEDIAN) if big else sat
    sat_d = _saturation_by_hue(sat_m, hbin, lit, nb, k_ctx)
    ms = opts["min_saturation"]
    coloured = (sat_d > ms) & (sat > _OWN_SATURATION * ms) & lit
    share_spec = xp.where(coloured, 1.0 - xp.clip(sat / xp.maximum(sat_d, _LIGHT_GUARD), 0.0, 1.0), 0.0)
    r_col = share_spec * rsum / float(g.sum())              # residual specular, in units of G
    return sat_d, r_col, coloured


def _saturation_by_hue(sat_m: Any, hbin: Any, lit: Any, nb: int, k_ctx: int) -> Any:
    """Each pixel's most saturated lit residual of its hue bin or a neighbouring one, within ``k_ctx``."""
    xp = namespace(sat_m)
    sat_d = xp.zeros(sat_m.shape, like=sat_m)
    per_bin = []
    for k in range(nb):
        # only lit pixels lend their saturation to a hue: an unlit pixel's hue is that of rounding
        # noise (its residual is ~1e-11), while the median filters give it its lit neighbours'
        # saturation; a change of 1e-7 in the input moved it to another hue and moved the diffuse
        # of a whole neighbourhood by up to 0.17
        m = (hbin == k) & lit
        per_bin.append(_imageops.dilate(xp.astype(xp.where(m, sat_m, 0.0), xp.float32), k_ctx)
                       if bool(m.any()) else None)
    for k in range(nb):
        m = hbin == k
        if not bool(m.any()):
            continue
        best = xp.zeros((int(m.sum()),), like=sat_m)
        for j in (k - 1, k, k + 1):   # neighbouring hues too: noise moves a pixel's hue a little
            pb = per_bin[j % nb]
            if pb is not None:
                best = xp.maximum(best, pb[m])
        sat_d[m] = best
    return sat_d


def _unpolarized_ratio(imin: Any, gx: Any, a_pix: Any, gate: Any, spec: Any, r_col: Any, coloured: Any,
                       max_ratio: float, k_ctx: int) -> tuple[float, str, Any]:
    """Step 5: k, the unpolarized residual over the polarized specular light, measured on coloured highlights.

    k is the Fresnel ratio ``(1 - rho_s) / rho_s``, smoothed over the neighbourhood ``k_ctx``:
    achromatic pixels take the k of the coloured highlights around them (or of the image).  Only
    where coherent polarized light marks a highlight (``spec``: weakly polarized white surfaces stay
    diffuse) and not where a sample is clipped (``coloured`` excludes them: that pixel's colour, and
    so its specular share, is not measured, and a clipped channel makes the residual look paler,
    which overstated k).  Returns the image's k, where it came from, and the local k (H, W).
    """
    xp = namespace(imin)
    rel = coloured & spec & (a_pix > _ONE_CODE)
    num_p = xp.astype(xp.where(rel, xp.minimum(r_col, max_ratio * a_pix), 0.0), xp.float32)
    den_p = xp.astype(xp.where(rel, a_pix, 0.0), xp.float32)
    if int(rel.sum()) >= _MIN_SAMPLES:
        ratio = float(num_p.sum() / den_p.sum())
        ratio_source = "coloured highlights"
    else:  # no coloured highlight: the highlights' spatial profile decides (as for mono stacks)
        ratio = gradient_ratio(xp.astype((imin / gx).mean(axis=-1), xp.float32),
                               xp.astype(a_pix * gate, xp.float32), max_ratio)
        ratio_source = "gradients"
    num = _imageops.box(num_p, k_ctx, normalize=False)
    den = _imageops.box(den_p, k_ctx, normalize=False)
    k_loc = xp.where(den > _LOCAL_WEIGHT * max(float(den.max()), 1e-12), num / xp.maximum(den, 1e-12), ratio)
    return ratio, ratio_source, k_loc


def _colour_prior(diffuse: Any, resid: Any, v: dict[str, Any], sat_d: Any, opts: dict[str, Any],
                  near_k: tuple[Any, Any, int] | None) -> Any:
    """Step 6: Shen & Zheng's (2013) specular-free clustering on the residual of coloured materials.

    Applied in the illuminant-normalised space (where the residual specular light is white), never
    above the residual; achromatic pixels keep the polarization-decided layer (a ramp over the
    locally averaged residual's saturation from ``min_saturation`` to twice it).  ``near_k``
    (step 3's gate, step 5's local k and the context) weights the prior down near polarized
    highlights whose measured k is small.  Returns (H, W, 3).
    """
    gx, g, k_small, measured, sig = v["gx"], v["g"], v["k_small"], v["measured"], v["sig"]
    xp = namespace(diffuse)
    norm = resid / gx
    peak = float(norm.max())
    if not peak > 0:
        return diffuse
    sf = _specular_free(xp.astype(xp.clip(norm / peak, 0.0, 1.0), xp.float64), _PRIOR_SCALE * k_small) * peak * gx
    sf = xp.clip(sf, 0.0, resid)
    ms = float(opts["min_saturation"])
    # the saturation of the locally averaged layer of step 5 (the specular light that polarization
    # measured already removed, so a highlight's white light does not make a coloured material
    # look achromatic): colour noise (demosaicing) averages out
    kw = _odd(_PRIOR_SCALE * k_small)
    rb = _imageops.box(diffuse, kw)
    cb = rb / xp.maximum(rb.sum(axis=-1, keepdims=True), _LIGHT_GUARD) - gx / g.sum()
    sat_w = xp.vnorm(cb, axis=-1)
    wgt = xp.clip((sat_w - ms) / ms, 0.0, 1.0)
    # and only on coloured materials: the most saturated residual of the pixel's hue nearby
    # (step 4's sat_d, the material's body colour) ramps the prior in from min_saturation to
    # twice it, so a weakly coloured material is decided by polarization, not by colour
    wgt = wgt * xp.clip((sat_d - ms) / ms, 0.0, 1.0)
    if near_k is not None:
        # near polarized highlights whose measured k is small, their specular light was almost
        # all polarized and step 2 removed it: the colour prior is weighted down there
        gate, k_loc, k_ctx = near_k
        near = _imageops.box(xp.astype(gate, xp.float32), k_ctx)
        wgt = wgt * (1.0 - near * (1.0 - xp.clip(k_loc / _PRIOR_K, 0.0, 1.0)))
    # not where a channel is clipped at all four angles: that pixel's colour is not measured (an
    # overexposed white wall under a tinted light looked coloured and lost up to 38 % of its
    # light); a clipped highlight is the clipped fill's (_clipping)
    wgt = xp.where(xp.amax(measured, axis=-1) >= SATURATED, 0.0, wgt)
    wgt = wgt[..., None]
    return diffuse - wgt * prior_removal(diffuse, sf, sig if opts["noise"] != "off" else 0.0 * sig,
                                          smooth=k_small)


def _specular_free(image: Any, smooth: float) -> Any:
    """Shen & Zheng's (2013) specular-free image, its clusters' intensity ratios smoothed in the image.

    ``image`` is (H, W, 3) float64 in [0, 1] (numpy or torch); returns (H, W, 3) float32 in
    [0, image], of the same kind.  Each
    cluster's ratio ``Q`` (:func:`polcam.separation.shen13.cluster_ratios`, the paper's defaults) is
    a constant of its material, but the hard clustering puts the pixels of one smoothly shaded,
    weakly coloured material on both sides of a cluster boundary, and two ratios side by side make
    blotches (seen on lmmse-1's pink candy).  So the ratio map is filtered with a joint bilateral
    filter (polcam.filters; Yang, Wang & Ahuja, ECCV 2010, filter a ratio the same way) guided by
    the image's mean over channels: spatial sigma ``smooth`` pixels, range sigma a tenth of the
    guide's maximum, so material edges of different brightness keep their own ratios.
    """
    xp = namespace(image)
    q_map, _ = cluster_ratios(image)
    ok = xp.isfinite(q_map)
    if bool(ok.any()):
        # on a grid f times coarser (f = smooth / 6, as the filter's own grid): the ratio map is
        # piecewise constant, and the filter's cost at full resolution was a second a frame
        h, w = ok.shape
        f = max(1, int(smooth // 6))
        size = (max(1, -(-w // f)), max(1, -(-h // f)))
        f32 = xp.float32
        wt = _imageops.resize(xp.astype(ok, f32), size, interpolation="area")
        qw = _imageops.resize(xp.astype(xp.where(ok, q_map, 0.0), f32), size, interpolation="area")
        guide = _imageops.resize(xp.astype(image.mean(axis=-1), f32), size, interpolation="area")
        q_s = joint_bilateral(qw / xp.maximum(wt, 1e-12), guide, sigma_spatial=float(smooth) / f,
                              sigma_range=0.1 * max(float(guide.max()), 1e-6), weights=wt)
        q_s = _imageops.resize(xp.astype(q_s, f32), (w, h), interpolation="linear")
        q_map = xp.where(ok, xp.astype(q_s, xp.float64), float("nan"))
    return xp.astype(xp.clip(image - ratio_specular(image, q_map)[..., None], 0.0, image), xp.float32)


def coherent_gate(a_coh: Any, lum: Any, k_small: int, threshold: float,
                   scale: float = 1.0) -> tuple[float, Any, Any, Any]:
    """Where coherent polarized light marks a highlight (colour and mono paths alike).

    ``a_coh`` (H, W) is the smoothed polarized amplitude (times ``scale``, the illuminant's mean
    for colour, it is in the units of ``lum``), ``lum`` (H, W) the intensity.  Returns the floor
    that noise leaves everywhere (the median of ``a_coh``), ``a_eff = max(a_coh - floor, 0)``,
    ``lum`` Gaussian-blurred over ``k_small``, and the gate: a ramp from ``threshold`` to twice it
    in the coherent degree of polarization ``scale a_eff / lum_s``, (H, W) in [0, 1].
    """
    xp = namespace(a_coh)
    floor = float(xp.median(a_coh))
    a_eff = xp.maximum(a_coh - floor, 0.0)
    lum_s = _imageops.gaussian(lum, k_small)
    dop = a_eff * scale / xp.maximum(lum_s, 1e-6)
    return floor, a_eff, lum_s, xp.clip((dop - threshold) / threshold, 0.0, 1.0)


def gradient_ratio(imin: Any, a_pix: Any, max_ratio: float) -> float:
    """k that removes the highlights' spatial profile from ``imin - k a_pix`` (both (H, W)).

    k minimises the total variation of ``Imin - k a`` along a's gradients: the weighted median of the
    gradient ratios ``grad Imin / grad a`` (x and y Sobel components, weights ``|grad a|``), over
    pixels inside highlights and away from dark regions (a silhouette is an edge of both), clipped
    to [0, max_ratio]; 0 with fewer than 20 such gradients.
    """
    xp = namespace(imin)
    gi = xp.concatenate([_imageops.sobel(imin, 1, 0).reshape(-1), _imageops.sobel(imin, 0, 1).reshape(-1)])
    ga = xp.concatenate([_imageops.sobel(a_pix, 1, 0).reshape(-1), _imageops.sobel(a_pix, 0, 1).reshape(-1)])
    inner = _imageops.erode(xp.astype((a_pix > 0) & (imin > _DARK), xp.float32), _INNER_ERODE) > 0
    use = (abs(ga) > _MIN_GRADIENT) & xp.concatenate([inner.reshape(-1), inner.reshape(-1)])
    if int(use.sum()) < _MIN_SAMPLES:
        return 0.0
    rr = gi[use] / ga[use]
    ww = abs(ga[use])
    order = xp.argsort(rr)
    cw = xp.cumsum(ww[order])
    return float(np.clip(float(rr[order][xp.searchsorted(cw, 0.5 * cw[-1])]), 0.0, max_ratio))


def mono_steps(stack: Any, opts: dict[str, Any], k_small: int,
               keep: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
    """Mono stacks with ``unpolarized="measured"``: remove the polarized light, then k times the coherent polarized light.

    Without colour, k (the unpolarized / polarized ratio of the specular light) is chosen so that the
    diffuse layer ``Imin - k a`` carries as little of the highlights' spatial profile as possible:
    the weighted median of the gradient ratios ``grad Imin / grad a`` (:func:`gradient_ratio`;
    docs/methods/polarized-residual.md), clipped to [0, ``opts["max_ratio"]``].  ``stack`` is
    (4, H, W) float32, numpy or torch; ``k_small`` the coherent polarization's Gaussian kernel side.
    Returns the layer ((H, W) float32) and ``info``; ``keep`` (a dict) receives ``imin``.
    """
    xp = namespace(stack)
    s = stack
    measured = s.mean(axis=0)
    if opts["declip"]:
        s = declipped(s[..., None])[..., 0]
    ic = s.mean(axis=0)
    q = 0.5 * (s[0] - s[2])
    u = 0.5 * (s[1] - s[3])
    isv = xp.hypot(q, u)
    imin = xp.maximum(ic - isv, 0.0)
    a_coh = xp.hypot(_imageops.gaussian(q, k_small), _imageops.gaussian(u, k_small))
    floor, a_eff, _, gate = coherent_gate(a_coh, ic, k_small, float(opts["polarized_threshold"]))
    a_pix = xp.astype(xp.minimum(a_eff, isv) * gate, xp.float32)
    ratio = gradient_ratio(imin, a_pix, float(opts["max_ratio"]))
    diffuse = xp.clip(imin - ratio * a_pix, 0.0, xp.minimum(imin, measured))
    if keep is not None:
        keep["imin"] = xp.astype(imin, xp.float32)
    return xp.astype(diffuse, xp.float32), {"residual_ratio": ratio, "polarized_floor": floor}
