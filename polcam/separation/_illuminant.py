"""The illuminant's colour from a colour polarization stack, and the polarizers' per-colour efficiency.

Specular reflection from a dielectric has the illuminant's colour (neutral
interface reflection) and is (partly) polarized; diffuse reflection is nearly
unpolarized.  So the colour of the polarized light is the classic estimate of
the illuminant (:func:`polarized_colour`: each channel's linear polarization
projected on its neighbourhood's polarization direction and summed, which
noise does not bias).  It is
right only when every colour channel's polarizer is equally efficient: a
polarizer of efficiency ``eta_c`` (the diattenuation, 1 for an ideal one)
measures ``eta_c Isv_c``.  Real wire-grid polarizers (on-chip ones too) have a
wavelength-dependent efficiency, and on the real stacks polcam is tested on the
polarized light's colour differs from the neutral colour of the white surfaces
and of the brightest highlights (docs/methods/polarized-residual.md).

:func:`estimate_illuminant` therefore:

1. with a calibration's per-colour efficiency: divides ``Isv`` by it and takes
   the polarized light's colour;
2. without one, when the polarized light's colour is within ``WHITE_Z``
   standard errors of white (weak polarization, as of specular light near
   normal incidence, or few pixels), keeps the camera's white balance: there is
   no evidence against it (:func:`_white_distance`);
3. otherwise compares the polarized light's colour with the brightest
   unsaturated, polarized pixels' own colour (:func:`highlight_colour`: at a
   strong highlight the specular term dominates the pixel).  When the two
   chromaticities agree within ``tolerance``, or the highlights are further
   from neutral than the polarized light (then they show their surface's own
   colour: the camera is assumed white-balanced), the polarized colour is used;
   otherwise the highlights' colour is the illuminant and the ratio of the two
   is the polarizers' implied per-colour efficiency (largest channel 1), which
   the separation divides ``Isv`` by.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from polcam import _imageops
from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.separation._common import max3, sum3

__all__ = ["IlluminantEstimate", "polarized_colour", "highlight_colour", "estimate_illuminant", "projected_chromaticity"]

#: Chromaticity distance under which the polarized light's colour is trusted.
TOLERANCE = 0.04
#: Standard errors from white under which the polarized light's colour is noise: the camera's white
#: balance is kept (:func:`estimate_illuminant`).
WHITE_Z = 3.0
#: Level (on the [0, 1] scale of a polarization image) at and above which the separation methods
#: treat a pixel as clipped: its measured light is not a measurement of the scene.
SATURATED = 0.98
#: Share of the lit, polarized, unsaturated pixels, the brightest, whose colour is the highlights'
#: (:func:`highlight_colour`).
HIGHLIGHT_SHARE = 0.002
#: Chromaticity distance from the surface's own colour over which polarized light counts in full
#: as the illuminant's (:func:`projected_chromaticity`'s ``own_colour``).
OWN_COLOUR = 0.1


class IlluminantEstimate(NamedTuple):
    """Result of :func:`estimate_illuminant`.

    Attributes
    ----------
    colour
        (3,) float64, mean 1: the illuminant's RGB colour.
    efficiency
        (3,) float64 in (0, 1], largest 1: per-colour polarizer efficiency
        (given, implied, or ones).
    source
        ``"calibration"``, ``"white balance"``, ``"polarized"`` or ``"highlights"``: what the colour
        came from.
    polarized, highlights
        (3,) float64 mean 1: the two measured colours (``highlights`` NaN when
        there were no usable highlight pixels).
    """

    colour: np.ndarray
    efficiency: np.ndarray
    source: str
    polarized: np.ndarray
    highlights: np.ndarray


def _unit_mean(v: np.ndarray) -> np.ndarray:
    v = np.maximum(np.asarray(v, dtype=np.float64), 0.0)
    m = v.mean()
    return v / m if m > 0 else np.ones(3)


def _chroma(v: np.ndarray) -> np.ndarray:
    return v / v.sum()


def _checked_stack(stack: Any) -> Any:
    """The stack as float32 (a ``torch.Tensor`` stays one, on its device); MethodError for a bad shape."""
    xp = namespace(stack)
    s = np.asarray(stack, dtype=np.float32) if xp.name == "numpy" else xp.astype(stack, xp.float32)
    if s.ndim != 4 or s.shape[0] != 4 or s.shape[-1] != 3:
        raise MethodError(f"illuminant: stack of shape {tuple(s.shape)}: expected (4, H, W, 3)")
    return s


class _Parts(NamedTuple):
    """What the estimates share, computed once from a (4, H, W, 3) float32 stack (numpy or torch)."""

    v0: Any        # (H, W, 3) I0 - I90 (S1)
    v1: Any        # (H, W, 3) I45 - I135 (S2)
    ic: Any        # (H, W, 3) mean of the four images
    isv: Any       # (H, W, 3) polarized amplitude, 0.5 |(S1, S2)|
    unsat: Any     # (H, W) bool: no sample at SATURATED or above


def _parts(stack: Any) -> _Parts:
    s = _checked_stack(stack)
    xp = namespace(s)
    v0 = s[0] - s[2]
    v1 = s[1] - s[3]
    ic = 0.25 * (s[0] + s[1] + s[2] + s[3])
    isv = 0.5 * xp.hypot(v0, v1)
    unsat = max3(xp.amax(s, axis=0)) < SATURATED
    return _Parts(v0, v1, ic, isv, unsat)


def polarized_colour(stack: np.ndarray, *, efficiency: np.ndarray | None = None) -> np.ndarray:
    """Colour of the polarized light, by projection on the neighbourhood's polarization direction.

    Each channel's linear polarization ``v_c = (S1_c, S2_c) / eta_c`` is projected on the
    polarization direction of the pixel's 8 neighbours (their channel-summed ``v``) and the
    projections are summed over unsaturated pixels
    (:func:`projected_chromaticity`, which this calls): zero-mean
    noise, independent between pixels, averages out instead of adding a positive bias in the
    colour of the brightest channel, as a sum of amplitudes ``Isv`` over the most polarized
    pixels did (measured in docs/benchmarks.md: 7.6 against 1.8 degrees from the planted light on
    Bunny1).

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1].
    efficiency
        (3,) per-colour polarizer efficiency in (0, 1], or None (ideal).

    Returns
    -------
    numpy.ndarray
        (3,) float64 with mean 1 (ones when the polarization is not significant).
    """
    _checked_stack(stack)
    eff = None if efficiency is None else check_efficiency(efficiency)
    return _unit_mean(projected_chromaticity(stack, efficiency=eff, own_colour=OWN_COLOUR))


def highlight_colour(stack: np.ndarray, *, share: float = HIGHLIGHT_SHARE) -> np.ndarray:
    """Own colour of the brightest unsaturated polarized pixels (the highlights).

    Among lit pixels (mean intensity above 5 % of the 99th percentile: a dark background's
    noise has a large, meaningless degree of polarization) with no saturated sample whose
    degree of polarization is above their median, the brightest ``share`` (by mean
    intensity) are averaged.

    Returns
    -------
    numpy.ndarray
        (3,) float64 with mean 1, or NaNs when no pixel qualifies.
    """
    return _highlight_colour(_parts(stack), share)


def _highlight_colour(parts: _Parts, share: float) -> np.ndarray:
    """:func:`highlight_colour` from the stack's shared parts."""
    ic, isv, unsat = parts.ic, parts.isv, parts.unsat
    xp = namespace(ic)
    lum = sum3(ic) / 3.0
    dolp = (sum3(isv) / 3.0) / xp.maximum(lum, 1e-6)
    ok = unsat & (lum > 0)
    if bool(ok.any()):
        ok &= lum > 0.05 * xp.quantile(lum, 0.99)
    if not bool(ok.any()):
        return np.full(3, np.nan)
    ok &= dolp >= xp.median(dolp[ok])
    if not bool(ok.any()):
        return np.full(3, np.nan)
    vals = lum[ok]
    sel = vals >= xp.quantile(vals, 1.0 - share)
    return _unit_mean(xp.to_numpy(xp.astype(ic[ok][sel], xp.float64).sum(axis=0)))


def check_efficiency(efficiency: object) -> np.ndarray:
    e = np.asarray(efficiency, dtype=np.float64).reshape(-1)
    if e.size != 3 or not np.all(np.isfinite(e)) or np.any(e <= 0) or np.any(e > 1):
        raise MethodError(f"polarizer efficiency {efficiency!r}: expected three numbers in (0, 1] (R, G, B)")
    return e


def estimate_illuminant(stack: np.ndarray, *, efficiency: object = None,
                        tolerance: float = TOLERANCE) -> IlluminantEstimate:
    """The illuminant's colour and the polarizers' per-colour efficiency (module docstring).

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1], angles 0, 45, 90, 135.
    efficiency
        (3,) per-colour polarizer efficiency in (0, 1] from a calibration, or None.
    tolerance
        Largest chromaticity distance between the polarized light's colour and
        the highlights' colour under which the former is used.

    Returns
    -------
    IlluminantEstimate
    """
    eff = None if efficiency is None else check_efficiency(efficiency)
    parts = _parts(stack)                       # shared by the polarized light's and the highlights' colour
    terms, ok = _projection_terms(parts, eff, OWN_COLOUR)
    pol = _unit_mean(_total_chromaticity(terms, ok, 5.0))      # polarized_colour
    hi = _highlight_colour(parts, HIGHLIGHT_SHARE)
    if eff is not None:
        return IlluminantEstimate(pol, eff / eff.max(), "calibration", pol, hi)
    if _white_distance(terms, ok) < WHITE_Z:
        # the polarized light's colour is within its own noise of white: no evidence against the
        # camera's white balance (the weak polarization of near-normal specular light, a small image)
        return IlluminantEstimate(np.ones(3), np.ones(3), "white balance", pol, hi)
    neutral = np.full(3, 1.0 / 3.0)
    if (not np.all(np.isfinite(hi)) or np.linalg.norm(_chroma(pol) - _chroma(hi)) <= tolerance
            or np.linalg.norm(_chroma(hi) - neutral) >= np.linalg.norm(_chroma(pol) - neutral)):
        # agreement, or highlights further from neutral than the polarized light: the
        # highlights then carry their surface's colour, and the polarized light is trusted
        return IlluminantEstimate(pol, np.ones(3), "polarized", pol, hi)
    ratio = pol / hi
    eff = np.clip(ratio / ratio.max(), 0.05, 1.0)
    return IlluminantEstimate(hi, eff, "highlights", pol, hi)


def projected_chromaticity(stack: Any, *, significance: float = 5.0, efficiency: Any = None,
                           own_colour: float | None = None) -> np.ndarray:
    """Illuminant chromaticity from the polarized light.

    Diffuse reflection is (close to) unpolarized, so the linear polarization
    ``v_c = (S1_c, S2_c)`` of every channel comes from specular reflection,
    whose colour is the illuminant's (dichromatic model): at a pixel,
    ``v_c = rho S Gamma_c (cos 2 phi, sin 2 phi)``, one direction for R, G and B
    with lengths in the ratio of Gamma.  The estimate projects each channel's
    ``v_c`` onto the polarization direction of the pixel's neighbourhood
    (the channel-summed ``v`` of its 8 neighbours), so that zero-mean noise,
    independent between pixels, averages out instead of adding a positive bias
    in the colour of the brightest channel (as a sum of amplitudes ``Isv``
    would):

        Gamma_c  proportional to  sum_p  v_c(p) . n(p),   n(p) = sum_{q in N8(p)} sum_c v_c(q)

    over unsaturated pixels.  When the total is not ``significance`` times its
    own noise (estimated from the spread of the per-pixel terms), or a channel
    comes out non-positive, the estimate is white.

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1] (numpy or torch; per-pixel terms in float32, sums over pixels in float64).
    significance
        How many standard deviations of the noise the signal must exceed.
    efficiency
        (3,) per-colour polarizer efficiency in (0, 1] (``v_c`` is divided by it), or None (ideal).
    own_colour
        None, or a chromaticity distance ``d``: each pixel's term is then weighted by
        ``min(|chroma(T5) - chroma(Imin)| / d, 1)``, ``T5`` the terms box-averaged over 5 x 5 pixels
        and ``Imin`` the pixel's polarization minimum: polarized light with the colour of the
        surface it leaves is the surface's own, partially polarized diffuse light (Atkinson &
        Hancock 2006), not evidence of the illuminant.  The weights are dropped when they keep
        less than 5 % of the pixels (a white scene: there the surface's colour is the light's).

    Returns
    -------
    numpy.ndarray
        (3,) chromaticity summing to 1 (white = 1/3 each).
    """
    terms, ok = _projection_terms(_parts(stack), efficiency, own_colour)
    return _total_chromaticity(terms, ok, significance)


def _projection_terms(parts: _Parts, efficiency: Any, own_colour: float | None) -> tuple[Any, Any]:
    """Per-pixel terms ``v_c(p) . n(p)`` ((H, W, 3) float32) and the unsaturated pixels ((H, W) bool).

    :func:`projected_chromaticity` gives the formula; numpy or torch in, the same out.  The terms
    are float32 (a product of two float32 differences); every sum over pixels is taken in float64.
    """
    xp = namespace(parts.v0)
    v0, v1 = parts.v0, parts.v1
    if efficiency is not None:
        e = xp.asarray(np.asarray(efficiency, np.float32).reshape(3), like=v0)
        v0 = v0 / e
        v1 = v1 / e
    terms = v0 * _neighbours(v0[..., 0] + v0[..., 1] + v0[..., 2])[..., None]
    terms = terms + v1 * _neighbours(v1[..., 0] + v1[..., 1] + v1[..., 2])[..., None]
    ok = parts.unsat
    if own_colour is not None:
        terms, ok = _own_colour_weighted(terms, parts, ok, float(own_colour))
    return terms, ok


def _neighbours(a: Any) -> Any:
    """Sum of each pixel's 8 neighbours of an (H, W) array, zero outside the image."""
    xp = namespace(a)
    h, w = a.shape
    p = xp.pad_hw(a, 1, 0.0)
    out = p[0:h, 0:w] + p[0:h, 1:w + 1]
    for dy, dx in ((0, 2), (1, 0), (1, 2), (2, 0), (2, 1), (2, 2)):
        out = out + p[dy:dy + h, dx:dx + w]
    return out


def _total_chromaticity(terms: Any, ok: Any, significance: float) -> np.ndarray:
    """Chromaticity of the summed terms over ``ok``; white when not significant (projected_chromaticity)."""
    xp = namespace(terms)
    t = xp.astype(terms[ok], xp.float64)
    if t.shape[0] == 0:
        return np.full(3, 1 / 3)
    total = xp.to_numpy(xp.sum(t, axis=0))
    per_pixel = t[:, 0] + t[:, 1] + t[:, 2]
    noise = float(np.sqrt(float((per_pixel * per_pixel).sum())))
    if total.sum() <= significance * noise or np.any(total <= 0):
        return np.full(3, 1 / 3)
    return total / total.sum()


def plane_basis() -> np.ndarray:
    """Two orthonormal vectors spanning the chromaticity plane (sum of components 0), (2, 3) float64."""
    return np.array([[1.0, -1.0, 0.0], [1.0, 1.0, -2.0]]) / np.array([[np.sqrt(2.0)], [np.sqrt(6.0)]])


def _white_distance(terms: np.ndarray, ok: np.ndarray, block: int | None = None) -> float:
    """How many standard errors the terms' chromaticity lies from white (a Mahalanobis distance).

    The chromaticity ``c = T / sum(T)`` of the total ``T`` of the terms ((H, W, 3), over ``ok``)
    is a ratio estimate; its covariance is estimated from ``block`` x ``block`` sums ``b`` (nearly
    independent: a term uses its 8 neighbours, demosaicing correlates a few pixels), as
    ``sum_b r_b r_b^T / sum(T)^2`` with ``r_b = b - c sum(b)`` (the delta method for a ratio), and
    the distance of ``c`` from (1/3, 1/3, 1/3) is measured in the chromaticity plane.  ``block``
    (None: 8, smaller on small images so that there are at least 400 blocks: the inverse of a
    covariance estimated from few blocks inflates the distance, a 96 x 96 image in 8 x 8 blocks
    by half in its mean square) sets the blocks' side.  Returns
    ``inf`` for a significant colour with no measurable spread (a noiseless stack), 0 when the
    terms sum to nothing positive.
    """
    xp = namespace(terms)
    t = xp.where(ok[..., None], xp.astype(terms, xp.float64), 0.0)
    total = xp.to_numpy(t.sum(axis=(0, 1)))
    s = float(total.sum())
    if s <= 0:
        return 0.0
    c = total / s
    h, w = t.shape[:2]
    if block is None:
        block = int(min(8, max(2, np.sqrt(h * w / 400.0))))
    hb, wb = max(h // block, 1), max(w // block, 1)
    bh, bw = h // hb, w // wb
    b = xp.to_numpy(t[:hb * bh, :wb * bw].reshape(hb, bh, wb, bw, 3).sum(axis=(1, 3)).reshape(-1, 3))
    r = b - np.outer(b.sum(axis=1), c)
    basis = plane_basis()
    d = basis @ (c - 1.0 / 3.0)
    cov = basis @ (r.T @ r) @ basis.T / (s * s)
    if np.linalg.det(cov) <= 1e-30 * max(float(np.trace(cov)) ** 2, 1e-300):
        return float("inf") if float(d @ d) > 1e-24 else 0.0
    return float(np.sqrt(d @ np.linalg.solve(cov, d)))


def _own_colour_weighted(terms: Any, parts: _Parts, ok: Any, dist: float) -> tuple[Any, Any]:
    """The projection terms weighted against the surface's own colour (``projected_chromaticity``).

    ``terms`` (H, W, 3) float32, ``parts`` the stack's shared parts and ``ok`` (H, W) bool, numpy or
    torch (the result is of the same kind).
    """
    xp = namespace(terms)
    imin = xp.maximum(parts.ic - parts.isv, 0.0)
    e = imin / xp.maximum(sum3(imin)[..., None], 1e-12)
    tb = _imageops.box(terms, 5)
    ts = sum3(tb)[..., None]
    big = abs(ts) > 1e-12
    chroma = xp.where(big, tb / xp.where(big, ts, 1.0), 1.0 / 3.0)
    d = chroma - e
    w = xp.clip(xp.sqrt(sum3(d * d)) / dist, 0.0, 1.0)
    if float(xp.astype(w[ok], xp.float64).sum()) < 0.05 * max(int(ok.sum()), 1):
        return terms, ok
    return terms * w[..., None], ok
