"""Noise of a polarization stack's Stokes components, and the garrotes that shrink what noise explains.

Used by ``polarized-residual`` (docs/methods/polarized-residual.md, steps 2 and 6): the
deviation of q and u per pixel measured from the stack itself (:func:`stokes_noise`), the
demosaicing's aliasing of them at intensity edges (:func:`aliasing_deviation`), the polarized
amplitude's noise bias removed (:func:`_debias`), and the colour prior's removal shrunk by the
noise of Ic (:func:`prior_removal`).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.separation._common import LIT
from polcam.separation._illuminant import SATURATED

#: Noise deviations at which the non-negative garrote of the polarized amplitude (``noise="shrink"``) sets in.
#: On the first 400 validation scenes polarized-residual scores alike from 2 to 3 (2: 28.47 dB, best or
#: within 0.3 dB of the four other methods 80.0 %; 2.5: 28.49, 79.5 %; 3: 28.49, 79.5 %), and the harm
#: checks of :func:`polcam.bench.residual_training.harm_checks` do not move (checker 0.983 at each).
_KSIG = 2.5
#: Deviations of its own noise at which a smoothed quantity is coherent signal, not noise: the amplitude
#: that fixes the polarization axis (:func:`axis_debias`), the colour prior's removal (:func:`prior_removal`).
#: The same 400 scenes: 3: 28.48 dB, 79.5 %; 4: 28.49, 79.5 %; 5: 28.49, 79.2 %.
COHERENT_KSIG = 4.0
#: The demosaicing's aliasing of the Stokes components: on an unpolarized scene the interpolated q and
#: u deviate from 0 by this many times ``C Ic`` (RMS), ``C`` the local log contrast of the intensity
#: (:func:`aliasing_deviation`).  Measured for the default demosaicing on crops of the training
#: photographs through the IMX250MYR mosaic, without noise: 0.061 over the pixels with ``C > 0.1``
#: (0.05-0.08 in each band of ``C`` from 0.05 to 1.2); tests/separation/test__polarization_noise.py
#: measures it again.
ALIASING = 0.06
#: Side of the window of that local contrast, in pixels: the demosaicing's support (the 4 x 4
#: colour-polarization period and the interpolation around it).
ALIASING_WINDOW = 9


def stokes_noise(stack: Any, ic: Any) -> Any:
    """Standard deviation of the noise of q and u per pixel, (H, W[, C]) like ``ic``.

    An ideal linear-polarizer stack obeys ``I0 + I90 = I45 + I135`` (both are S0) whatever the
    scene, so ``r = (I0 + I90 - I45 - I135) / 2`` is noise only: with independent noise of
    deviation ``sigma_I`` per image, ``var r = sigma_I^2`` and ``var q = var u = sigma_I^2 / 2``.
    A real stack can break the identity systematically (unequal gains of the four polarizer
    images, misregistration), while a smooth signal leaves a residual in any spatial high-pass;
    so the estimate is the smaller of two: the consistency residual's ``|r| / sqrt 2``, and the
    residual of a 3 x 3 box mean of q and u (``q - box(q)`` has variance ``sigma^2 (1 - 1/9)`` for
    independent noise; a smooth gain error leaves nothing there).  Each is a robust spread
    (1.4826 x the median absolute value) over pixels of similar intensity (eight quantile bins of
    ``ic``: photon noise grows with the signal, so it is taken non-decreasing in the intensity),
    linearly interpolated in ``ic``.  numpy or torch (float32) in, the same out.
    """
    xp = namespace(stack)
    s = xp.astype(stack, xp.float32)
    shape = ic.shape
    flat = (shape[0], shape[1], -1)
    q = (0.5 * (s[0] - s[2])).reshape(flat)
    u = (0.5 * (s[1] - s[3])).reshape(flat)
    r = (0.5 * (s[0] + s[2] - s[1] - s[3])).reshape(flat)
    i2 = ic.reshape(flat)
    valid = (xp.amax(s, axis=0) < SATURATED).reshape(flat)      # clipping breaks both identities
    out = []
    for c in range(i2.shape[-1]):
        lev = i2[..., c]
        hp_q = abs(q[..., c] - _imageops.box(q[..., c], 3))
        hp_u = abs(u[..., c] - _imageops.box(u[..., c], 3))
        sig_r, sig_hp = _binned_spread(lev, (abs(r[..., c]) / np.sqrt(2.0),
                                             np.sqrt(9.0 / 8.0) * 0.5 * (hp_q + hp_u)), valid[..., c])
        out.append(xp.minimum(sig_r, sig_hp))
    return xp.stack(out, axis=-1).reshape(shape)


def aliasing_deviation(ic: Any) -> Any:
    """The deviation of q and u that demosaicing makes at intensity edges, (H, W, C) float32 >= 0 like ``ic``.

    A polarization mosaic samples the four angles at different places, so an interpolated stack
    has polarization wherever the intensity changes within the interpolation's support: a
    systematic error, but one whose sign follows the scene's texture below the mosaic's period
    (aliasing), so it acts as noise of deviation :data:`ALIASING` ``C Ic``, where
    ``C = log(max / min)`` of the channel sum over :data:`ALIASING_WINDOW` pixels (dark pixels
    floored at three code values).  0 on a flat surface; about 0.04 ``Ic`` at a 2:1 edge.

    ``ic`` is (H, W, C) float32 (numpy or torch), the mean over the angles.
    """
    xp = namespace(ic)
    light = xp.maximum(ic.sum(axis=-1), LIT)   # no measurable contrast under LIT
    k = min(ALIASING_WINDOW, *[d | 1 for d in light.shape])
    contrast = xp.log(_imageops.dilate(light, k) / _imageops.erode(light, k))
    return xp.astype(ALIASING * contrast[..., None] * ic, xp.float32)


def _binned_spread(level: Any, absres: tuple[Any, ...], valid: Any, bins: int = 8) -> list[Any]:
    """Robust deviation of zero-mean residuals as non-decreasing functions of ``level``.

    ``level``, each of ``absres`` (a residual's absolute value) and ``valid`` (which pixels to learn
    from) are (H, W); each result, (H, W) float32, is defined at every pixel.  The eight bins (of
    ``level``, shared by the residuals) and their statistics come from a regular subsample of at most
    500 000 values, taken on the host (a torch array's subsample is copied there); the interpolation
    runs on the array's device.
    """
    xp = namespace(level)
    lev = level[valid]
    if lev.shape[0] == 0:
        return [xp.zeros(level.shape, like=level, dtype=xp.float32) for _ in absres]
    step = max(1, lev.shape[0] // 250_000)             # a regular subsample is plenty for eight medians
    lev = xp.to_numpy(lev[::step])
    edges = np.quantile(lev, np.linspace(0, 1, bins + 1))
    idx = np.clip(np.searchsorted(edges, lev, side="right") - 1, 0, bins - 1)
    members = [m for m in (idx == b for b in range(bins)) if m.sum() >= 50]
    if not members:
        return [xp.zeros(level.shape, like=level, dtype=xp.float32) for _ in absres]
    centres = [float(np.median(lev[m])) for m in members]
    out = []
    for a in absres:
        res = xp.to_numpy(a[valid][::step])
        sig = np.maximum.accumulate(np.asarray([1.4826 * float(np.median(res[m])) for m in members]))
        out.append(xp.astype(xp.interp(level, centres, sig), xp.float32))
    return out


def _garrote(x2: Any, var: Any) -> Any:
    """Non-negative garrote factor ``clip(1 - _KSIG^2 var / x2, 0, 1)`` for a value of square ``x2``."""
    xp = namespace(x2)
    return xp.clip(1.0 - (_KSIG * _KSIG) * var / xp.maximum(x2, 1e-12), 0.0, 1.0)


def prior_removal(diffuse: Any, sf: Any, sig: Any, *, smooth: int | None = None) -> Any:
    """What the colour prior removes from ``diffuse``, shrunk by the noise of Ic.

    ``diffuse`` and ``sf`` (the prior's specular-free estimate) are (H, W, 3); ``sig`` is the
    deviation of q and u per pixel and channel, (H, W, 3).  The removal ``diffuse - min(sf, diffuse)``
    is scaled by a garrote at ``_KSIG`` deviations of Ic's noise over the three channels
    (``var Ic = var q / 2``): on a noisy stack the specular-free estimate scatters below the diffuse by
    the noise alone.  With ``smooth`` (an odd Gaussian kernel side), the removal is kept whole where
    its Gaussian-smoothed value exceeds ``COHERENT_KSIG`` of its own deviations (a coherent
    highlight's, which the garrote would shrink by ``_KSIG^2 var / removal``: a quarter at five
    deviations), blended with the garroted removal over one deviation around that threshold (no
    jump; docs/methods/polarized-residual.md).  Returns (H, W, 3) float32 >= 0 (numpy or torch, as the input).
    """
    xp = namespace(diffuse)
    delta = diffuse - xp.minimum(sf, diffuse)
    dn2 = (delta * delta).sum(axis=-1, keepdims=True)
    var = 0.5 * (sig * sig).sum(axis=-1, keepdims=True)
    out = delta * _garrote(dn2, var)
    if smooth is not None:
        db = _imageops.gaussian(delta, smooth)
        # deviations of the smoothed removal: kept whole from COHERENT_KSIG + 0.5 of them, garroted
        # below COHERENT_KSIG - 0.5, in proportion between (a hard switch made the removal jump by
        # its whole garroted part under a change of 1e-7 in the input)
        dev = xp.sqrt((db * db).sum(axis=-1, keepdims=True) / xp.maximum(var, 1e-30)) / noise_reduction(smooth)
        whole = xp.where(var > 0, xp.clip(dev - (COHERENT_KSIG - 0.5), 0.0, 1.0), 1.0)
        out = whole * delta + (1.0 - whole) * out
    return xp.astype(out, xp.float32)


def noise_reduction(side: int) -> float:
    """Factor by which a ``side`` x ``side`` Gaussian blur (OpenCV's default sigma) reduces independent noise."""
    k = cv2.getGaussianKernel(side, 0)
    return float(np.sqrt(((k @ k.T) ** 2).sum()))


def _debias(isv: Any, sig: Any, how: str, *, components: int = 2) -> Any:
    """The polarized amplitude with the noise's bias removed (``isv``, ``sig`` same shape).

    ``isv`` is the length of ``components`` (2: q and u; 1: one projection) Stokes components, each
    with noise of deviation ``sig``.
    """
    xp = namespace(isv)
    if how == "rice":      # E|A|^2 = a^2 + components sigma^2
        return xp.sqrt(xp.maximum(isv * isv - components * sig * sig, 0.0))
    if how == "shrink":
        return isv * _garrote(isv * isv, sig * sig)
    if how == "thresh":
        return xp.maximum(isv - _KSIG * sig, 0.0)
    raise MethodError(f"polarized-residual: noise={how!r}: expected 'off', 'rice', 'shrink' or 'thresh'")


def axis_debias(q: Any, u: Any, c2: Any, s2: Any, smoothed: Any,
                 sig: Any, reduction: float, how: str, aliasing: Any = None) -> Any:
    """The polarized amplitude per pixel and channel, unbiased where the polarization axis is known.

    ``q``, ``u`` (H, W, C) are the Stokes components, ``(c2, s2)`` (H, W, 1) the unit polarization
    axis of the smoothed components, ``smoothed`` (H, W, C) the smoothed signed amplitude along it,
    ``sig`` (H, W, C) the deviation of their noise, ``reduction`` the factor by which smoothing
    reduced it (the smoothing kernel's root sum of squared weights, :func:`noise_reduction`), and
    ``aliasing`` (H, W, C, or None: 0) the deviation the demosaicing's aliasing adds to them
    (:func:`aliasing_deviation`).

    Where ``|smoothed|`` exceeds ``COHERENT_KSIG`` of its own deviations (``reduction sig``), the
    axis is signal, not noise: the projection ``par = q c2 + u s2`` has zero-mean noise, so
    ``|par|`` is kept as it is (a garrote would shrink a true amplitude ``x`` by
    ``_KSIG^2 sig^2 / x``: a fifth of it at five deviations), and only the orthogonal part, noise
    for a coherent polarization, is debiased as one component.  Elsewhere the amplitude
    ``hypot(q, u)`` is debiased as before (:func:`_debias`).  The two are blended over one
    deviation, from ``COHERENT_KSIG - 0.5`` to ``COHERENT_KSIG + 0.5``: a hard switch made
    ``Imin`` jump by up to 0.02 under a change of 1e-7 in the input
    (docs/methods/polarized-residual.md).

    The aliasing's deviation joins the noise's (in quadrature) in both debiases, the orthogonal
    part's and the pixel's whole amplitude's, but not in the test of the axis: at a highlight's
    rim, where the local contrast is highest, it would take a sharp highlight's own polarization
    for aliasing (on a sharp highlight over a yellow-green sphere, the whole highlight was left in
    the diffuse, 7 dB lower).  Returns (H, W, C) float32 >= 0.
    """
    xp = namespace(q)
    par = q * c2 + u * s2
    orth = u * c2 - q * s2
    unit = reduction * sig
    # where the noise is zero, any amplitude fixes the axis
    known_w = xp.where(unit > 0, xp.clip(abs(smoothed) / xp.maximum(unit, 1e-30) - (COHERENT_KSIG - 0.5), 0.0, 1.0),
                       xp.astype(abs(smoothed) > 0, q.dtype))
    dev = sig if aliasing is None else xp.hypot(sig, aliasing)
    known = xp.hypot(par, _debias(abs(orth), dev, how, components=1))
    return xp.astype(known_w * known + (1.0 - known_w) * _debias(xp.hypot(q, u), dev, how), xp.float32)
