"""``polarized-residual``: polcam's own separation: remove the polarized light, then model only the residual.

The physics (docs/algorithm.md, polarized-residual, gives the equations and the
benchmarks behind every choice):

* Specular reflection has the illuminant's colour ``G`` and is partly
  polarized (Fresnel: degree ``rho_s``, strongly near Brewster's angle, weakly
  near normal incidence).  Its polarized part is measured by the polarization
  sinusoid and removed exactly.
* Diffuse reflection is unpolarized or weakly polarized with its AoLP
  perpendicular to the specular's (Atkinson & Hancock 2006; Kajiyama et al.
  WACV 2023).  Per pixel the signed amplitudes of the three channels along a
  common axis are ``A = a G - b e`` with ``e`` the diffuse colour: the part
  along ``G`` is specular, the perpendicular diffuse part ``b e`` is kept.
* The unpolarized part ``(1 - rho_s) s G`` of the specular light is what needs
  a prior.  A dichromatic prior is applied to that residual only: in the
  chromaticity plane every pixel of one material lies on the line from its
  diffuse chromaticity to the illuminant's, so its hue around the illuminant
  point identifies the material and its saturation, against the most saturated
  pixel of that hue nearby, gives the specular share.  Achromatic surfaces
  (no hue) are decided by polarization and spatial context: only where
  polarized specular light is present nearby is any residual removed, and there
  in the proportion of unpolarized to polarized specular light measured on the
  coloured highlights of the same image.  A white wall with no polarized
  specular light stays diffuse.
* Constraints: ``0 <= diffuse <= Imin`` (plus the diffuse light's own
  polarized amplitude where it is found), and a single specular colour ``G``
  for the residual.
* Clipped highlights (a channel at the white level at all four angles, bordered
  by polarized specular light): nothing is measured there, so the diffuse is
  filled from the neighbours' (inpainting) by a multiple of ``G``.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from polcam.errors import MethodError
from polcam.separation._clipping import declipped, inpaint
from polcam.separation._illuminant import _SATURATED, _plane_basis, estimate_illuminant
from polcam.separation._polarization_noise import (
    _COHERENT_KSIG,
    _axis_debias,
    _prior_removal,
    _reduction,
    _stokes_noise,
)
from polcam.separation._registry import register

__all__ = ["REFERENCE", "separate_polarized_residual", "stages", "DEFAULTS"]

REFERENCE = (
    "polcam's own method; builds on L. B. Wolff & T. E. Boult, IEEE TPAMI 13(7) 1991 (polarization "
    "minimum); S. A. Shafer, Color Res. Appl. 10(4) 1985 (dichromatic model); S. Wen, Y. Zheng & F. Lu, "
    "IEEE TIP 30 2021; G. A. Atkinson & E. R. Hancock, IEEE TIP 15(6) 2006; Kajiyama et al., WACV 2023"
)

#: Default options (docs/algorithm.md gives the benchmark behind each).
DEFAULTS: dict[str, Any] = {
    "illuminant": None,          # None: estimate; or an RGB triple
    "efficiency": None,          # per-colour polarizer efficiency from a calibration, (3,) in (0, 1]
    "diffuse_polarization": True,
    "context": 0.12,             # neighbourhood side, as a share of the image's larger side
    "hue_bins": 24,
    "min_saturation": 0.04,      # below: achromatic (no hue)
    "polarized_threshold": 0.02,  # polarized specular / intensity that marks a highlight neighbourhood
    "max_ratio": 4.0,            # unpolarized specular residual <= max_ratio x the polarized specular nearby
    "noise": "shrink",           # the amplitude's noise bias: "off", "rice", "shrink" (garrote) or "thresh";
                                 # unless "off", the colour prior's removal is shrunk by the noise too
    "declip": True,              # rebuild clipped samples from the other angles (S0 identity, shared AoLP)
    "residual_model": "shen13",  # coloured pixels' residual: "shen13" (specular-free clustering) or "hue"
}


#: Where polarized highlights measure k (unpolarized / polarized specular light) below this, the colour
#: prior is weighted down in proportion: step 2 has already removed almost all of their specular light.
_PRIOR_K = 0.5
#: Largest degree of polarization of diffuse light kept as diffuse (Atkinson & Hancock 2006, Fresnel
#: transmission: ~0.53 at grazing view for n = 1.8, below 0.4 short of 80 degrees).
_MAX_DIFFUSE_DOLP = 0.5
#: A polarized diffuse part is accepted only where the two-colour fit ``alpha G + beta e`` leaves less than
#: this share of what G alone leaves (the part off G lies along the pixel's body colour).
_DIFFUSE_FIT = 0.3


def _check(opts: dict[str, Any]) -> None:
    for k in ("context", "min_saturation", "polarized_threshold"):
        v = opts[k]
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not (0 < float(v) < 1):
            raise MethodError(f"polarized-residual: {k}={v!r}: expected a number in (0, 1)")
    mr = opts["max_ratio"]
    if isinstance(mr, bool) or not isinstance(mr, (int, float, np.floating)) or not 0 <= float(mr) < 1e3:
        raise MethodError(f"polarized-residual: max_ratio={mr!r}: expected a number in [0, 1000)")
    for k in ("declip", "diffuse_polarization"):
        if not isinstance(opts[k], (bool, np.bool_)):
            raise MethodError(f"polarized-residual: {k}={opts[k]!r}: expected True or False")
    if opts["noise"] not in ("off", "rice", "shrink", "thresh"):
        raise MethodError(f"polarized-residual: noise={opts['noise']!r}: expected 'off', 'rice', 'shrink' or 'thresh'")
    if opts["residual_model"] not in ("shen13", "hue"):
        raise MethodError(f"polarized-residual: residual_model={opts['residual_model']!r}: expected 'shen13' or 'hue'")
    hb = opts["hue_bins"]
    if isinstance(hb, bool) or not isinstance(hb, (int, np.integer)) or not 4 <= hb <= 360:
        raise MethodError(f"polarized-residual: hue_bins={hb!r}: expected an integer in [4, 360]")
    g = opts["illuminant"]
    if g is not None:
        arr = np.asarray(g, dtype=np.float64).reshape(-1)
        if arr.size != 3 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            raise MethodError(f"polarized-residual: illuminant={g!r}: expected three positive numbers (R, G, B)")


def _odd(n: float) -> int:
    k = max(int(round(n)), 1)
    return k if k % 2 else k + 1


@register("polarized-residual", kind="stack", mono=True, reference=REFERENCE, options=tuple(DEFAULTS))
def separate_polarized_residual(stack: np.ndarray, **options: Any) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer of a colour polarization stack (module docstring).

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1], angles 0, 45, 90, 135.
    **options
        See :data:`DEFAULTS`: ``illuminant`` (RGB or None), ``efficiency``
        ((3,) per-colour polarizer efficiency in (0, 1] or None),
        ``diffuse_polarization`` (keep a perpendicular polarized diffuse part), ``noise`` (how the
        polarized amplitude's noise bias is removed; unless "off", the colour prior's removal is
        shrunk by the noise too), ``declip`` (rebuild clipped samples),
        ``context``, ``hue_bins``, ``min_saturation``, ``polarized_threshold``.

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) float32 in [0, mean over angles].
    info : dict
        ``illuminant`` (RGB, mean 1), ``illuminant_source``, ``efficiency``,
        ``residual_ratio`` (unpolarized / polarized specular light on coloured highlights).
    """
    return _separate(stack, options, None)


def stages(stack: np.ndarray, **options: Any) -> dict[str, np.ndarray]:
    """The diffuse layer after each step, to see which step does what on a frame.

    Parameters
    ----------
    stack
        (4, H, W, 3) or (4, H, W) float in [0, 1], angles 0, 45, 90, 135.
    **options
        As :func:`separate_polarized_residual`.

    Returns
    -------
    dict
        float32 arrays of one angle image's shape, >= 0 (and at most the mean over angles, except
        before the last step where clipped samples were rebuilt): ``imin`` (``Ic`` less each channel's debiased polarized amplitude), and for colour stacks
        ``polarized_removed`` (after step 2: the polarized specular light removed),
        ``ratio_removed`` (after step 5: ``k`` times it more), ``prior_removed`` (after step 6, the
        colour prior; before the clipped highlights' fill); and ``diffuse``, the layer
        :func:`separate_polarized_residual` returns.  Each of the three step layers is at most the
        one before it.
    """
    keep: dict[str, np.ndarray] = {}
    diffuse, _ = _separate(stack, options, keep)
    keep["diffuse"] = diffuse
    return keep


def _separate(stack: np.ndarray, options: dict[str, Any],
              keep: dict[str, np.ndarray] | None) -> tuple[np.ndarray, dict[str, Any]]:
    """:func:`separate_polarized_residual`; with ``keep`` (a dict), the step layers go into it."""
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise MethodError(f"polarized-residual: unknown option(s) {', '.join(sorted(unknown))}")
    opts = {**DEFAULTS, **options}
    _check(opts)
    s = np.asarray(stack, dtype=np.float32)
    if s.ndim == 3 and s.shape[0] == 4:
        return _mono(s, opts, keep)
    if s.ndim != 4 or s.shape[0] != 4 or s.shape[-1] != 3:
        raise MethodError(f"polarized-residual: stack of shape {s.shape}: expected (4, H, W, 3) or (4, H, W)")
    h, w = s.shape[1:3]
    measured = s.mean(axis=0)
    clipped_any = (s >= _SATURATED).any(axis=(0, 3))       # (H, W): a sample of the pixel at the white level
    if opts["declip"]:
        s = declipped(s)
    ic = s.mean(axis=0)
    q = 0.5 * (s[0] - s[2])
    u = 0.5 * (s[1] - s[3])

    # illuminant and per-colour polarizer efficiency
    if opts["illuminant"] is not None:
        g = np.asarray(opts["illuminant"], dtype=np.float64)
        est = None
        eff = np.ones(3) if opts["efficiency"] is None else np.asarray(opts["efficiency"], np.float64)
        if opts["efficiency"] is not None:
            from polcam.separation._illuminant import _check_efficiency

            eff = _check_efficiency(eff)
        source = "given"
    else:
        est = estimate_illuminant(s, efficiency=opts["efficiency"])
        g = est.colour
        eff = est.efficiency if est.source == "calibration" else np.ones(3)
        source = est.source
    g = (g / g.mean()).astype(np.float32)
    if not np.all(eff == 1):
        q = q / eff.astype(np.float32)
        u = u / eff.astype(np.float32)
    sig = _stokes_noise(s, ic)

    # 1. coherent polarization: Stokes components smoothed over a few pixels (demosaicing and noise
    #    leave polarization of alternating sign that this cancels; a highlight's is coherent); their
    #    common axis and the signed amplitude of every channel along it
    side = max(h, w)
    k_small = _odd(max(3.0, side / 200))
    qs = cv2.GaussianBlur(q, (k_small, k_small), 0)
    us = cv2.GaussianBlur(u, (k_small, k_small), 0)
    qq = (qs / g).sum(axis=-1)
    uu = (us / g).sum(axis=-1)
    nn = np.hypot(qq, uu)
    safe = nn > 0
    c2 = np.where(safe, qq / np.where(safe, nn, 1), 1.0)[..., None]
    s2 = np.where(safe, uu / np.where(safe, nn, 1), 0.0)[..., None]
    amp = qs * c2 + us * s2                                 # (H, W, 3) signed
    amp_px = q * c2 + u * s2                                # the same, unsmoothed (the pixel's own colours)
    # the polarized amplitude with the noise's bias removed: unbiased along the axis where the smoothed
    # amplitude fixes it, shrunk by the noise elsewhere (_polarization_noise._axis_debias)
    if opts["noise"] == "off":
        isv = np.hypot(q, u)
    else:
        isv = _axis_debias(q, u, c2, s2, amp, sig, _reduction(k_small), opts["noise"])
    imin = np.maximum(ic - isv, 0.0)
    # in units of G: the G-normalised channel sum is 3 a for a G-coloured polarized specular, while
    # colour demosaicing's polarization errors differ between channels and partly cancel in it
    a_coh = (nn / 3.0).astype(np.float32)

    # 2. polarized specular light: the least multiple a of G that covers every channel's amplitude
    #    (so diffuse <= Imin with one specular colour); where the amplitudes are better explained by
    #    A = alpha G + beta e with alpha, beta of opposite signs (a diffuse part of colour e polarized
    #    perpendicular to the specular), the specular part is |alpha| G and the diffuse keeps |beta| e.
    gg = float(g @ g)
    amp_g = amp @ g
    along = amp_g / gg
    cover = (isv / g).max(axis=-1)
    esum = imin.sum(axis=-1, keepdims=True)
    e = np.where(esum > 1e-6, imin / np.maximum(esum, 1e-6), g / g.sum())
    a = cover.astype(np.float32)
    b = np.zeros_like(a)
    if opts["diffuse_polarization"]:
        off = np.linalg.norm(amp - along[..., None] * g, axis=-1)   # what G alone leaves unexplained
        noise = float(np.median(off))
        ge = e @ g
        ee = (e * e).sum(axis=-1)
        det = gg * ee - ge * ge
        well = det > (0.2 ** 2) * gg * ee                  # e far from G's colour (sin > 0.2)
        # the decomposition from the pixel's own amplitudes: smoothing mixes the colours of neighbouring
        # pixels, which near occluding contours (where diffuse polarization is strongest) differ most
        dsafe = np.where(well, det, 1.0)

        def fit(xg: np.ndarray, xe: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            # per pixel, least squares x = alpha G + beta e from x.G and x.e; and whether the diffuse
            # colour's term dominates, |beta| |e| > |alpha| |G|
            al = (ee * xg - ge * xe) / dsafe
            be = (gg * xe - ge * xg) / dsafe
            return al, be, np.abs(be) * np.sqrt(ee) > np.abs(al) * np.sqrt(gg)

        ga = amp_px @ g
        al, be, dom = fit(ga, (amp_px * e).sum(axis=-1))
        # significant: beyond five times the typical misfit, 1/255 and 1 % of the pixel's intensity
        sig_off = off > 5.0 * noise + np.maximum(1.0 / 255, 0.01 * np.linalg.norm(ic, axis=-1))
        # and explained: what G leaves of the pixel's amplitudes lies along its own body colour e (the
        # two-colour fit leaves under _DIFFUSE_FIT of it); demosaicing's false polarization (one
        # channel's interpolation error, a neighbour's colour at an edge) points elsewhere
        off_px = np.linalg.norm(amp_px - (ga / gg)[..., None] * g, axis=-1)
        misfit = np.linalg.norm(amp_px - al[..., None] * g - be[..., None] * e, axis=-1)
        sig_off &= misfit < _DIFFUSE_FIT * off_px
        # also where the diffuse colour's term dominates the amplitudes (dom: a polarized diffuse part
        # with little or no specular light, e.g. near occluding contours): only a G term of the opposite
        # sign (perpendicular AoLP) is specular there, so the polarized diffuse light is kept
        # and physically possible: a diffuse surface's degree of polarization stays below 0.5 (Atkinson &
        # Hancock 2006: at most ~0.53 at grazing view for n = 1.8); a larger |beta| e comes from a misfit
        # (opposite-signed alpha and beta cancelling each other on strongly polarized highlights)
        a_c = np.where(al * be < 0, np.abs(al), 0.0)
        plaus = (np.abs(be)[..., None] * e
                 <= _MAX_DIFFUSE_DOLP * np.maximum(ic - a_c[..., None] * g, 0.0) + 1.0 / 255).all(axis=-1)
        take = well & sig_off & ((al * be < 0) | dom) & plaus
        a = np.where(take, np.where(al * be < 0, np.abs(al), 0.0), a).astype(np.float32)
        b = np.where(take, np.abs(be), 0.0).astype(np.float32)
        # for step 3, only the specular part marks a highlight: where the smoothed amplitudes' diffuse-
        # colour term dominates and what G leaves of them is beyond _COHERENT_KSIG of its noise (a
        # surface's own coherent polarized light, as near occluding contours), the G term |alpha| alone
        # counts
        al_s, _, dom_s = fit(amp_g, (amp * e).sum(axis=-1))
        own = well & dom_s & (off > _COHERENT_KSIG * _reduction(k_small) * np.sqrt((sig * sig).sum(axis=-1)))
        a_coh = np.where(own, np.minimum(np.abs(al_s), a_coh), a_coh).astype(np.float32)
    ub = np.minimum(imin + b[..., None] * e, ic)            # diffuse <= Imin (+ its own polarized part)
    # the bound is met by more of the one specular colour, not by clipping channels one by one (which
    # would give the specular layer the colours of the channels' polarization errors)
    a = np.maximum(a, ((ic - ub) / g).max(axis=-1))
    a = np.minimum(a, (ic / g).min(axis=-1))                # one specular colour: never more than the pixel has
    resid = np.clip(ic - a[..., None] * g, 0.0, ub)         # polarized specular light removed
    if keep is not None:
        keep.update(imin=imin.astype(np.float32), polarized_removed=resid.astype(np.float32))

    # 3. where coherent polarized specular light is (highlights; a_coh is specular only, step 2)
    lum = ic.mean(axis=-1)
    floor, a_eff, lum_s, gate = _coherent_gate(a_coh, lum, k_small, float(opts["polarized_threshold"]),
                                               float(g.mean()))
    spec = a_eff * float(g.mean()) > np.maximum(opts["polarized_threshold"] * lum_s, 1.0 / 255)
    k_ctx = _odd(opts["context"] * side)

    # 4. hue and saturation of the residual around the illuminant point of the chromaticity plane
    rsum = resid.sum(axis=-1)
    lit = rsum > 3.0 / 255
    chroma = resid / np.maximum(rsum, 1e-6)[..., None]
    v = (chroma - g / g.sum()) @ _plane_basis().T.astype(np.float32)  # (H, W, 2)
    sat = np.hypot(v[..., 0], v[..., 1]).astype(np.float32)
    sat = np.where(lit, sat, 0.0).astype(np.float32)
    hue = np.arctan2(v[..., 1], v[..., 0])
    nb = int(opts["hue_bins"])
    hbin = np.floor((hue + np.pi) / (2 * np.pi) * nb).astype(np.int32) % nb
    # median filters: robust to colour noise without mixing the colours of neighbouring materials
    big = min(h, w) >= 5
    sat_m = cv2.medianBlur(sat, 5) if big else sat
    sat = cv2.medianBlur(sat, 3) if big else sat
    kernel = np.ones((k_ctx, k_ctx), np.uint8)
    sat_d = np.zeros_like(sat)
    per_bin = []
    for k in range(nb):
        m = hbin == k
        per_bin.append(cv2.dilate(np.where(m, sat_m, 0.0).astype(np.float32), kernel) if m.any() else None)
    for k in range(nb):
        m = hbin == k
        if not m.any():
            continue
        best = np.zeros(int(m.sum()), np.float32)
        for j in (k - 1, k, k + 1):   # neighbouring hues too: noise moves a pixel's hue a little
            pb = per_bin[j % nb]
            if pb is not None:
                best = np.maximum(best, pb[m])
        sat_d[m] = best
    coloured = (sat_d > opts["min_saturation"]) & (sat > 0.5 * opts["min_saturation"]) & lit
    share_spec = np.where(coloured, 1.0 - np.clip(sat / np.maximum(sat_d, 1e-6), 0.0, 1.0), 0.0)
    r_col = share_spec * rsum / float(g.sum())              # residual specular, in units of G

    # 5. the unpolarized residual is k times the polarized specular light, with k (the Fresnel ratio
    #    (1 - rho_s) / rho_s) measured on coloured highlights and smoothed over the neighbourhood:
    #    achromatic pixels take the k of the coloured highlights around them (or of the image)
    a_pix = np.minimum(a_eff, a)                            # coherent, and no more than the pixel's own
    # only where coherent polarized light marks a highlight (step 3's gate: weakly polarized white
    # surfaces stay diffuse)
    # not where a sample is clipped: that pixel's colour (and so its specular share) is not measured, and
    # a clipped channel makes the residual look paler, which overstated k
    rel = coloured & spec & (a_pix > 1.0 / 255) & ~clipped_any
    num_p = np.where(rel, np.minimum(r_col, float(opts["max_ratio"]) * a_pix), 0.0).astype(np.float32)
    den_p = np.where(rel, a_pix, 0.0).astype(np.float32)
    if int(rel.sum()) >= 20:
        ratio = float(num_p.sum() / den_p.sum())
        ratio_source = "coloured highlights"
    else:  # no coloured highlight: the highlights' spatial profile decides (as for mono stacks)
        ratio = _gradient_ratio((imin / g).mean(axis=-1).astype(np.float32), (a_pix * gate).astype(np.float32),
                                float(opts["max_ratio"]))
        ratio_source = "gradients"
    num = cv2.boxFilter(num_p, -1, (k_ctx, k_ctx), normalize=False)
    den = cv2.boxFilter(den_p, -1, (k_ctx, k_ctx), normalize=False)
    k_loc = np.where(den > 1e-3 * max(float(den.max()), 1e-12), num / np.maximum(den, 1e-12), ratio)
    r = gate * k_loc * a_pix
    r = np.minimum(r, (resid / g).min(axis=-1))             # diffuse >= 0 in every channel
    diffuse = np.clip(resid - r[..., None] * g, 0.0, ub)
    if keep is not None:
        keep["ratio_removed"] = diffuse.astype(np.float32)
    if opts["residual_model"] == "shen13":
        # coloured pixels: Shen & Zheng's (2013) specular-free clustering applied to the residual only,
        # in the illuminant-normalised space (where the residual specular light is white), never
        # above the residual; achromatic pixels keep the polarization-decided layer above (a ramp
        # over the locally averaged residual's saturation from min_saturation to twice it)
        norm = resid / g
        peak = float(norm.max())
        if peak > 0:
            sf = _specular_free(np.clip(norm / peak, 0.0, 1.0).astype(np.float64), 3 * k_small) * peak * g
            sf = np.clip(sf, 0.0, resid)
            ms = float(opts["min_saturation"])
            # the saturation of the locally averaged layer of step 5 (the specular light that polarization
            # measured already removed, so a highlight's white light does not make a coloured material
            # look achromatic): colour noise (demosaicing) averages out
            kw = _odd(3 * k_small)
            rb = cv2.blur(diffuse, (kw, kw))
            cb = rb / np.maximum(rb.sum(axis=-1, keepdims=True), 1e-6) - g / g.sum()
            sat_w = np.linalg.norm(cb, axis=-1)
            wgt = np.clip((sat_w - ms) / ms, 0.0, 1.0)
            # and only on coloured materials: the most saturated residual of the pixel's hue nearby
            # (step 4's sat_d, the material's body colour) ramps the prior in from min_saturation to
            # twice it, so a weakly coloured material is decided by polarization, not by colour
            wgt = wgt * np.clip((sat_d - ms) / ms, 0.0, 1.0)
            if ratio_source == "coloured highlights":
                # near polarized highlights whose measured k is small, their specular light was almost
                # all polarized and step 2 removed it: the colour prior is weighted down there
                near = cv2.blur(gate.astype(np.float32), (k_ctx, k_ctx))
                wgt = wgt * (1.0 - near * (1.0 - np.clip(k_loc / _PRIOR_K, 0.0, 1.0)))
            wgt = wgt[..., None]
            diffuse = diffuse - wgt * _prior_removal(diffuse, sf, sig if opts["noise"] != "off" else 0.0 * sig,
                                                     smooth=k_small)
    if keep is not None:
        keep["prior_removed"] = diffuse.astype(np.float32)
    # saturated pixels (a channel at the white level in all four angles): that channel's polarization
    # sinusoid is not measured at all there, so its polarized light cannot be removed; the diffuse
    # is filled in from the neighbours (Telea's fast-marching inpainting) as far as a single
    # specular colour allows
    sat_px = measured.max(axis=-1) >= _SATURATED                   # a channel clipped at all four angles
    if sat_px.any():
        # only clipped highlights: a clipped region at least 30 % of whose unclipped border (a 2-pixel
        # ring) shows coherent polarized specular light (step 3); an overexposed diffuse surface has
        # none around it and is left as measured
        n_cc, lab = cv2.connectedComponents(sat_px.astype(np.uint8), connectivity=8)
        lab_d = cv2.dilate(lab.astype(np.float32), np.ones((5, 5), np.uint8)).astype(np.int64)
        ring = (lab_d > 0) & ~sat_px
        hits = np.bincount(lab_d[ring], weights=spec[ring].astype(np.float64), minlength=n_cc)
        tot = np.bincount(lab_d[ring], minlength=n_cc)
        keep = hits >= 0.3 * np.maximum(tot, 1)
        keep[0] = False
        sat_px = keep[lab]
    if 0 < int(sat_px.sum()) < sat_px.size // 2:
        # the multiple t of the illuminant's colour (either sign) that brings the pixel nearest to
        # its neighbours' diffuse (least squares over the channels), within 0 <= diffuse <= I
        fill = inpaint(diffuse, sat_px)
        t = ((diffuse - fill) @ g) / float(g @ g)
        diffuse = np.where(sat_px[..., None], np.clip(diffuse - t[..., None] * g, 0.0, ic), diffuse)
    info = {"illuminant": [float(x) for x in g], "illuminant_source": source,
            "efficiency": [float(x) for x in eff], "residual_ratio": ratio, "residual_ratio_source": ratio_source,
            "polarized_floor": floor}
    if est is not None:
        info["polarized_colour"] = [float(x) for x in est.polarized]
    # never more than was measured (declipping raises Ic where samples were clipped): lowered by the
    # least multiple of the one specular colour that brings every channel under the measurement
    over = ((diffuse - measured) / g).max(axis=-1)
    diffuse = np.clip(diffuse - np.maximum(over, 0.0)[..., None] * g, 0.0, measured)
    return diffuse.astype(np.float32), info


def _specular_free(image: np.ndarray, smooth: float) -> np.ndarray:
    """Shen & Zheng's (2013) specular-free image, its clusters' intensity ratios smoothed in the image.

    ``image`` is (H, W, 3) float64 in [0, 1]; returns (H, W, 3) float32 in [0, image].  Each
    cluster's ratio ``Q`` (:func:`polcam.separation.shen13.cluster_ratios`, the paper's defaults) is
    a constant of its material, but the hard clustering puts the pixels of one smoothly shaded,
    weakly coloured material on both sides of a cluster boundary, and two ratios side by side make
    blotches (seen on lmmse-1's pink candy).  So the ratio map is filtered with a joint bilateral
    filter (polcam.filters; Yang, Wang & Ahuja, ECCV 2010, filter a ratio the same way) guided by
    the image's mean over channels: spatial sigma ``smooth`` pixels, range sigma a tenth of the
    guide's maximum, so material edges of different brightness keep their own ratios.
    """
    from polcam.filters import joint_bilateral
    from polcam.separation.shen13 import cluster_ratios, ratio_specular

    q_map, _ = cluster_ratios(image)
    ok = np.isfinite(q_map)
    if ok.any():
        # on a grid f times coarser (f = smooth / 6, as the filter's own grid): the ratio map is
        # piecewise constant, and the filter's cost at full resolution was a second a frame
        h, w = ok.shape
        f = max(1, int(smooth // 6))
        size = (max(1, -(-w // f)), max(1, -(-h // f)))
        area = cv2.INTER_AREA
        wt = cv2.resize(ok.astype(np.float32), size, interpolation=area)
        qw = cv2.resize(np.where(ok, q_map, 0.0).astype(np.float32), size, interpolation=area)
        guide = cv2.resize(image.mean(axis=-1).astype(np.float32), size, interpolation=area)
        q_s = joint_bilateral(qw / np.maximum(wt, 1e-12), guide, sigma_spatial=float(smooth) / f,
                              sigma_range=0.1 * max(float(guide.max()), 1e-6), weights=wt)
        q_s = cv2.resize(np.asarray(q_s, np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
        q_map = np.where(ok, q_s.astype(np.float64), np.nan)
    return np.clip(image - ratio_specular(image, q_map)[..., None], 0.0, image).astype(np.float32)


def _mono(stack: np.ndarray, opts: dict[str, Any],
          keep: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Mono stacks: remove the polarized light, then k times the coherent polarized light.

    Without colour, k (the unpolarized / polarized ratio of the specular light) is chosen so that the
    diffuse layer ``Imin - k a`` carries as little of the highlights' spatial profile as possible:
    least squares of the gradients, ``k = <grad Imin, grad a> / <grad a, grad a>`` over the
    neighbourhood (docs/algorithm.md), clipped to [0, max_ratio].
    """
    s = np.asarray(stack, dtype=np.float32)
    h, w = s.shape[1:3]
    measured = s.mean(axis=0)
    if opts["declip"]:
        s = declipped(s[..., None])[..., 0]
    ic = s.mean(axis=0)
    q = 0.5 * (s[0] - s[2])
    u = 0.5 * (s[1] - s[3])
    isv = np.hypot(q, u)
    imin = np.maximum(ic - isv, 0.0)
    side = max(h, w)
    k_small = _odd(max(3.0, side / 200))
    a_coh = np.hypot(cv2.GaussianBlur(q, (k_small, k_small), 0), cv2.GaussianBlur(u, (k_small, k_small), 0))
    floor, a_eff, _, gate = _coherent_gate(a_coh, ic, k_small, float(opts["polarized_threshold"]))
    a_pix = (np.minimum(a_eff, isv) * gate).astype(np.float32)
    ratio = _gradient_ratio(imin, a_pix, float(opts["max_ratio"]))
    diffuse = np.clip(imin - ratio * a_pix, 0.0, np.minimum(imin, measured))
    if keep is not None:
        keep["imin"] = imin.astype(np.float32)
    return diffuse.astype(np.float32), {"residual_ratio": ratio, "polarized_floor": floor}


def _coherent_gate(a_coh: np.ndarray, lum: np.ndarray, k_small: int, threshold: float,
                   scale: float = 1.0) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Where coherent polarized light marks a highlight (colour and mono paths alike).

    ``a_coh`` (H, W) is the smoothed polarized amplitude (times ``scale``, the illuminant's mean
    for colour, it is in the units of ``lum``), ``lum`` (H, W) the intensity.  Returns the floor
    that noise leaves everywhere (the median of ``a_coh``), ``a_eff = max(a_coh - floor, 0)``,
    ``lum`` Gaussian-blurred over ``k_small``, and the gate: a ramp from ``threshold`` to twice it
    in the coherent degree of polarization ``scale a_eff / lum_s``, (H, W) in [0, 1].
    """
    floor = float(np.median(a_coh))
    a_eff = np.maximum(a_coh - floor, 0.0)
    lum_s = cv2.GaussianBlur(lum, (k_small, k_small), 0)
    dop = a_eff * scale / np.maximum(lum_s, 1e-6)
    return floor, a_eff, lum_s, np.clip((dop - threshold) / threshold, 0.0, 1.0)


def _gradient_ratio(imin: np.ndarray, a_pix: np.ndarray, max_ratio: float) -> float:
    """k that removes the highlights' spatial profile from ``imin - k a_pix`` (both (H, W)).

    k minimises the total variation of ``Imin - k a`` along a's gradients: the weighted median of the
    gradient ratios ``grad Imin / grad a`` (x and y Sobel components, weights ``|grad a|``), over
    pixels inside highlights and away from dark regions (a silhouette is an edge of both), clipped
    to [0, max_ratio]; 0 with fewer than 20 such gradients.
    """
    gi = np.concatenate([cv2.Sobel(imin, cv2.CV_32F, 1, 0, ksize=3).ravel(),
                         cv2.Sobel(imin, cv2.CV_32F, 0, 1, ksize=3).ravel()])
    ga = np.concatenate([cv2.Sobel(a_pix, cv2.CV_32F, 1, 0, ksize=3).ravel(),
                         cv2.Sobel(a_pix, cv2.CV_32F, 0, 1, ksize=3).ravel()])
    inner = cv2.erode(((a_pix > 0) & (imin > 2.0 / 255)).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    use = (np.abs(ga) > 1e-4) & np.concatenate([inner.ravel(), inner.ravel()])
    if use.sum() < 20:
        return 0.0
    rr = gi[use] / ga[use]
    ww = np.abs(ga[use])
    order = np.argsort(rr)
    cw = np.cumsum(ww[order])
    return float(np.clip(rr[order][np.searchsorted(cw, 0.5 * cw[-1])], 0.0, max_ratio))
