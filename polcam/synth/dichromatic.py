"""Synthetic dichromatic RGB images with a known diffuse layer.

Every image here follows the dichromatic reflection model under a white
illuminant,

    I_c = m_d Lambda_c + m_s / 3,        c in {R, G, B},

with ``Lambda`` the diffuse colour of the surface, ``m_d`` its shading and
``m_s`` the specular weight, so the ground-truth diffuse layer is
``m_d Lambda`` and ``I - diffuse`` is the same (``m_s / 3 >= 0``) in the three
channels.  The single-image separation methods assume exactly this model, so
on these images they can be checked against the truth.

Two scene generators, kept numerically fixed (the separation tests' PSNR
thresholds were measured on them):

* :func:`banded_scene`: vertical bands of diffuse colour with smooth shading,
  one Gaussian lobe per band;
* :func:`patch_scene`: a 2 x 2 block of coloured patches on black, one lobe
  per patch.

:func:`polarization_stack` turns an image and its diffuse layer into a
four-angle stack whose mean is the image, and :func:`edge_cases` lists the
degenerate inputs (black, white, grey, one pixel, thin, saturated, dark
noise, ...) that every single-image method must survive.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from polcam.errors import PolcamError

__all__ = [
    "BAND_COLOURS",
    "PATCH_COLOURS",
    "banded_scene",
    "edge_cases",
    "patch_scene",
    "polarization_stack",
]

#: Diffuse colours of :func:`banded_scene`'s default two bands (red, cyan).
BAND_COLOURS: tuple[tuple[float, float, float], ...] = ((0.9, 0.05, 0.05), (0.1, 0.45, 0.45))

#: Diffuse chromaticities of :func:`patch_scene`'s four patches (top left, top right,
#: bottom left, bottom right).  Neighbouring patches differ by more than 0.1 in both
#: red and green chromaticity (Tan & Ikeuchi's colour-discontinuity test), and every
#: minimum channel stays clear of the methods' dark thresholds.
PATCH_COLOURS: np.ndarray = np.array(
    [[0.65, 0.25, 0.10], [0.10, 0.60, 0.30], [0.30, 0.10, 0.60], [0.50, 0.40, 0.10]]
)


def _check_size(name: str, value: int, least: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
        raise PolcamError(f"{name}={value!r}: expected an integer >= {least}")


def _check_peak(peak: float) -> None:
    real = isinstance(peak, (int, float, np.integer, np.floating)) and not isinstance(peak, bool)
    if not (real and np.isfinite(peak) and peak >= 0):
        raise PolcamError(f"peak={peak!r}: expected a finite number >= 0")


def _as_colours(colours: object, *, count: int | None = None) -> np.ndarray:
    arr = np.asarray(colours, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 1 or (count is not None and arr.shape[0] != count):
        want = f"({count}, 3)" if count is not None else "(n, 3) with n >= 1"
        raise PolcamError(f"colours of shape {arr.shape}: expected {want} RGB rows")
    if not (np.all(np.isfinite(arr)) and np.all(arr >= 0)):
        raise PolcamError("colours: expected finite values >= 0")
    return arr


def banded_scene(
    h: int = 64,
    w: int = 96,
    *,
    peak: float = 0.6,
    colours: Sequence[Sequence[float]] = BAND_COLOURS,
) -> tuple[np.ndarray, np.ndarray]:
    """Vertical bands of diffuse colour with smooth shading and one white lobe per band.

    The image is cut into ``n = len(colours)`` vertical bands of width
    ``bw = w / n``.  Band ``i`` has diffuse colour ``colours[i]`` and shading

        m_d = 0.55 + 0.35 cos(pi (y - h/2) / h) cos(pi (x mod bw - bw/2) / (2 bw)),

    in [0.55, 0.9].  Its specular lobe is a Gaussian of peak ``m_s = peak`` and
    sigma 5 px centred at ``(h (0.4 + 0.2 (i mod 2)), bw (i + 1/2))``, cut to
    zero beyond 3 sigma (15 px); lobes add where they overlap (bands narrower
    than 30 px).  The image is ``m_d Lambda + m_s / 3``.

    Parameters
    ----------
    h, w
        Image size in pixels, >= 1.
    peak
        Peak specular weight ``m_s`` (>= 0); at 0 the image is its diffuse
        layer.  The image is not clipped: it exceeds 1 where
        ``m_d max Lambda + peak / 3 > 1``.
    colours
        (n, 3) diffuse colours, n >= 1, values >= 0 (not normalised: a row is
        ``Lambda`` times an albedo).

    Returns
    -------
    image : numpy.ndarray
        (h, w, 3) float64, >= 0, at most ``0.9 max(colours) + n peak / 3``
        (``+ peak / 3`` where the lobes do not overlap, as in the default
        64 x 96 scene).
    diffuse : numpy.ndarray
        (h, w, 3) float64 ground-truth diffuse layer, in
        ``[0, 0.9 max(colours)]``; ``image - diffuse`` is equal in the three
        channels and >= 0.

    Raises
    ------
    PolcamError
        ``h`` or ``w`` not an integer >= 1, ``peak`` negative or not finite,
        ``colours`` not (n, 3) with finite values >= 0.
    """
    _check_size("h", h, 1)
    _check_size("w", w, 1)
    _check_peak(peak)
    table = _as_colours(colours)
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    n = table.shape[0]
    band = np.minimum((xx * n // w).astype(int), n - 1)
    lam = table[band]
    bw = w / n
    shade = 0.55 + 0.35 * np.cos(np.pi * (yy - h / 2) / h) * np.cos(np.pi * (xx % bw - bw / 2) / (2 * bw))
    diffuse = shade[..., None] * lam
    ms = np.zeros((h, w))
    for i in range(n):
        cy, cx = h * (0.4 + 0.2 * (i % 2)), bw * (i + 0.5)
        r2 = (yy - cy) ** 2 + (xx - cx) ** 2
        ms += np.where(r2 < 15.0**2, peak * np.exp(-r2 / (2 * 5.0**2)), 0.0)  # lobe cut at 3 sigma
    return diffuse + ms[..., None] / 3, diffuse


def patch_scene(
    h: int = 48,
    w: int = 64,
    *,
    margin: int = 8,
    peak: float = 0.6,
    colours: np.ndarray = PATCH_COLOURS,
) -> tuple[np.ndarray, np.ndarray]:
    """A 2 x 2 block of coloured patches on black, each with a white specular lobe.

    The patches are ``hh = (h - 2 margin) // 2`` by ``hw = (w - 2 margin) // 2``
    pixels, starting ``margin`` pixels from the top left corner (the black
    border keeps the mean minimum channel low, as in natural test scenes).
    Patch ``k`` (row by row) has diffuse colour ``colours[k]``, shading
    ``m_d = 0.9 (1 - 0.8 r^2)`` with ``r^2 = ((y - cy) / hh)^2 + ((x - cx) / hw)^2``
    about its centre ``(cy, cx)``, and a Gaussian lobe of peak ``m_s = peak``
    and sigma 2.5 px at ``(cy - hh/5, cx + hw/5)``, away from the shading
    maximum, not cut but confined to the patch.  The image is
    ``m_d Lambda + m_s / 3``; outside the patches it is 0.

    Parameters
    ----------
    h, w
        Image size in pixels, each >= ``2 margin + 2``.
    margin
        Black border above and left of the block, in pixels, >= 0.
    peak
        Peak specular weight ``m_s`` (>= 0); at 0 the image is its diffuse
        layer.  The image is not clipped.
    colours
        (4, 3) diffuse colours, values >= 0.

    Returns
    -------
    image : numpy.ndarray
        (h, w, 3) float64, >= 0, at most ``0.9 max(colours) + peak / 3`` (each
        lobe stays in its patch).
    diffuse : numpy.ndarray
        (h, w, 3) float64 ground truth, as for :func:`banded_scene`: in
        ``[0, 0.9 max(colours)]``, ``image - diffuse`` white and >= 0.

    Raises
    ------
    PolcamError
        Sizes that leave an empty patch, ``peak`` negative or not finite,
        ``colours`` not (4, 3) with finite values >= 0.
    """
    _check_size("margin", margin, 0)
    _check_size("h", h, 2 * margin + 2)
    _check_size("w", w, 2 * margin + 2)
    _check_peak(peak)
    table = _as_colours(colours, count=4)
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    diffuse = np.zeros((h, w, 3))
    spec = np.zeros((h, w))
    hh, hw = (h - 2 * margin) // 2, (w - 2 * margin) // 2
    origins = [(margin, margin), (margin, margin + hw), (margin + hh, margin), (margin + hh, margin + hw)]
    for k, (y0, x0) in enumerate(origins):
        sl = (slice(y0, y0 + hh), slice(x0, x0 + hw))
        cy, cx = y0 + hh / 2, x0 + hw / 2
        r2 = ((yy[sl] - cy) / hh) ** 2 + ((xx[sl] - cx) / hw) ** 2
        diffuse[sl] = (0.9 * (1.0 - 0.8 * r2))[..., None] * table[k]
        sy, sx = cy - hh / 5, cx + hw / 5
        spec[sl] = peak * np.exp(-((yy[sl] - sy) ** 2 + (xx[sl] - sx) ** 2) / (2 * 2.5**2))
    return diffuse + spec[..., None] / 3.0, diffuse


def polarization_stack(
    image: np.ndarray, diffuse: np.ndarray, *, amplitude: float = 0.8, phase: float = 0.6
) -> np.ndarray:
    """Four polarizer-angle images whose mean is ``image``: only the specular part varies.

    ``I(t) = D + (I - D) (1 + amplitude cos(2 t - phase))`` at ``t`` = 0, 45,
    90, 135 degrees: the diffuse layer ``D`` is unpolarized and the specular
    part ``I - D`` is partially linearly polarized with degree ``amplitude``
    and angle ``phase / 2``.  The cosines sum to zero over the four angles,
    so the mean over angles is ``image`` (to rounding).

    Parameters
    ----------
    image, diffuse
        (H, W, 3) float arrays of one shape (e.g. from :func:`banded_scene`).
    amplitude
        Degree of linear polarization of the specular part, in [0, 1].
    phase
        ``2 x`` the angle of polarization, in radians.

    Returns
    -------
    numpy.ndarray
        (4, H, W, 3) float64, angle order 0, 45, 90, 135 degrees; >= 0 when
        ``image >= diffuse >= 0``.

    Raises
    ------
    PolcamError
        Shapes differ or are not (H, W, 3), or ``amplitude`` outside [0, 1].
    """
    img = np.asarray(image, dtype=float)
    dif = np.asarray(diffuse, dtype=float)
    if img.ndim != 3 or img.shape[-1] != 3 or dif.shape != img.shape:
        raise PolcamError(
            f"image of shape {img.shape} and diffuse of shape {dif.shape}: expected two (H, W, 3) arrays"
        )
    if not (np.isfinite(amplitude) and 0.0 <= amplitude <= 1.0):
        raise PolcamError(f"amplitude={amplitude!r}: expected a number in [0, 1]")
    t = np.deg2rad([0, 45, 90, 135])[:, None, None, None]
    return dif[None] + (img - dif)[None] * (1 + amplitude * np.cos(2 * t - phase))


def edge_cases() -> list[tuple[str, np.ndarray]]:
    """Degenerate RGB inputs every single-image separation method must survive.

    Returns
    -------
    list of (str, numpy.ndarray)
        ``(name, image)`` pairs, each image (H, W, 3) float64 in [0, 1], new
        arrays on every call: ``zeros`` and ``white`` (9 x 11), ``grey`` (an
        achromatic ramp 0.1..0.9), ``one pixel``, ``one row`` (1 x 7),
        ``one column`` (7 x 1), ``single channel`` (red ramp, green and blue
        0), ``tiny values`` (1e-12..3e-12), ``saturated`` (the default
        :func:`banded_scene` with ``peak = 3`` clipped to 1) and
        ``dark noise`` (uniform in [0, 0.03], seeded, 20 x 24).
    """
    return [
        ("zeros", np.zeros((9, 11, 3))),
        ("white", np.ones((9, 11, 3))),
        ("grey", np.repeat(np.linspace(0.1, 0.9, 99).reshape(9, 11, 1), 3, axis=2)),
        ("one pixel", np.array([[[0.6, 0.3, 0.1]]])),
        ("one row", np.linspace(0, 1, 21).reshape(1, 7, 3)),
        ("one column", np.linspace(0, 1, 21).reshape(7, 1, 3)),
        ("single channel", np.stack([np.linspace(0, 1, 99).reshape(9, 11), np.zeros((9, 11)),
                                     np.zeros((9, 11))], axis=-1)),
        ("tiny values", np.full((9, 11, 3), 1e-12) * np.array([1.0, 2.0, 3.0])),
        ("saturated", np.clip(banded_scene(peak=3.0)[0], 0, 1)),
        ("dark noise", np.random.default_rng(5).uniform(0, 0.03, (20, 24, 3))),
    ]
