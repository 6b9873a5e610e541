"""The unpolarized specular light left in the diffuse, estimated by a small learned model.

A specular reflection is partly polarized: of its light ``s G`` the polarization sinusoid shows
``rho_s s G``, which polarized-residual removes, and ``(1 - rho_s) s G`` stays in the diffuse
layer.  ``rho_s`` is the Fresnel degree of polarization at the incidence angle (and the refractive
index), which one pixel does not show; no single ratio fits every highlight (on the randomized
family's validation scenes the true unpolarized / polarized ratio ranges over 0 to 24).  What does
show it is local: how far the pixel rises above its neighbourhood, how close its colour is to
``G`` against the colour around it and against the least white pixel near it (a body colour's
own whiteness: a pixel paler than its material holds light of ``G``'s colour; Tan & Ikeuchi
2005), how much polarized light was removed there and whether that light crosses the edges
(specular) or follows them (diffuse, at rims).

This stage maps those local measures (:func:`features`, 34 per pixel, ratios free of the exposure
but for the measured level) to the share of the light it may remove, along ``G``, that is
unpolarized specular:

    s = b * clip(z, 0, 1),    z = MLP(x),
    b = min(min_c D_c / G_c, max(e, r p)),    e = the rise of the pixel above its surroundings' floor,
    D' = D - s G,                             p = the coherent polarized light at the pixel,

inside the neighbourhood of coherent polarized light (the highlight gate of
:func:`polcam.separation._residual.highlight_mask`, dilated; a pixel with a blind channel only on the
gate itself, :func:`zone`) and off the pixels whose every channel is blind; nothing is removed
elsewhere.  ``e`` (:func:`polcam.separation._highlight.peak_excess`, in units of ``G``, the
floor the larger of the opening and the lower-quartile rank opening over a square of
:data:`EVIDENCE_WINDOW` of the larger side) is the evidence of a
highlight at the place: a uniform matte patch does not rise above itself, so it is never thinned.
``r p`` (:data:`POLARIZED_RATIO`) is the other evidence, the highlight's own polarization: a broad
highlight that covers its surroundings does not rise above them, but its polarized part is seen
(polarized-residual's ``evidence=True`` leaves it out: the rise alone bounds the removal).
The removal is one multiple of ``G`` per pixel (the layer keeps one specular colour) and never more
than the layer holds, in every channel: a blind channel (its mean over the four angles at the
white level, which shows neither its level nor its polarization) loses the same multiple, as in
polarized-residual's step 4, and so keeps the least value its measurement allows.  A pixel whose
every channel is blind shows nothing; polarized-residual's clipped fill treats it.

A mono stack (run as a grey colour stack, ``G = (1, 1, 1)``) shows no colour: every surface is of
``G``'s colour, so a pale matte patch rises above its surroundings as a highlight does and the
whiteness measures cannot tell them apart.  There the bound is the polarized light alone,
``b = min(min_c D_c / G_c, r p)`` (:func:`removal_bound`'s ``"polarized"``), and the model's weights
are their own (:data:`MONO_WEIGHTS_FILE`, trained on the family's mono camera): with the colour
weights and the rise bound the stage cost the family's matte mono scenes 1.2 dB
(docs/decisions/mono-learned-stage.md).

The MLP (34 -> 24 -> 24 -> 1, tanh) is trained by ``polcam bench train-residual``
(:mod:`polcam.bench.residual_training`) on the randomized scene family's training seeds only
(:func:`polcam.synth.family.training_seeds`, disjoint from validation and test), whose albedo
photographs are public domain or CC0, so the weights ship.  Kernel sizes are shares of the image's
larger side (as trained at 128 pixels), so a larger frame sees the same neighbourhoods; above twice
that side the blurs run on the image shrunk to about the training resolution (:func:`_blur`).

One implementation for numpy and PyTorch (:mod:`polcam._xp`, :mod:`polcam._imageops`).
"""

from __future__ import annotations

import json
from functools import lru_cache, partial
from pathlib import Path
from typing import Any

import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.separation._common import max3, min3, sum3
from polcam.separation._highlight import EVIDENCE_MEDIAN, peak_excess

__all__ = ["WEIGHTS_FILE", "MONO_WEIGHTS_FILE", "BOUND_EVIDENCE", "TRAIN_SIDE", "FEATURES", "EVIDENCE_WINDOW",
           "POLARIZED_RATIO", "removal_bound", "features", "zone", "apply", "forward", "load_weights", "stage_inputs"]

#: The shipped weights for colour stacks (made by ``polcam bench train-residual``).
WEIGHTS_FILE = Path(__file__).with_name("residual_weights.npz")
#: The shipped weights for mono stacks (``polcam bench train-residual --camera mono``).
MONO_WEIGHTS_FILE = Path(__file__).with_name("residual_weights_mono.npz")
#: How :func:`removal_bound` combines its two evidences: the rise above the surroundings ``e`` and the
#: polarized light ``r p``.
BOUND_EVIDENCE = ("either", "rise", "polarized", "both")
#: The scenes' side the model is trained at; kernel sizes below are in pixels at this side.
TRAIN_SIDE = 128
#: Smallest light (in units of ``G``) a ratio is divided by: under one 12-bit code value (1/4095).
_EPS = 1e-4
#: The features, in order (names stored with the weights and checked when they load).
FEATURES = (
    "removed/L", "smax/L", "white", "diffuse_white", "dolp", "gate", "gate@13", "gate@37",
    "a_eff/L", "share", "measured_max",
    "P", "P_pixel", "coherence", "coherent_dolp", "P*gate@19", "P*gate@49", "P@49",
    "log L/L@9", "log removed@9/L", "white@9-white",
    "log L/L@25", "log removed@25/L", "white@25-white",
    "log L/L@61", "log removed@61/L", "white@61-white",
    "log L/max5", "log min5/L", "log L/max15", "log min15/L", "bound/L",
    "white-minwhite15", "white-minwhite37",
)
#: Pixels per block of the model's evaluation (its hidden layers stay in the cache).
_CHUNK = 16384
#: The side of the square the highlight gate is dilated by: where the stage acts.
_ZONE = 9
#: Side of the surroundings (share of the image's larger side) above whose floor a pixel must rise for
#: light to be removed there: a highlight is a peak over its own material.  A sweep on the validation
#: split, for the model trained without the bound (0.06: 27.35 dB, 0.12: 27.37, 0.25: 27.50, none:
#: 27.54), against the matte grey checker of tests/separation/test_polarized_residual_physics.py
#: (0.25 and none keep under 0.98 of its light); 0.12 is also polarized-residual's ``context``.
EVIDENCE_WINDOW = 0.12
#: The unpolarized specular light allowed per unit of the polarized light seen at the pixel,
#: ``(1 - rho_s) / rho_s`` at a specular DoLP ``rho_s`` of 0.5 (Fresnel: above 0.5 from about 35 to 75
#: degrees of incidence for n = 1.5); nearer normal incidence only the rise above the surroundings
#: bounds it.  A sweep on the first 400 validation scenes with 150 training scenes (none: 27.92 dB,
#: best or within 0.3 dB 82 %; 1: 28.13, 85 %; 2: 28.13, 84 %; 4: 28.14, 84 %) against the matte grey
#: checker of tests/separation/test_polarized_residual_physics.py, which false polarization at its
#: edges makes keep under 0.98 of its light from 2 on (1: 0.981 and 0.986).  With the shipped weights
#: 2 keeps the checker but thins a one-pixel contour of polarized diffuse light beside a highlight and
#: gains nothing on the test split (docs/decisions/learned-unpolarized-specular.md, "Still r = 1").
POLARIZED_RATIO = 1.0


def _k(px: int, side: int) -> int:
    """A kernel of ``px`` pixels at :data:`TRAIN_SIDE`, scaled to an image of larger side ``side`` (odd, >= 3)."""
    k = max(int(round(px * side / TRAIN_SIDE)), 3)
    return k if k % 2 else k + 1


def _blur(a: Any, px: int, side: int) -> Any:
    """A Gaussian blur over ``px`` pixels at :data:`TRAIN_SIDE`, for an image of larger side ``side``.

    At up to twice the training side, the ``k x k`` Gaussian with ``k`` scaled to the image; above,
    the same blur at the training resolution: the image shrunk by the integer factor
    ``side // TRAIN_SIDE`` (area), blurred with the training kernel, and brought back (bilinear), so
    a wide neighbourhood costs what it costs at 128 pixels.
    """
    f = side // TRAIN_SIDE
    if f < 2:
        return _imageops.gaussian(a, _k(px, side))
    return _imageops.shrunk(a, f, lambda small: _imageops.gaussian(small, _k(px, side // f)))


def _gather(a: Any, idx: Any) -> Any:
    """``a.reshape(H * W, ...)[idx]`` for an (H, W) or (H, W, 3) array and flat pixel indices ``idx``."""
    return namespace(a).take(a.reshape((-1,) + tuple(a.shape[2:])), idx, 0)


def removal_bound(diffuse: Any, ic: Any, gx: Any, side: int, polarized: Any, *, evidence: str = "either") -> Any:
    """The most the stage may remove, in units of ``G``: ``b = min(min_c D_c / G_c, E)``, (H, W) float32 >= 0.

    ``e`` is the rise of ``ic`` (H, W, 3) above its surroundings' floor
    (:func:`polcam.separation._highlight.peak_excess`, the floor of its openings over a square of
    :data:`EVIDENCE_WINDOW` of the larger side ``side``); ``p`` (H, W) the coherent polarized light
    at the pixel in units of ``G`` (the highlight gate times its amplitude over the noise floor) and
    ``r`` :data:`POLARIZED_RATIO`: where a highlight's polarization is seen, its unpolarized part may
    be up to ``r`` times it, however broad the highlight.  ``evidence`` (:data:`BOUND_EVIDENCE`) says
    which bounds: ``E = max(e, r p)`` (``"either"``, colour stacks), ``e`` (``"rise"``, colour
    stacks with ``evidence=True``), ``r p`` (``"polarized"``, mono stacks) or ``min(e, r p)``
    (``"both"``, mono stacks with ``evidence=True``).  Without colour a rise does not tell a pale
    matte surface from a highlight (every surface is of ``G``'s colour), so a mono stack's removal
    needs polarized light at the pixel.
    """
    if evidence not in BOUND_EVIDENCE:
        raise ValueError(f"evidence={evidence!r}: expected one of {', '.join(BOUND_EVIDENCE)}")
    xp = namespace(diffuse)
    smax = xp.maximum(min3(diffuse / gx), 0.0)
    seen = POLARIZED_RATIO * polarized
    if evidence == "polarized":
        return xp.astype(xp.minimum(smax, seen), xp.float32)
    rise = peak_excess(ic, gx, window=_k(EVIDENCE_WINDOW * TRAIN_SIDE, side), smooth=EVIDENCE_MEDIAN)
    bound = {"either": xp.maximum(rise, seen), "rise": rise, "both": xp.minimum(rise, seen)}[evidence]
    return xp.astype(xp.minimum(smax, bound), xp.float32)


def features(diffuse: Any, v: dict[str, Any], gx: Any, gate: Any, a_eff: Any, share: float,
             axis: tuple[Any, Any, Any], measured: Any, bound: Any, where: Any) -> Any:
    """The per-pixel measures the model reads, at the ``where`` pixels.

    Parameters
    ----------
    diffuse
        (H, W, 3) the layer so far (polarized light removed, clipped regions treated).
    v
        The quantities of polarized-residual's step 2: ``ic``, ``imin``, ``q``, ``u`` (H, W, 3),
        ``qq``, ``uu`` (H, W) and ``side``.
    gx
        (3,) the illuminant's colour ``G`` (mean 1), where the arrays are.
    gate, a_eff
        (H, W): the highlight gate in [0, 1] and the coherent polarized amplitude over its floor.
    share
        The image's diffuse-like share in [0, 1].
    axis
        The structure tensor's ``(cos 2 psi, sin 2 psi, coherence)``, each (H, W).
    measured
        (H, W, 3) the mean over the four angles as measured.
    bound
        (H, W) :func:`removal_bound`.
    where
        (H, W) bool: the pixels whose features are wanted (:func:`zone`).

    Returns
    -------
    x : array
        (N, 34) float32, the ``where`` pixels in row-major order, :data:`FEATURES` in order: ratios
        and logs of ratios (free of the exposure) and the measured level.
        Neighbourhood measures are computed over the whole image, the pixel's own only where
        wanted.
    """
    xp = namespace(diffuse)
    side = int(v["side"])
    ic = v["ic"]
    gsq = float((gx * gx).sum())
    c2, s2, coh = axis
    # whole-image maps that neighbourhood measures read
    icg = ic / gx
    light = xp.maximum(sum3(icg) / 3.0, _EPS)
    removed = sum3((ic - diffuse) * gx) / gsq
    white = min3(icg) / light
    nn = xp.maximum(xp.hypot(v["qq"], v["uu"]), 1e-6)
    along = (v["qq"] * c2 + v["uu"] * s2) / nn * coh

    at = partial(_gather, idx=xp.nonzero(where.reshape(-1))[0])   # ``a[where]``, by index: a mask is slower

    def g(a: Any, px: int) -> Any:
        return at(_blur(a, px, side))

    # the pixel's own measures, where wanted
    lw, ww = at(light), at(white)
    dw = at(diffuse) / gx
    dmin = min3(dw)
    icw = at(ic)
    qs = sum3(at(v["q"]) / gx)
    us = sum3(at(v["u"]) / gx)
    c2w, s2w = at(c2), at(s2)
    mmax = max3(at(measured))
    f = [at(removed) / lw, xp.maximum(dmin, 0.0) / lw, ww,
         dmin / xp.maximum(sum3(dw) / 3.0, _EPS),
         xp.clip(sum3(icw - at(v["imin"])) / xp.maximum(sum3(icw), _EPS), 0.0, 1.0),
         at(gate), g(gate, 13), g(gate, 37),
         at(a_eff) * float(gx.mean()) / lw, xp.zeros(lw.shape, like=lw) + float(share),
         mmax,
         at(along), (qs * c2w + us * s2w) / xp.maximum(xp.hypot(qs, us), 1e-6), at(coh), at(nn) / 3.0 / lw,
         g(along * gate, 19), g(along * gate, 49), g(along, 49)]
    f += _neighbourhood(light, removed, white, bound, at, lw, ww, side)
    # (F, N) rows copied whole, then seen as (N, F): matrix products read the transpose in place
    return xp.stack([xp.astype(a, xp.float32) for a in f], axis=0).T


def _neighbourhood(light: Any, removed: Any, white: Any, bound: Any, at: Any, lw: Any, ww: Any,
                   side: int) -> list[Any]:
    """The last 16 of :data:`FEATURES`, at the wanted pixels (``at`` gathers them from an (H, W) map;
    ``lw``, ``ww`` are ``light`` and ``white`` gathered already).

    The pixel's level, removal and whiteness against their blurs over 9, 25 and 61 pixels (at
    :data:`TRAIN_SIDE`); its level against the local maximum and minimum over 5 and 15; the bound;
    its whiteness less the least whiteness within 15 and 37 pixels: where that pixel is the same
    material unlit by the highlight, how much paler than its body colour the pixel is, which only
    light of ``G``'s colour makes it (the maximum chromaticity of Tan & Ikeuchi 2005).
    """
    xp = namespace(light)
    f = []
    for px in (9, 25, 61):
        f.append(xp.log(lw / xp.maximum(at(_blur(light, px, side)), _EPS)))
        f.append(xp.log(xp.maximum(at(_blur(removed, px, side)), 0.0) / lw + 1e-3))
        f.append(at(_blur(white, px, side)) - ww)
    for px in (5, 15):
        k = _k(px, side)
        f.append(xp.log(lw / xp.maximum(at(_imageops.dilate(light, k)), _EPS)))
        f.append(xp.log(xp.maximum(at(_imageops.erode(light, k)), _EPS) / lw))
    f.append(at(bound) / lw)
    for px in (15, 37):
        f.append(ww - at(_imageops.erode(white, _k(px, side))))
    return f


def zone(gate: Any, blind: Any, side: int, bound: Any) -> Any:
    """(H, W) bool: where the stage may act.

    The highlight gate's support dilated by :data:`_ZONE` pixels (at :data:`TRAIN_SIDE`), less the
    pixels whose every channel is blind (``blind`` (H, W, 3) bool: a channel's mean over the four
    angles at the white level), the partly blind pixels off the gate itself, and those whose
    ``bound`` (:func:`removal_bound`) is 0, where nothing could be removed.  A blind channel hides
    the pixel's colour, which the model's whiteness measures then misread (without this condition a
    clipped matte white wall under a green-heavy light lost up to 5 % of its light); coherent
    polarized light at the pixel is the evidence of a highlight that colour cannot give there.
    """
    xp = namespace(gate)
    near = _imageops.dilate(xp.astype(gate > 0, xp.float32), _k(_ZONE, side)) > 0
    part = blind.any(axis=-1)
    return near & ~blind.all(axis=-1) & (~part | (gate > 0)) & (bound > 0)


def forward(x: Any, weights: dict[str, np.ndarray]) -> Any:
    """The MLP's output ``z`` (N,) for (N, F) features: normalised, tanh hidden layers, a linear head.

    The normalisation ``(x - mu) / sd`` is folded into the first layer's weights.
    """
    xp = namespace(x)
    mu, sd = np.asarray(weights["mu"], np.float64), np.asarray(weights["sd"], np.float64)
    w0 = np.asarray(weights["w0"], np.float64)
    folded = {"w0": w0 / sd[:, None], "b0": np.asarray(weights["b0"], np.float64) - (mu / sd) @ w0}
    n = int(weights["layers"])
    layers = [(xp.asarray(np.ascontiguousarray(np.asarray(folded.get(f"w{i}", weights[f"w{i}"]), np.float32).T),
                          like=x),
               xp.asarray(np.asarray(folded.get(f"b{i}", weights[f"b{i}"]), np.float32)[:, None], like=x))
              for i in range(n)]
    xt = x.T                                                 # (F, N): each layer a (out, in) @ (in, N) product
    total = xt.shape[1]
    if total == 0:
        return xp.zeros((0,), like=x)
    out = []
    for start in range(0, total, _CHUNK):                    # blocks that stay in the cache
        h = xt[:, start:start + _CHUNK]
        for i, (w, b) in enumerate(layers):
            h = w @ h
            h += b
            if i < n - 1:
                h = xp.tanh(h)
        out.append(h[0])
    return xp.concatenate(out) if len(out) != 1 else out[0]


def apply(diffuse: Any, x: Any, bound: Any, where: Any, gx: Any, weights: dict[str, np.ndarray]) -> tuple[Any, Any]:
    """``D - s G`` with ``s = bound clip(z, 0, 1)`` where ``where`` (H, W) holds, 0 elsewhere; and ``s``.

    ``x`` holds the features of the ``where`` pixels ((N, F), :func:`features` given ``where``).
    """
    xp = namespace(diffuse)
    idx = xp.nonzero(where.reshape(-1))[0]
    flat = bound.reshape(-1)
    s = xp.zeros(flat.shape, like=bound)
    s[idx] = xp.take(flat, idx, 0) * xp.clip(forward(x, weights), 0.0, 1.0)
    s = s.reshape(bound.shape)
    return xp.maximum(diffuse - s[..., None] * gx, 0.0), s


@lru_cache(maxsize=4)
def _load(path: str) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            w = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise MethodError(f"polarized-residual: learned-residual weights {path}: unreadable ({e}); "
                          "remake them with `polcam bench train-residual`") from e
    names = tuple(json.loads(str(w.get("features", np.array("[]")))))
    if names != FEATURES:
        raise MethodError(f"polarized-residual: learned-residual weights {path}: features {list(names)[:3]}... "
                          f"do not match this polcam's {len(FEATURES)} features; remake them with "
                          "`polcam bench train-residual`")
    n = int(w["layers"])
    if w["mu"].shape != (len(FEATURES),) or w[f"w{n - 1}"].shape[1] != 1:
        raise MethodError(f"polarized-residual: learned-residual weights {path}: shapes "
                          f"{w['mu'].shape} / {w[f'w{n - 1}'].shape}: expected ({len(FEATURES)},) inputs, one output")
    for k in w:
        if w[k].dtype.kind == "f":
            w[k] = w[k].astype(np.float32)
    return w


def load_weights(path: str | Path | None = None, *, mono: bool = False) -> dict[str, np.ndarray]:
    """The model's arrays (``layers``, ``mu``, ``sd``, ``w0``, ``b0``, ...): of ``path``, or the
    shipped file (:data:`WEIGHTS_FILE`, or with ``mono`` :data:`MONO_WEIGHTS_FILE`)."""
    if path is None:
        path = MONO_WEIGHTS_FILE if mono else WEIGHTS_FILE
    return _load(str(Path(path)))


def stage_inputs(diffuse: Any, v: dict[str, Any], gx: Any, gate: Any, a_eff: Any, share: float,
                 axis: tuple[Any, Any, Any], measured: Any, blind: Any, *,
                 rise_only: bool = False, colour_seen: bool = True) -> dict[str, Any]:
    """What the stage reads: ``bound`` (:func:`removal_bound`), ``zone`` (:func:`zone`) and ``x``
    (:func:`features` of the zone's pixels).  Arguments as :func:`features` and :func:`zone`;
    ``rise_only`` bounds the removal by the rise above the surroundings (alone on a colour stack,
    with the polarized light on a mono one); ``colour_seen=False`` (a mono stack as a grey one) asks
    for polarized light at the pixel (:func:`removal_bound`'s ``"polarized"``)."""
    side = int(v["side"])
    evidence = ("rise" if rise_only else "either") if colour_seen else ("both" if rise_only else "polarized")
    bound = removal_bound(diffuse, v["ic"], gx, side, a_eff * gate, evidence=evidence)
    where = zone(gate, blind, side, bound)
    x = features(diffuse, v, gx, gate, a_eff, share, axis, measured, bound, where)
    return {"x": x, "bound": bound, "zone": where}
