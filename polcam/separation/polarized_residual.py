"""``polarized-residual``: polcam's own separation: remove the specular light that polarization shows.

The physics (docs/methods/polarized-residual.md gives the equations and the
validation sweeps behind every choice):

* Specular reflection has the illuminant's colour ``G`` and is partly polarized,
  perpendicular to its plane of incidence; its polarized part is what the
  polarization sinusoid measures, and it is removed.
* A colour polarization sensor's demosaicing draws polarization at intensity
  edges, linear in the gradient: fitted per image and removed first
  (:mod:`polcam.separation._false_polarization`).
* Diffuse light leaving a dielectric is polarized along the normal's azimuth,
  strongly only near occluding contours, where that azimuth is the axis of the
  image's gradient: the polarized light along it is given back to the diffuse
  (:mod:`polcam.separation._diffuse_polarization`; Atkinson & Hancock 2006,
  Kajiyama et al. WACV 2023).
* One specular colour: what is removed is the largest multiple of ``G`` under
  every channel's removal; polarized light in the body's colour stays diffuse.
* The unpolarized part ``(1 - rho_s) s G`` of the specular light: by default
  (``unpolarized="learned"``) a small model trained on the randomized family's
  training scenes reads it from local measures, near coherent polarized light,
  off clipped pixels and never beyond the pixel's rise above its surroundings or
  the polarized light seen at it
  (:mod:`polcam.separation._learned_residual`); ``"none"`` leaves it in the
  diffuse; ``"measured"`` runs the steps of :mod:`polcam.separation._residual`
  (k from coloured highlights, a colour prior).
* Optionally (``evidence=True``) the removal is bounded by the pixel's rise
  above its surroundings' floor (:mod:`polcam.separation._highlight`).
* Clipped highlights (a channel at the white level at all four angles) are filled
  smoothly with their own material's colour only when their border is a
  highlight of one material; otherwise left as measured and counted in ``info``
  (:func:`polcam.separation._clipping.fill_clipped_highlights`).
* A mono stack is a colour stack of three equal channels under a white illuminant: the
  same steps run on it, except that clipped regions are left as measured (a grey border
  cannot show which material lies under them) and the learned stage removes light only where
  polarized light is seen at the pixel, with weights of its own (without colour a rise does not
  tell a pale matte surface from a highlight).

One implementation for numpy and PyTorch: the array code runs over :mod:`polcam._xp`, the
neighbourhood filters are :mod:`polcam._imageops` (OpenCV for numpy, the same kernels on a torch
device); a ``torch.Tensor`` stack, or ``device=``, runs it on PyTorch
(docs/methods/polarized-residual.md, "Backends").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.separation._clipping import declipped, fill_clipped_highlights
from polcam.separation._common import max3, sum3
from polcam.separation._diffuse_polarization import diffuse_like_share, edge_axis, radial_share
from polcam.separation._false_polarization import without_edge_polarization
from polcam.separation._highlight import EVIDENCE_MEDIAN, peak_excess
from polcam.separation._illuminant import SATURATED, check_efficiency, estimate_illuminant
from polcam.separation._learned_residual import FEATURES as LEARNED_FEATURES
from polcam.separation._learned_residual import MONO_WEIGHTS_FILE as LEARNED_MONO_WEIGHTS
from polcam.separation._learned_residual import WEIGHTS_FILE as LEARNED_WEIGHTS
from polcam.separation._learned_residual import apply as _learned_apply
from polcam.separation._learned_residual import load_weights as _learned_weights
from polcam.separation._learned_residual import stage_inputs as _learned_inputs
from polcam.separation._one_colour import LIGHT_GUARD as _LIGHT_GUARD
from polcam.separation._one_colour import one_specular_colour as _one_specular_colour
from polcam.separation._polarization_noise import aliasing_deviation, axis_debias, noise_reduction, stokes_noise
from polcam.separation._registry import register
from polcam.separation._residual import highlight_mask, mono_steps, residual_steps
from polcam.separation.tensor.torch_backend import check_device

__all__ = ["REFERENCE", "separate_polarized_residual", "stages", "learned_inputs", "learned_layer", "DEFAULTS",
           "LEARNED_FEATURES", "LEARNED_WEIGHTS", "LEARNED_MONO_WEIGHTS"]

REFERENCE = (
    "polcam's own method; builds on L. B. Wolff & T. E. Boult, IEEE TPAMI 13(7) 1991 (polarization "
    "minimum); S. A. Shafer, Color Res. Appl. 10(4) 1985 (dichromatic model); S. Wen, Y. Zheng & F. Lu, "
    "IEEE TIP 30 2021; G. A. Atkinson & E. R. Hancock, IEEE TIP 15(6) 2006; Kajiyama et al., WACV 2023"
)

#: Default options (docs/methods/polarized-residual.md gives the benchmark behind each).
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
    "unpolarized": "learned",    # the unpolarized specular light: "learned" (_learned_residual), "none" (left in
                                 # the diffuse) or "measured" (steps of _residual: one specular colour, k from
                                 # coloured highlights, colour prior)
    "edge_fit": 1,               # demosaicing's polarization at edges fitted and removed: 0 (off), 1 or 2 (order)
    "aliasing": True,            # count the demosaicing's aliasing as noise in step 2 (False for stacks not from a mosaic)
    "edge_polarization": True,   # give back the polarized light along the local edge normal (_diffuse_polarization)
    "one_colour": True,          # remove only a multiple of the illuminant's colour G
    "evidence": False,            # bound the removal by the pixel's rise above its surroundings (_highlight)
    "evidence_window": 0.06,     # side of the surroundings' window, as a share of the image's larger side
    "declip": True,              # rebuild clipped samples from the other angles (S0 identity, shared AoLP)
    "residual_model": "shen13",  # coloured pixels' residual: "shen13" (specular-free clustering) or "hue"
    "device": None,              # None: numpy and OpenCV; "cpu", "cuda", ...: PyTorch on that device (torch extra)
}

#: The coherent polarization's Gaussian kernel ``k_s``: the image's larger side over this, and at least
#: ``_COHERENT_MIN_PX``: demosaicing and noise leave polarization of alternating sign from pixel to pixel,
#: which a few pixels' smoothing cancels, while a highlight's polarization is coherent over it.
_COHERENT_PER_SIDE = 200
_COHERENT_MIN_PX = 3.0
#: Share of a clipped region's border light that the layer must remove for the region to be a highlight
#: (filled): a sweep on the randomized family's validation split (0.02 / 0.03: 29.34 dB, 0.05 / 0.07:
#: 29.18, the fill of one scene lost; docs/methods/polarized-residual.md).
_HIGHLIGHT_BORDER = 0.03


def _check(opts: dict[str, Any]) -> None:
    if opts["edge_fit"] not in (0, 1, 2) or isinstance(opts["edge_fit"], bool):
        raise MethodError(f"polarized-residual: edge_fit={opts['edge_fit']!r}: expected 0, 1 or 2")
    if opts["unpolarized"] not in ("none", "measured", "learned"):
        raise MethodError(f"polarized-residual: unpolarized={opts['unpolarized']!r}: "
                          "expected 'none', 'measured' or 'learned'")
    for k in ("context", "min_saturation", "polarized_threshold", "evidence_window"):
        v = opts[k]
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating)) or not (0 < float(v) < 1):
            raise MethodError(f"polarized-residual: {k}={v!r}: expected a number in (0, 1)")
    mr = opts["max_ratio"]
    if isinstance(mr, bool) or not isinstance(mr, (int, float, np.floating)) or not 0 <= float(mr) < 1e3:
        raise MethodError(f"polarized-residual: max_ratio={mr!r}: expected a number in [0, 1000)")
    for k in ("declip", "diffuse_polarization", "evidence", "one_colour", "edge_polarization", "aliasing"):
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
        ((3,) per-colour polarizer efficiency in (0, 1] or None), ``noise`` (how the polarized
        amplitude's noise bias is removed), ``declip`` (rebuild clipped samples), ``edge_fit``
        (0, 1 or 2: demosaicing's edge polarization fitted to that order and removed), ``aliasing``
        (count the demosaicing's aliasing as noise in step 2; False for a stack
        not interpolated from a polarization mosaic), ``edge_polarization`` (give back the
        polarized light along the local edge normal), ``one_colour`` (remove only a multiple of
        ``G``), ``evidence`` and ``evidence_window`` (bound the removal by the rise above the
        surroundings), ``unpolarized`` ("learned", the
        default: the learned stage; "none"; or "measured": the optional steps, with
        ``diffuse_polarization``, ``context``, ``hue_bins``, ``min_saturation``, ``max_ratio``,
        ``residual_model``), ``polarized_threshold``.  A mono stack runs the colour path on the
        stack as a grey one (``illuminant`` and ``efficiency`` ignored; clipped regions left as
        measured; the learned stage bounded by the polarized light seen, with the mono weights;
        docs/methods/polarized-residual.md, "Mono stacks").

    Returns
    -------
    diffuse : numpy.ndarray or torch.Tensor
        (H, W, 3) (or (H, W)) float32 in [0, mean over angles]; a tensor for a tensor stack.
    info : dict
        ``illuminant`` (RGB, mean 1), ``illuminant_source``, ``efficiency`` (colour stacks), ``clipped_pixels``,
        ``clipped_filled``, ``clipped_as_measured``, ``clipped_seen`` (pixels with a channel
        clipped at all four angles, and how they were treated: filled, left as measured with every
        channel clipped, separated on the channels still measured unless step 4 left the pixel as
        measured), ``residual_ratio`` (unpolarized / polarized specular
        light; 0 unless ``unpolarized="measured"``); unless ``unpolarized="measured"`` on a mono
        stack, ``diffuse_like_share`` (in [0, 1]: how much of the edge-coherent polarization follows
        the edges, the weight of steps 3 and 4) and, with ``unpolarized="learned"``,
        ``learned_specular`` (the share of the layer's light the learned stage removed, in [0, 1]).
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
        before the last step where clipped samples were rebuilt): ``imin`` (``Ic`` less each
        channel's debiased polarized amplitude); for colour stacks with ``unpolarized="measured"``
        ``polarized_removed``, ``ratio_removed`` and ``prior_removed`` (each at most the one
        before it), then ``diffuse_polarization`` (edge polarization given back, if on) and
        ``evidence_bounded`` (one specular colour and the evidence bound, before the clipped
        fill); and ``diffuse``, the layer :func:`separate_polarized_residual` returns.
    """
    keep: dict[str, np.ndarray] = {}
    diffuse, _ = _separate(stack, options, keep)
    keep["diffuse"] = diffuse
    return keep


def learned_inputs(stack: np.ndarray, **options: Any) -> dict[str, Any]:
    """The learned stage's inputs on a stack, as polarized-residual computes them (its training reads them).

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1], angles 0, 45, 90, 135; or (4, H, W) mono, taken as the grey
        colour stack polarized-residual runs on it (:func:`separate_polarized_residual`).
    **options
        As :func:`separate_polarized_residual`, except ``unpolarized`` (the layer is taken before
        the stage, as with ``unpolarized="none"``).

    Returns
    -------
    dict
        ``diffuse`` (H, W, 3) the layer before the stage (three equal channels for a mono stack,
        whose layer is their mean); ``zone`` (H, W) bool, where it acts;
        ``x`` (N, F) float32 the features of the zone's pixels (row-major);
        ``bound`` (H, W) float32 >= 0 the most it may remove, in units of ``G``; ``g`` (3,) ``G``.
    """
    inputs: dict[str, Any] = {}
    _separate(stack, {**options, "unpolarized": "none"}, None, inputs)
    return inputs


def learned_layer(inputs: dict[str, Any], weights: dict[str, np.ndarray]) -> Any:
    """The layer the learned stage makes from :func:`learned_inputs` with ``weights`` (its training tries them).

    ``weights`` as :func:`polcam.separation._learned_residual.load_weights` gives them (the shipped
    ones, ``mono=True`` for the inputs of a mono stack, make polarized-residual's default layer).
    Returns (H, W, 3) float32 >= 0 (a mono stack's layer is its channels' mean).
    """
    w = {k: (np.asarray(v, np.float32) if np.asarray(v).dtype.kind == "f" else v) for k, v in weights.items()}
    out, _ = _learned_apply(inputs["diffuse"], inputs["x"], inputs["bound"], inputs["zone"], inputs["g"], w)
    return namespace(out).astype(out, namespace(out).float32)


def _separate(stack: Any, options: dict[str, Any], keep: dict[str, Any] | None,
              inputs: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
    """:func:`separate_polarized_residual`; with ``keep`` (a dict), the step layers go into it.

    With ``inputs`` (a dict, colour stacks), the learned stage's inputs go into it (``diffuse``
    before that stage, ``x`` (the zone's features, (N, F)), ``bound``, ``zone``, ``g``), whether or not
    the stage runs.
    """
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise MethodError(f"polarized-residual: unknown option(s) {', '.join(sorted(unknown))}")
    opts = {**DEFAULTS, **options}
    _check(opts)
    s, host = _on_device(stack, opts["device"])
    if s.ndim == 3 and s.shape[0] == 4:
        diffuse, info = _mono(s, opts, keep, inputs)
    elif s.ndim != 4 or s.shape[0] != 4 or s.shape[-1] != 3:
        raise MethodError(f"polarized-residual: stack of shape {tuple(s.shape)}: expected (4, H, W, 3) or (4, H, W)")
    else:
        diffuse, info = _colour(s, opts, keep, inputs)
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


def _colour(s: Any, opts: dict[str, Any], keep: dict[str, Any] | None,
            inputs: dict[str, Any] | None = None, *, colour_seen: bool = True) -> tuple[Any, dict[str, Any]]:
    """The colour path of :func:`_separate` on a (4, H, W, 3) float32 stack (numpy or torch).

    Steps 0-7 of docs/methods/polarized-residual.md ("Colour stacks, as implemented"), one function
    each; with ``unpolarized="measured"`` :func:`polcam.separation._residual.residual_steps` takes the
    place of steps 2 and 4.  ``colour_seen=False`` (a mono stack as a grey one): the clipped
    regions' fill, which needs the border's colour to tell one material, leaves them as measured,
    and the learned stage (step 7) is bounded by the polarized light alone, with the mono weights.
    """
    xp = namespace(s)
    measured = s.mean(axis=0)
    clipped_any = (s >= SATURATED).any(axis=(0, 3))       # (H, W): a sample of the pixel at the white level
    # (H, W, 3): a channel blind, its four samples' mean at the white level (each sample within 0.08
    # of full scale, so its polarization is not measured); steps 4, 6 and 7 read this one definition
    blind = measured >= SATURATED
    s = _declip(s, opts)
    g, eff, est, source = _illuminant(s, opts)
    gx = xp.asarray(g, like=s)                              # the same (3,) float32 where the stack is
    v = _polarization_minimum(s, gx, eff, opts)
    ic, imin = v["ic"], v["imin"]
    lum = sum3(ic) / 3.0
    if opts["unpolarized"] == "measured":
        v.update(s=s, g=g, gx=gx, measured=measured, clipped_any=clipped_any)
        diffuse, extra = residual_steps(v, opts, keep)
        spec, floor = extra["spec"], extra["floor"]
        ratio, ratio_source = extra["ratio"], extra["ratio_source"]
    else:
        # where coherent polarized light marks a highlight (the clipped regions' fill asks it)
        floor, a_eff, gate, spec = highlight_mask(v["a_coh"], lum, v["k_small"], g, float(opts["polarized_threshold"]))
        diffuse = imin
        ratio, ratio_source = 0.0, "none"
        if keep is not None:
            keep["imin"] = xp.astype(imin, xp.float32)
    # how much of the edge-coherent polarization follows the edges (diffuse-like) rather than
    # crossing them (specular-like): steps 3 and 4 keep diffuse polarization in that proportion
    axis = edge_axis(lum, _odd(2 * v["k_small"] + 1))
    share = diffuse_like_share(v["qq"], v["uu"], axis)
    if opts["edge_polarization"]:
        diffuse = _edge_polarization_given_back(diffuse, v, share, axis)
        if keep is not None:
            keep["diffuse_polarization"] = xp.astype(diffuse, xp.float32)
    if opts["unpolarized"] != "measured" and opts["one_colour"]:
        diffuse = _one_specular_colour(diffuse, ic, gx, share, gate, blind=blind)
    if opts["evidence"]:
        diffuse = _highlight_evidence(diffuse, ic, gx, window=_odd(float(opts["evidence_window"]) * v["side"]))
    if keep is not None:
        keep["evidence_bounded"] = xp.astype(diffuse, xp.float32)
    diffuse, clip_stats = _clipped_highlights(diffuse, measured, ic, spec, gx, blind,
                                              removed_share=opts["unpolarized"] != "measured", colour_seen=colour_seen)
    info = {**clip_stats, "illuminant": [float(x) for x in g], "illuminant_source": source,
            "efficiency": [float(x) for x in eff], "residual_ratio": ratio, "residual_ratio_source": ratio_source,
            "polarized_floor": floor, "diffuse_like_share": share}
    if est is not None:
        info["polarized_colour"] = [float(x) for x in est.polarized]
    diffuse = _within_measured(diffuse, measured, gx)
    if opts["unpolarized"] == "learned" or (inputs is not None and opts["unpolarized"] == "none"):
        diffuse, info["learned_specular"] = _learned_stage(diffuse, v, gx, gate, a_eff, share, axis, measured, blind,
                                                           run=opts["unpolarized"] == "learned", inputs=inputs,
                                                           rise_only=bool(opts["evidence"]), colour_seen=colour_seen)
    return xp.astype(diffuse, xp.float32), info


def _learned_stage(diffuse: Any, v: dict[str, Any], gx: Any, gate: Any, a_eff: Any, share: float,
                   axis: tuple[Any, Any, Any], measured: Any, blind: Any, *, run: bool,
                   inputs: dict[str, Any] | None, rise_only: bool, colour_seen: bool) -> tuple[Any, float]:
    """Step 7 (``unpolarized="learned"``): the unpolarized specular light a small model reads, removed along ``G``.

    :mod:`polcam.separation._learned_residual`: near coherent polarized light, off pixels whose every
    channel is ``blind``, and at most the pixel's rise above its surroundings or its polarized light
    (:data:`polcam.separation._learned_residual.POLARIZED_RATIO` times it; the rise alone with
    ``rise_only``, as ``evidence=True`` asks).  Without colour (``colour_seen=False``, a mono stack)
    at most its polarized light (and the rise too with ``rise_only``), with the mono weights.
    Returns the layer (unchanged unless ``run``) and the light removed as a share of the layer's
    light; ``inputs`` (a dict or None) receives the model's inputs.
    """
    read = _learned_inputs(diffuse, v, gx, gate, a_eff, share, axis, measured, blind, rise_only=rise_only,
                           colour_seen=colour_seen)
    if inputs is not None:
        inputs.update(read, diffuse=diffuse, g=gx)
    if not run:
        return diffuse, 0.0
    weights = _learned_weights(mono=not colour_seen)
    out, _ = _learned_apply(diffuse, read["x"], read["bound"], read["zone"], gx, weights)
    return out, float((diffuse - out).sum()) / max(float(diffuse.sum()), _LIGHT_GUARD)


def _coherent_kernel(side: int) -> int:
    """Side of the Gaussian kernel over which polarization is coherent, ``k_s``, for an image's larger side."""
    return _odd(max(_COHERENT_MIN_PX, side / _COHERENT_PER_SIDE))


def _declip(s: Any, opts: dict[str, Any]) -> Any:
    """Step 0: clipped samples rebuilt (``declip``), demosaicing's edge polarization removed (``edge_fit``)."""
    if opts["declip"]:
        s = declipped(s)
    if opts["edge_fit"]:
        s = without_edge_polarization(s, order=int(opts["edge_fit"]))
    return s


def _illuminant(s: Any, opts: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, Any, str]:
    """Step 1: the illuminant's colour ``G`` and the per-colour polarizer efficiency.

    Returns ``G`` ((3,) float32, mean 1), the efficiency ((3,) float64 in (0, 1]), the estimate
    (None when ``illuminant`` is given) and the source's name for ``info``.
    """
    if opts["illuminant"] is not None:
        g = np.asarray(opts["illuminant"], dtype=np.float64)
        est = None
        eff = np.ones(3) if opts["efficiency"] is None else np.asarray(opts["efficiency"], np.float64)
        if opts["efficiency"] is not None:
            eff = check_efficiency(eff)
        source = "given"
    else:
        est = estimate_illuminant(s, efficiency=opts["efficiency"])
        g = est.colour
        eff = est.efficiency if est.source == "calibration" else np.ones(3)
        source = est.source
    return (g / g.mean()).astype(np.float32), eff, est, source


def _polarization_minimum(s: Any, gx: Any, eff: np.ndarray, opts: dict[str, Any]) -> dict[str, Any]:
    """Step 2: ``Imin``, each channel's mean less its debiased polarized amplitude, and the coherent polarization.

    The Stokes components are divided by the polarizer efficiency, smoothed over ``k_s`` pixels
    (demosaicing and noise leave polarization of alternating sign that this cancels; a highlight's is
    coherent), and their common axis gives the signed amplitude of every channel along it.  Returns
    the quantities later steps use: ``ic``, ``q``, ``u`` (H, W, 3), ``isv``, ``imin``, ``amp``
    (smoothed) and ``amp_px`` (the pixel's own) signed amplitudes, ``sig`` (Stokes noise),
    ``a_coh`` (H, W) the coherent amplitude in units of ``G``, ``qq``, ``uu`` (H, W) the smoothed
    Stokes components over ``G`` summed over the channels, ``k_small`` and ``side``.
    """
    xp = namespace(s)
    h, w = s.shape[1:3]
    ic = s.mean(axis=0)
    q = 0.5 * (s[0] - s[2])
    u = 0.5 * (s[1] - s[3])
    if not np.all(eff == 1):
        effx = xp.asarray(eff.astype(np.float32), like=s)
        q = q / effx
        u = u / effx
    sig = stokes_noise(s, ic)
    side = max(h, w)
    k_small = _coherent_kernel(side)
    qs = _imageops.gaussian(q, k_small)
    us = _imageops.gaussian(u, k_small)
    qq = sum3(qs / gx)
    uu = sum3(us / gx)
    nn = xp.hypot(qq, uu)
    safe = nn > 0
    c2 = xp.where(safe, qq / xp.where(safe, nn, 1.0), 1.0)[..., None]
    s2 = xp.where(safe, uu / xp.where(safe, nn, 1.0), 0.0)[..., None]
    amp = qs * c2 + us * s2                                 # (H, W, 3) signed
    amp_px = q * c2 + u * s2                                # the same, unsmoothed (the pixel's own colours)
    # the polarized amplitude with the bias of the noise and of the demosaicing's aliasing at edges
    # removed: along the axis where the smoothed amplitude fixes it, shrunk elsewhere
    # (_polarization_noise.axis_debias, aliasing_deviation)
    if opts["noise"] == "off":
        isv = xp.hypot(q, u)
    else:
        alias = aliasing_deviation(ic) if opts["aliasing"] else None
        isv = axis_debias(q, u, c2, s2, amp, sig, noise_reduction(k_small), opts["noise"], alias)
    imin = xp.maximum(ic - isv, 0.0)
    # in units of G: the G-normalised channel sum is 3 a for a G-coloured polarized specular, while
    # colour demosaicing's polarization errors differ between channels and partly cancel in it
    a_coh = xp.astype(nn / 3.0, xp.float32)
    return dict(ic=ic, q=q, u=u, isv=isv, imin=imin, amp=amp, amp_px=amp_px, a_coh=a_coh, sig=sig,
                k_small=k_small, side=side, qq=qq, uu=uu)


def _edge_polarization_given_back(diffuse: Any, v: dict[str, Any], weight: float,
                                  axis: tuple[Any, Any, Any]) -> Any:
    """Step 3: the polarized light along the local edge normal is the diffuse light's own, given back.

    At occluding contours the intensity gradient's axis is the normal's azimuth
    (:func:`polcam.separation._diffuse_polarization.radial_share`, structure tensor smoothed over
    ``2 k_s + 1`` pixels).  ``weight`` in [0, 1] is the image's diffuse-like share
    (:func:`polcam.separation._diffuse_polarization.diffuse_like_share`): that proportion of it is
    given back; ``axis`` is the structure tensor's (``edge_axis``).  Returns (H, W, 3), at most ``Ic``.
    """
    xp = namespace(diffuse)
    ic, imin = v["ic"], v["imin"]
    share = radial_share(v["q"], v["u"], axis)
    return xp.minimum(diffuse + weight * share * (ic - imin), ic)


def _highlight_evidence(diffuse: Any, ic: Any, gx: Any, *, window: int) -> Any:
    """Step 5: nothing is removed beyond the multiple of ``G`` by which the pixel rises above its surroundings.

    The surroundings' floor is the larger of the opening and the lower-quartile rank opening by a
    square of side ``window``
    (:func:`polcam.separation._highlight.peak_excess`).
    """
    xp = namespace(diffuse)
    excess = peak_excess(ic, gx, window=window, smooth=EVIDENCE_MEDIAN)
    return xp.maximum(diffuse, ic - excess[..., None] * gx)


def _clipped_highlights(diffuse: Any, measured: Any, ic: Any, spec: Any, gx: Any, blind: Any,
                        *, removed_share: bool, colour_seen: bool) -> tuple[Any, dict[str, int]]:
    """Step 6: regions clipped at all four angles filled when their border is a highlight of one material.

    With ``removed_share`` a border pixel votes by the share of its light the layer removes: a ramp
    over half of ``_HIGHLIGHT_BORDER`` either side of it, so that a pixel's vote does not switch
    under noise; otherwise ``spec`` (the coherent polarized specular light's mask) votes.  Without
    ``colour_seen`` none is filled (:func:`polcam.separation._clipping.fill_clipped_highlights`).
    """
    xp = namespace(diffuse)
    light = None
    if removed_share and colour_seen:
        light = sum3(ic)
        share = sum3(ic - diffuse) / xp.maximum(light, _LIGHT_GUARD)
        spec = xp.clip((share - _HIGHLIGHT_BORDER) / _HIGHLIGHT_BORDER + 0.5, 0.0, 1.0)
    return fill_clipped_highlights(diffuse, measured, spec, gx, light, colour_seen=colour_seen, blind=blind)


def _within_measured(diffuse: Any, measured: Any, gx: Any) -> Any:
    """Never more than was measured (declipping raises ``Ic`` where samples were clipped).

    The layer is lowered by the least multiple of the one specular colour that brings every channel
    under the measurement, then clipped to ``[0, measured]``.
    """
    xp = namespace(diffuse)
    over = max3((diffuse - measured) / gx)
    return xp.clip(diffuse - xp.maximum(over, 0.0)[..., None] * gx, 0.0, measured)


def _mono(stack: Any, opts: dict[str, Any], keep: dict[str, Any] | None = None,
          inputs: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
    """Mono stacks ((4, H, W) float32, numpy or torch): the colour path on the stack as a grey one.

    A mono sensor is a colour sensor whose three channels see the same light: the stack is taken
    as (4, H, W, 3) with equal channels and the illuminant ``G = (1, 1, 1)`` (exact: every colour
    is the illuminant's), so steps 0-6 run unchanged and their colour tests pass on every pixel,
    except the clipped regions' fill: without colour the border cannot show that one material lies
    under the clipping, so they are left as measured (counted in ``info``).  Step 7, the learned
    stage, removes at most the polarized light seen at the pixel and reads the mono weights
    (:func:`polcam.separation._learned_residual.removal_bound`).  The layer is the
    channels' mean.  ``illuminant`` and ``efficiency`` do not apply and are ignored, and ``info``
    carries no illuminant.  With ``unpolarized="measured"``,
    :func:`polcam.separation._residual.mono_steps`.
    """
    if opts["unpolarized"] == "measured":
        return mono_steps(stack, opts, _coherent_kernel(max(stack.shape[1:3])), keep)
    xp = namespace(stack)
    grey = xp.stack([stack, stack, stack], axis=-1)
    layers: dict[str, Any] | None = None if keep is None else {}
    diffuse, info = _colour(grey, {**opts, "illuminant": (1.0, 1.0, 1.0), "efficiency": None}, layers,
                            inputs, colour_seen=False)
    if layers is not None:
        keep.update({k: xp.astype(v.mean(axis=-1), xp.float32) for k, v in layers.items()})
    for k in ("illuminant", "illuminant_source", "efficiency", "polarized_colour"):
        info.pop(k, None)
    return xp.astype(diffuse.mean(axis=-1), xp.float32), info
