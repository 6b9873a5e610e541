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
  filled from the neighbours' (inpainting) by a multiple of ``G``, in
  proportion to how much of the border is polarized highlight.  The colour
  prior does not act on any pixel clipped so: its colour is not measured.

One implementation for numpy and PyTorch: the array code runs over :mod:`polcam._xp`, the
neighbourhood filters are :mod:`polcam._imageops` (OpenCV for numpy, the same kernels on a torch
device); a ``torch.Tensor`` stack, or ``device=``, runs it on PyTorch (docs/algorithm.md,
"Backends").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.separation._clipping import declipped, fill_clipped_highlights
from polcam.separation._highlight import peak_excess
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
    "evidence": True,            # bound the removal by the pixel's rise above its surroundings (_highlight)
    "declip": True,              # rebuild clipped samples from the other angles (S0 identity, shared AoLP)
    "residual_model": "shen13",  # coloured pixels' residual: "shen13" (specular-free clustering) or "hue"
    "device": None,              # None: numpy and OpenCV; "cpu", "cuda", ...: PyTorch on that device (torch extra)
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
    for k in ("declip", "diffuse_polarization", "evidence"):
        if not isinstance(opts[k], (bool, np.bool_)):
            raise MethodError(f"polarized-residual: {k}={opts[k]!r}: expected True or False")
    if opts["noise"] not in ("off", "rice", "shrink", "thresh"):
        raise MethodError(f"polarized-residual: noise={opts['noise']!r}: expected 'off', 'rice', 'shrink' or 'thresh'")
    if opts["residual_model"] not in ("shen13", "hue"):
        raise MethodError(f"polarized-residual: residual_model={opts['residual_model']!r}: expected 'shen13' or 'hue'")
    hb = opts["hue_bins"]
    if isinstance(hb, bool) or not isinstance(hb, (int, np.integer)) or not 4 <= hb <= 360:
        raise MethodError(f"polarized-residual: hue_bins={hb!r}: expected an integer in [4, 360]")
    dev = opts["device"]
    if dev is not None:
        if not isinstance(dev, str):
            raise MethodError(f"polarized-residual: device={dev!r}: expected None (numpy) or a torch device name")
        from polcam.separation.tensor.torch_backend import check_device

        check_device(dev)
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
        (4, H, W, 3) float in [0, 1], angles 0, 45, 90, 135 (or (4, H, W) mono): a numpy array,
        or a ``torch.Tensor``, computed on its device.
    **options
        See :data:`DEFAULTS`: ``device`` (None: numpy and OpenCV; a torch device name such as
        ``"cuda"``: the same code on that device, the result back as numpy), ``illuminant`` (RGB or None), ``efficiency``
        ((3,) per-colour polarizer efficiency in (0, 1] or None),
        ``diffuse_polarization`` (keep a perpendicular polarized diffuse part), ``noise`` (how the
        polarized amplitude's noise bias is removed; unless "off", the colour prior's removal is
        shrunk by the noise too), ``declip`` (rebuild clipped samples),
        ``context``, ``hue_bins``, ``min_saturation``, ``polarized_threshold``.

    Returns
    -------
    diffuse : numpy.ndarray or torch.Tensor
        (H, W, 3) (or (H, W)) float32 in [0, mean over angles]; a tensor for a tensor stack.
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


def _separate(stack: Any, options: dict[str, Any],
              keep: dict[str, Any] | None) -> tuple[Any, dict[str, Any]]:
    """:func:`separate_polarized_residual`; with ``keep`` (a dict), the step layers go into it."""
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise MethodError(f"polarized-residual: unknown option(s) {', '.join(sorted(unknown))}")
    opts = {**DEFAULTS, **options}
    _check(opts)
    s, host = _on_device(stack, opts["device"])
    if s.ndim == 3 and s.shape[0] == 4:
        diffuse, info = _mono(s, opts, keep)
    elif s.ndim != 4 or s.shape[0] != 4 or s.shape[-1] != 3:
        raise MethodError(f"polarized-residual: stack of shape {tuple(s.shape)}: expected (4, H, W, 3) or (4, H, W)")
    else:
        diffuse, info = _colour(s, opts, keep)
    if host:
        xp = namespace(s)
        diffuse = xp.to_numpy(diffuse)
        if keep is not None:
            for k in keep:
                keep[k] = xp.to_numpy(keep[k])
    return diffuse, info


def _on_device(stack: Any, device: str | None) -> tuple[Any, bool]:
    """The stack as float32 where it is computed, and whether the result goes back to numpy.

    A ``torch.Tensor`` is computed on its own device (and the result stays there); a numpy array
    with ``device`` set is copied to that torch device and the result comes back as numpy.
    """
    if namespace(stack).name == "torch":
        return stack.to(namespace(stack).float32), False
    s = np.asarray(stack, dtype=np.float32)
    if device is None:
        return s, False
    import torch

    return torch.as_tensor(np.ascontiguousarray(s), device=torch.device(device)), True


def _colour(s: Any, opts: dict[str, Any], keep: dict[str, Any] | None) -> tuple[Any, dict[str, Any]]:
    """The colour path of :func:`_separate` on a (4, H, W, 3) float32 stack (numpy or torch)."""
    xp = namespace(s)
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
    gx = xp.asarray(g, like=s)                              # the same (3,) float32 where the stack is
    if not np.all(eff == 1):
        effx = xp.asarray(eff.astype(np.float32), like=s)
        q = q / effx
        u = u / effx
    sig = _stokes_noise(s, ic)

    # 1. coherent polarization: Stokes components smoothed over a few pixels (demosaicing and noise
    #    leave polarization of alternating sign that this cancels; a highlight's is coherent); their
    #    common axis and the signed amplitude of every channel along it
    side = max(h, w)
    k_small = _odd(max(3.0, side / 200))
    qs = _imageops.gaussian(q, k_small)
    us = _imageops.gaussian(u, k_small)
    qq = (qs / gx).sum(axis=-1)
    uu = (us / gx).sum(axis=-1)
    nn = xp.hypot(qq, uu)
    safe = nn > 0
    c2 = xp.where(safe, qq / xp.where(safe, nn, 1.0), 1.0)[..., None]
    s2 = xp.where(safe, uu / xp.where(safe, nn, 1.0), 0.0)[..., None]
    amp = qs * c2 + us * s2                                 # (H, W, 3) signed
    amp_px = q * c2 + u * s2                                # the same, unsmoothed (the pixel's own colours)
    # the polarized amplitude with the noise's bias removed: unbiased along the axis where the smoothed
    # amplitude fixes it, shrunk by the noise elsewhere (_polarization_noise._axis_debias)
    if opts["noise"] == "off":
        isv = xp.hypot(q, u)
    else:
        isv = _axis_debias(q, u, c2, s2, amp, sig, _reduction(k_small), opts["noise"])
    imin = xp.maximum(ic - isv, 0.0)
    # in units of G: the G-normalised channel sum is 3 a for a G-coloured polarized specular, while
    # colour demosaicing's polarization errors differ between channels and partly cancel in it
    a_coh = xp.astype(nn / 3.0, xp.float32)

    # 2. polarized specular light: the least multiple a of G that covers every channel's amplitude
    #    (so diffuse <= Imin with one specular colour); where the amplitudes are better explained by
    #    A = alpha G + beta e with alpha, beta of opposite signs (a diffuse part of colour e polarized
    #    perpendicular to the specular), the specular part is |alpha| G and the diffuse keeps |beta| e.
    gg = float(g @ g)
    amp_g = amp @ gx
    along = amp_g / gg
    cover = xp.amax(isv / gx, axis=-1)
    esum = imin.sum(axis=-1, keepdims=True)
    e = xp.where(esum > 1e-6, imin / xp.maximum(esum, 1e-6), gx / g.sum())
    a = xp.astype(cover, xp.float32)
    b = xp.zeros(a.shape, like=a)
    if opts["diffuse_polarization"]:
        off = xp.vnorm(amp - along[..., None] * gx, axis=-1)   # what G alone leaves unexplained
        noise = float(xp.median(off))
        ge = e @ gx
        ee = (e * e).sum(axis=-1)
        det = gg * ee - ge * ge
        well = det > (0.2 ** 2) * gg * ee                  # e far from G's colour (sin > 0.2)
        # the decomposition from the pixel's own amplitudes: smoothing mixes the colours of neighbouring
        # pixels, which near occluding contours (where diffuse polarization is strongest) differ most
        dsafe = xp.where(well, det, 1.0)

        def fit(xg: Any, xe: Any) -> tuple[Any, Any, Any]:
            # per pixel, least squares x = alpha G + beta e from x.G and x.e; and whether the diffuse
            # colour's term dominates, |beta| |e| > |alpha| |G|
            al = (ee * xg - ge * xe) / dsafe
            be = (gg * xe - ge * xg) / dsafe
            return al, be, abs(be) * xp.sqrt(ee) > abs(al) * np.sqrt(gg)

        ga = amp_px @ gx
        al, be, dom = fit(ga, (amp_px * e).sum(axis=-1))
        # significant: beyond five times the typical misfit, 1/255 and 1 % of the pixel's intensity
        sig_off = off > 5.0 * noise + xp.maximum(0.01 * xp.vnorm(ic, axis=-1), 1.0 / 255)
        # and explained: what G leaves of the pixel's amplitudes lies along its own body colour e (the
        # two-colour fit leaves under _DIFFUSE_FIT of it); demosaicing's false polarization (one
        # channel's interpolation error, a neighbour's colour at an edge) points elsewhere
        off_px = xp.vnorm(amp_px - (ga / gg)[..., None] * gx, axis=-1)
        misfit = xp.vnorm(amp_px - al[..., None] * gx - be[..., None] * e, axis=-1)
        sig_off &= misfit < _DIFFUSE_FIT * off_px
        # also where the diffuse colour's term dominates the amplitudes (dom: a polarized diffuse part
        # with little or no specular light, e.g. near occluding contours): only a G term of the opposite
        # sign (perpendicular AoLP) is specular there, so the polarized diffuse light is kept
        # and physically possible: a diffuse surface's degree of polarization stays below 0.5 (Atkinson &
        # Hancock 2006: at most ~0.53 at grazing view for n = 1.8); a larger |beta| e comes from a misfit
        # (opposite-signed alpha and beta cancelling each other on strongly polarized highlights)
        a_c = xp.where(al * be < 0, abs(al), 0.0)
        plaus = (abs(be)[..., None] * e
                 <= _MAX_DIFFUSE_DOLP * xp.maximum(ic - a_c[..., None] * gx, 0.0) + 1.0 / 255).all(axis=-1)
        take = well & sig_off & ((al * be < 0) | dom) & plaus
        a = xp.astype(xp.where(take, xp.where(al * be < 0, abs(al), 0.0), a), xp.float32)
        b = xp.astype(xp.where(take, abs(be), 0.0), xp.float32)
        # for step 3, only the specular part marks a highlight: where the smoothed amplitudes' diffuse-
        # colour term dominates and what G leaves of them is beyond _COHERENT_KSIG of its noise (a
        # surface's own coherent polarized light, as near occluding contours), the G term |alpha| alone
        # counts
        al_s, _, dom_s = fit(amp_g, (amp * e).sum(axis=-1))
        own = well & dom_s & (off > _COHERENT_KSIG * _reduction(k_small) * xp.sqrt((sig * sig).sum(axis=-1)))
        a_coh = xp.astype(xp.where(own, xp.minimum(abs(al_s), a_coh), a_coh), xp.float32)
    ub = xp.minimum(imin + b[..., None] * e, ic)            # diffuse <= Imin (+ its own polarized part)
    # the bound is met by more of the one specular colour, not by clipping channels one by one (which
    # would give the specular layer the colours of the channels' polarization errors)
    a = xp.maximum(a, xp.amax((ic - ub) / gx, axis=-1))
    a = xp.minimum(a, xp.amin(ic / gx, axis=-1))            # one specular colour: never more than the pixel has
    resid = xp.clip(ic - a[..., None] * gx, 0.0, ub)        # polarized specular light removed
    if keep is not None:
        keep.update(imin=xp.astype(imin, xp.float32), polarized_removed=xp.astype(resid, xp.float32))

    # 3. where coherent polarized specular light is (highlights; a_coh is specular only, step 2)
    lum = ic.mean(axis=-1)
    floor, a_eff, lum_s, gate = _coherent_gate(a_coh, lum, k_small, float(opts["polarized_threshold"]),
                                               float(g.mean()))
    spec = a_eff * float(g.mean()) > xp.maximum(opts["polarized_threshold"] * lum_s, 1.0 / 255)
    k_ctx = _odd(opts["context"] * side)

    # 4. hue and saturation of the residual around the illuminant point of the chromaticity plane
    rsum = resid.sum(axis=-1)
    lit = rsum > 3.0 / 255
    chroma = resid / xp.maximum(rsum, 1e-6)[..., None]
    v = (chroma - gx / g.sum()) @ xp.asarray(_plane_basis().T.astype(np.float32), like=s)  # (H, W, 2)
    sat = xp.astype(xp.hypot(v[..., 0], v[..., 1]), xp.float32)
    sat = xp.astype(xp.where(lit, sat, 0.0), xp.float32)
    hue = xp.arctan2(v[..., 1], v[..., 0])
    nb = int(opts["hue_bins"])
    hbin = xp.astype(xp.floor((hue + np.pi) / (2 * np.pi) * nb), xp.index) % nb
    # median filters: robust to colour noise without mixing the colours of neighbouring materials
    big = min(h, w) >= 5
    sat_m = _imageops.median(sat, 5) if big else sat
    sat = _imageops.median(sat, 3) if big else sat
    sat_d = xp.zeros(sat.shape, like=sat)
    per_bin = []
    for k in range(nb):
        # only lit pixels lend their saturation to a hue: an unlit pixel's hue is that of rounding
        # noise (its residual is ~1e-11), while the median filters give it its lit neighbours'
        # saturation; a change of 1e-7 in the input moved it to another hue and moved the diffuse
        # of a whole neighbourhood by up to 0.17 (docs/algorithm.md, ninth round)
        m = (hbin == k) & lit
        per_bin.append(_imageops.dilate(xp.astype(xp.where(m, sat_m, 0.0), xp.float32), k_ctx)
                       if bool(m.any()) else None)
    for k in range(nb):
        m = hbin == k
        if not bool(m.any()):
            continue
        best = xp.zeros((int(m.sum()),), like=sat)
        for j in (k - 1, k, k + 1):   # neighbouring hues too: noise moves a pixel's hue a little
            pb = per_bin[j % nb]
            if pb is not None:
                best = xp.maximum(best, pb[m])
        sat_d[m] = best
    coloured = (sat_d > opts["min_saturation"]) & (sat > 0.5 * opts["min_saturation"]) & lit
    share_spec = xp.where(coloured, 1.0 - xp.clip(sat / xp.maximum(sat_d, 1e-6), 0.0, 1.0), 0.0)
    r_col = share_spec * rsum / float(g.sum())              # residual specular, in units of G

    # 5. the unpolarized residual is k times the polarized specular light, with k (the Fresnel ratio
    #    (1 - rho_s) / rho_s) measured on coloured highlights and smoothed over the neighbourhood:
    #    achromatic pixels take the k of the coloured highlights around them (or of the image)
    a_pix = xp.minimum(a_eff, a)                            # coherent, and no more than the pixel's own
    # only where coherent polarized light marks a highlight (step 3's gate: weakly polarized white
    # surfaces stay diffuse)
    # not where a sample is clipped: that pixel's colour (and so its specular share) is not measured, and
    # a clipped channel makes the residual look paler, which overstated k
    rel = coloured & spec & (a_pix > 1.0 / 255) & ~clipped_any
    num_p = xp.astype(xp.where(rel, xp.minimum(r_col, float(opts["max_ratio"]) * a_pix), 0.0), xp.float32)
    den_p = xp.astype(xp.where(rel, a_pix, 0.0), xp.float32)
    if int(rel.sum()) >= 20:
        ratio = float(num_p.sum() / den_p.sum())
        ratio_source = "coloured highlights"
    else:  # no coloured highlight: the highlights' spatial profile decides (as for mono stacks)
        ratio = _gradient_ratio(xp.astype((imin / gx).mean(axis=-1), xp.float32),
                                xp.astype(a_pix * gate, xp.float32), float(opts["max_ratio"]))
        ratio_source = "gradients"
    num = _imageops.box(num_p, k_ctx, normalize=False)
    den = _imageops.box(den_p, k_ctx, normalize=False)
    k_loc = xp.where(den > 1e-3 * max(float(den.max()), 1e-12), num / xp.maximum(den, 1e-12), ratio)
    r = gate * k_loc * a_pix
    r = xp.minimum(r, xp.amin(resid / gx, axis=-1))         # diffuse >= 0 in every channel
    diffuse = xp.clip(resid - r[..., None] * gx, 0.0, ub)
    if keep is not None:
        keep["ratio_removed"] = xp.astype(diffuse, xp.float32)
    if opts["residual_model"] == "shen13":
        # coloured pixels: Shen & Zheng's (2013) specular-free clustering applied to the residual only,
        # in the illuminant-normalised space (where the residual specular light is white), never
        # above the residual; achromatic pixels keep the polarization-decided layer above (a ramp
        # over the locally averaged residual's saturation from min_saturation to twice it)
        norm = resid / gx
        peak = float(norm.max())
        if peak > 0:
            sf = _specular_free(xp.astype(xp.clip(norm / peak, 0.0, 1.0), xp.float64), 3 * k_small) * peak * gx
            sf = xp.clip(sf, 0.0, resid)
            ms = float(opts["min_saturation"])
            # the saturation of the locally averaged layer of step 5 (the specular light that polarization
            # measured already removed, so a highlight's white light does not make a coloured material
            # look achromatic): colour noise (demosaicing) averages out
            kw = _odd(3 * k_small)
            rb = _imageops.box(diffuse, kw)
            cb = rb / xp.maximum(rb.sum(axis=-1, keepdims=True), 1e-6) - gx / g.sum()
            sat_w = xp.vnorm(cb, axis=-1)
            wgt = xp.clip((sat_w - ms) / ms, 0.0, 1.0)
            # and only on coloured materials: the most saturated residual of the pixel's hue nearby
            # (step 4's sat_d, the material's body colour) ramps the prior in from min_saturation to
            # twice it, so a weakly coloured material is decided by polarization, not by colour
            wgt = wgt * xp.clip((sat_d - ms) / ms, 0.0, 1.0)
            if ratio_source == "coloured highlights":
                # near polarized highlights whose measured k is small, their specular light was almost
                # all polarized and step 2 removed it: the colour prior is weighted down there
                near = _imageops.box(xp.astype(gate, xp.float32), k_ctx)
                wgt = wgt * (1.0 - near * (1.0 - xp.clip(k_loc / _PRIOR_K, 0.0, 1.0)))
            # not where a channel is clipped at all four angles: that pixel's colour is not measured (an
            # overexposed white wall under a tinted light looked coloured and lost up to 38 % of its
            # light; docs/algorithm.md, tenth round); a clipped highlight is step 7's
            wgt = xp.where(xp.amax(measured, axis=-1) >= _SATURATED, 0.0, wgt)
            wgt = wgt[..., None]
            diffuse = diffuse - wgt * _prior_removal(diffuse, sf, sig if opts["noise"] != "off" else 0.0 * sig,
                                                     smooth=k_small)
    if keep is not None:
        keep["prior_removed"] = xp.astype(diffuse, xp.float32)
    # 7. highlight evidence: nothing is removed beyond the multiple of G by which the pixel rises
    #    above its surroundings' floor (_highlight.peak_excess)
    if opts["evidence"]:
        excess = peak_excess(ic, gx, window=k_ctx, smooth=5)
        diffuse = xp.maximum(diffuse, ic - excess[..., None] * gx)
    if keep is not None:
        keep["evidence_bounded"] = xp.astype(diffuse, xp.float32)
    diffuse, clip_stats = fill_clipped_highlights(diffuse, measured, spec, gx)
    info = {**clip_stats, "illuminant": [float(x) for x in g], "illuminant_source": source,
            "efficiency": [float(x) for x in eff], "residual_ratio": ratio, "residual_ratio_source": ratio_source,
            "polarized_floor": floor}
    if est is not None:
        info["polarized_colour"] = [float(x) for x in est.polarized]
    # never more than was measured (declipping raises Ic where samples were clipped): lowered by the
    # least multiple of the one specular colour that brings every channel under the measurement
    over = xp.amax((diffuse - measured) / gx, axis=-1)
    diffuse = xp.clip(diffuse - xp.maximum(over, 0.0)[..., None] * gx, 0.0, measured)
    return xp.astype(diffuse, xp.float32), info


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
    from polcam.filters import joint_bilateral
    from polcam.separation.shen13 import cluster_ratios, ratio_specular

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


def _mono(stack: Any, opts: dict[str, Any], keep: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
    """Mono stacks: remove the polarized light, then k times the coherent polarized light.

    Without colour, k (the unpolarized / polarized ratio of the specular light) is chosen so that the
    diffuse layer ``Imin - k a`` carries as little of the highlights' spatial profile as possible:
    least squares of the gradients, ``k = <grad Imin, grad a> / <grad a, grad a>`` over the
    neighbourhood (docs/algorithm.md), clipped to [0, max_ratio].  ``stack`` is (4, H, W) float32,
    numpy or torch.
    """
    xp = namespace(stack)
    s = stack
    h, w = s.shape[1:3]
    measured = s.mean(axis=0)
    if opts["declip"]:
        s = declipped(s[..., None])[..., 0]
    ic = s.mean(axis=0)
    q = 0.5 * (s[0] - s[2])
    u = 0.5 * (s[1] - s[3])
    isv = xp.hypot(q, u)
    imin = xp.maximum(ic - isv, 0.0)
    side = max(h, w)
    k_small = _odd(max(3.0, side / 200))
    a_coh = xp.hypot(_imageops.gaussian(q, k_small), _imageops.gaussian(u, k_small))
    floor, a_eff, _, gate = _coherent_gate(a_coh, ic, k_small, float(opts["polarized_threshold"]))
    a_pix = xp.astype(xp.minimum(a_eff, isv) * gate, xp.float32)
    ratio = _gradient_ratio(imin, a_pix, float(opts["max_ratio"]))
    diffuse = xp.clip(imin - ratio * a_pix, 0.0, xp.minimum(imin, measured))
    if keep is not None:
        keep["imin"] = xp.astype(imin, xp.float32)
    return xp.astype(diffuse, xp.float32), {"residual_ratio": ratio, "polarized_floor": floor}


def _coherent_gate(a_coh: Any, lum: Any, k_small: int, threshold: float,
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


def _gradient_ratio(imin: Any, a_pix: Any, max_ratio: float) -> float:
    """k that removes the highlights' spatial profile from ``imin - k a_pix`` (both (H, W)).

    k minimises the total variation of ``Imin - k a`` along a's gradients: the weighted median of the
    gradient ratios ``grad Imin / grad a`` (x and y Sobel components, weights ``|grad a|``), over
    pixels inside highlights and away from dark regions (a silhouette is an edge of both), clipped
    to [0, max_ratio]; 0 with fewer than 20 such gradients.
    """
    xp = namespace(imin)
    gi = xp.concatenate([_imageops.sobel(imin, 1, 0).reshape(-1), _imageops.sobel(imin, 0, 1).reshape(-1)])
    ga = xp.concatenate([_imageops.sobel(a_pix, 1, 0).reshape(-1), _imageops.sobel(a_pix, 0, 1).reshape(-1)])
    inner = _imageops.erode(xp.astype((a_pix > 0) & (imin > 2.0 / 255), xp.float32), 5) > 0
    use = (abs(ga) > 1e-4) & xp.concatenate([inner.reshape(-1), inner.reshape(-1)])
    if int(use.sum()) < 20:
        return 0.0
    rr = gi[use] / ga[use]
    ww = abs(ga[use])
    order = xp.argsort(rr)
    cw = xp.cumsum(ww[order])
    return float(np.clip(float(rr[order][xp.searchsorted(cw, 0.5 * cw[-1])]), 0.0, max_ratio))
