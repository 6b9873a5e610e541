"""Shared helpers of the single-image highlight-removal methods.

Every single-image method in :mod:`polcam.separation` models a pixel with the
dichromatic reflection model under a white (or white-balanced) illuminant,

    I_c = m_d Lambda_c + m_s / 3,        c in {R, G, B},

with ``Lambda`` the diffuse chromaticity (``sum_c Lambda_c = 1``), ``m_d`` and
``m_s`` the diffuse and specular weights.  The helpers here compute the
quantities those methods share: the chromaticity ``sigma_c = I_c / sum I``,
the specular-free image ``I - min_c I`` (optionally with an offset, Shen et
al.'s "modified specular-free" image), the chromaticity of the specular-free
image (Yang et al.'s approximation ``lambda`` of the diffuse chromaticity) and
the diffuse layer from a maximum diffuse chromaticity (Tan & Ikeuchi 2005,
eq. 11; Yang et al. 2010, eq. 5).

Each one is total on its domain: dark pixels (``sum I = 0``), achromatic
pixels (``sigma_min = 1/3``, where ``1 - 3 sigma_min = 0``) and saturated
pixels give finite values in the documented range, never NaN, never a
RuntimeWarning.  The functions and their signatures are a stable interface
for the method modules (yang10, shen09, shen13, yamamoto19, tan05, yoon06,
shen08, akashi16).

The helpers Yang'10 uses (:func:`as_rgb_image`, the channel reductions,
:func:`safe_divide`, :func:`specular_free_chromaticity`,
:func:`diffuse_from_max_chromaticity`, :func:`finish_diffuse`) are written over
the array namespace of :mod:`polcam._xp`: given a ``torch.Tensor`` they return
one on its device (float64), so the method runs on a device unchanged.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam._xp import namespace
from polcam.errors import MethodError

__all__ = [
    "EPS",
    "LIT",
    "as_rgb_image",
    "channel_max",
    "channel_min",
    "channel_sum",
    "min3",
    "max3",
    "sum3",
    "safe_divide",
    "chromaticity",
    "specular_free",
    "specular_free_chromaticity",
    "diffuse_from_max_chromaticity",
    "dark_mask",
    "finish_diffuse",
    "is_finite_number",
]

#: Denominators at or below this magnitude count as zero.
EPS = 1e-10
#: Least channel sum that is lit: three code values.  Under it a pixel has no measurable hue or
#: contrast (its chromaticity is that of rounding noise).
LIT = 3.0 / 255


def as_rgb_image(image: Any, *, method: str = "") -> np.ndarray:
    """Validate an RGB image and return it as float64 in [0, 1].

    Parameters
    ----------
    image
        (H, W, 3) array of floats in [0, 1] (values within 1e-6 outside are
        clipped), H, W >= 1; a ``torch.Tensor`` stays one.
    method
        Name of the calling method, used in the error message.

    Returns
    -------
    numpy.ndarray or torch.Tensor
        (H, W, 3) float64 in [0, 1] (a copy when clipping or casting).

    Raises
    ------
    MethodError
        Wrong shape, non-float dtype, non-finite values, values outside
        [0, 1] or an empty image.
    """
    who = f"method {method!r}: " if method else ""
    xp = namespace(image)
    arr = xp.asarray(image)
    shape = tuple(arr.shape)
    if arr.ndim != 3 or shape[-1] != 3:
        raise MethodError(f"{who}image of shape {shape}: expected an (H, W, 3) RGB image")
    if shape[0] == 0 or shape[1] == 0:
        raise MethodError(f"{who}image of shape {shape}: expected H >= 1 and W >= 1")
    if not xp.is_floating(arr):
        raise MethodError(
            f"{who}image of dtype {arr.dtype}: expected linear floats in [0, 1]"
        )
    if not bool(xp.isfinite(arr).all()):
        raise MethodError(f"{who}image contains NaN or infinite values: expected floats in [0, 1]")
    lo, hi = float(arr.min()), float(arr.max())
    if lo < -1e-6 or hi > 1 + 1e-6:
        raise MethodError(f"{who}image values span [{lo:.4g}, {hi:.4g}]: expected [0, 1]")
    return xp.clip(xp.astype(arr, xp.float64), 0.0, 1.0)


def is_finite_number(value: Any) -> bool:
    """True for a finite real scalar option value (Python or NumPy int or float, not bool).

    Parameters
    ----------
    value
        Any object.

    Returns
    -------
    bool
        False for bools, strings, arrays, None, NaN and infinities.
    """
    real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    return bool(real and np.isfinite(value))


def _float64(a: Any) -> tuple[Any, Any]:
    """The namespace of ``a`` and ``a`` as a float64 array of it."""
    xp = namespace(a)
    return xp, xp.asarray(a, dtype=xp.float64)


def max3(a: Any) -> Any:
    """Largest of the three channels of an (..., 3) array, in its own dtype.

    Elementwise over the channels: numpy's reduction over a three-long last axis is several times
    slower than two ``maximum`` calls.
    """
    xp = namespace(a)
    return xp.maximum(xp.maximum(a[..., 0], a[..., 1]), a[..., 2])


def min3(a: Any) -> Any:
    """Smallest of the three channels of an (..., 3) array, in its own dtype (as :func:`max3`)."""
    xp = namespace(a)
    return xp.minimum(xp.minimum(a[..., 0], a[..., 1]), a[..., 2])


def sum3(a: Any) -> Any:
    """Sum of the three channels of an (..., 3) array, in its own dtype (as :func:`max3`)."""
    return a[..., 0] + a[..., 1] + a[..., 2]


def channel_max(image: np.ndarray) -> np.ndarray:
    """Largest channel ``max_c I_c`` of an (..., 3) array, as (...) float64."""
    return max3(_float64(image)[1])


def channel_min(image: np.ndarray) -> np.ndarray:
    """Smallest channel ``min_c I_c`` of an (..., 3) array, as (...) float64."""
    return min3(_float64(image)[1])


def channel_sum(image: np.ndarray) -> np.ndarray:
    """Sum of the channels ``I_R + I_G + I_B`` of an (..., 3) array, as (...) float64."""
    return sum3(_float64(image)[1])


def safe_divide(num: Any, den: Any, *, fill: float = 0.0, eps: float = EPS) -> np.ndarray:
    """``num / den`` where ``|den| > eps``, ``fill`` elsewhere, without warnings.

    Parameters
    ----------
    num, den
        Arrays (or scalars) broadcastable to a common shape (torch tensors:
        both on one device).
    fill
        Value where the denominator is (near) zero.
    eps
        Threshold on ``|den|``.

    Returns
    -------
    numpy.ndarray or torch.Tensor
        float64 of the broadcast shape.
    """
    xp, num = _float64(num)
    den = xp.asarray(den, like=num, dtype=xp.float64)
    return xp.divide_where(num, den, abs(den) > eps, float(fill))


def chromaticity(image: np.ndarray, *, fill: float = 1.0 / 3.0) -> np.ndarray:
    """Chromaticity ``sigma_c = I_c / (I_R + I_G + I_B)``.

    Parameters
    ----------
    image
        (..., 3) non-negative intensities.
    fill
        Chromaticity of pixels whose sum is zero (black): 1/3, the
        achromatic point, by default.

    Returns
    -------
    numpy.ndarray
        (..., 3) float64 in [0, 1], summing to 1 per pixel.
    """
    _, image = _float64(image)
    return safe_divide(image, channel_sum(image)[..., None], fill=fill)


def specular_free(image: np.ndarray, *, offset: Any = 0.0) -> np.ndarray:
    """Specular-free image ``I_c - min_c I_c + offset``.

    With ``offset = 0`` this is the minimal specular-free image: under a
    white illuminant subtracting the per-pixel minimum removes the specular
    term ``m_s / 3`` exactly (and with it ``m_d min_c Lambda_c``), so the
    result has the geometry of the diffuse layer and the hue of the diffuse
    chromaticity, but not its saturation.  A positive offset gives Shen et
    al.'s modified specular-free (MSF) image, whose chromaticity is closer
    to the diffuse one.

    Parameters
    ----------
    image
        (..., 3) intensities.
    offset
        Scalar or array broadcastable to ``image[..., :1]`` added to every
        channel.

    Returns
    -------
    numpy.ndarray
        (..., 3) float64, >= ``offset``.
    """
    xp, image = _float64(image)
    return image - channel_min(image)[..., None] + xp.asarray(offset, like=image, dtype=xp.float64)


def specular_free_chromaticity(image: np.ndarray) -> np.ndarray:
    """Chromaticity of the minimal specular-free image (Yang et al.'s ``lambda``).

    ``lambda_c = (sigma_c - sigma_min) / (1 - 3 sigma_min)``, which equals
    ``(I_c - I_min) / (sum I - 3 I_min)``: Yang, Wang & Ahuja (ECCV 2010),
    Sec. 3.2, use ``lambda_max = max_c lambda_c`` as an approximation of the
    maximum diffuse chromaticity.  Where ``1 - 3 sigma_min`` is (near) zero
    (achromatic or black pixels) the value is 1/3, the achromatic point.

    Parameters
    ----------
    image
        (..., 3) non-negative intensities.

    Returns
    -------
    numpy.ndarray
        (..., 3) float64 in [0, 1], summing to 1 per pixel; the minimum
        channel is 0 except at achromatic pixels.
    """
    xp, image = _float64(image)
    free = image - channel_min(image)[..., None]
    total = channel_sum(free)[..., None]
    # Relative threshold: a pixel whose channel spread is below 1e-9 of its
    # intensity is achromatic to numerical precision.
    scale = channel_sum(image)[..., None]
    ok = total > xp.clamp_min(1e-9 * scale, EPS)
    return xp.divide_where(free, total, ok, 1.0 / 3.0)


def diffuse_from_max_chromaticity(
    image: np.ndarray, max_diffuse_chromaticity: np.ndarray, *, eps: float = 1e-6
) -> np.ndarray:
    """Diffuse layer from an estimate of the maximum diffuse chromaticity.

    From ``I_c = m_d Lambda_c + m_s / 3`` with ``sum_c Lambda_c = 1``:
    ``sum I = m_d + m_s`` and ``max_c I = m_d Lambda_max + m_s / 3``, so the
    specular term per channel is

        m_s / 3 = (max_c I - Lambda_max sum I) / (1 - 3 Lambda_max)
                = sum I (Lambda_max - sigma_max) / (3 Lambda_max - 1)

    (Tan & Ikeuchi, TPAMI 2005, eq. 11; Yang et al., ECCV 2010, eq. 5), and the
    diffuse layer is ``I - m_s / 3``.

    Failure points handled: ``Lambda_max`` is raised to at least the pixel's
    own ``sigma_max`` (a diffuse chromaticity cannot be less saturated than
    the pixel, which would make the specular term negative); where
    ``3 Lambda_max - 1 <= eps`` (achromatic surface: the diffuse and specular
    colours coincide and the split is undetermined) nothing is removed; the
    result is clipped to ``[0, I]``.

    Parameters
    ----------
    image
        (H, W, 3) float in [0, 1].
    max_diffuse_chromaticity
        (H, W) estimate of ``Lambda_max`` in [1/3, 1].
    eps
        Threshold on ``3 Lambda_max - 1``.

    Returns
    -------
    numpy.ndarray or torch.Tensor
        (H, W, 3) float64 diffuse layer with ``0 <= diffuse <= image``.
    """
    xp, image = _float64(image)
    total = channel_sum(image)
    sigma_max = safe_divide(channel_max(image), total, fill=1.0 / 3.0)
    lam = xp.clip(xp.asarray(max_diffuse_chromaticity, like=image, dtype=xp.float64), 1.0 / 3.0, 1.0)
    lam = xp.maximum(lam, sigma_max)
    spec = safe_divide(total * (lam - sigma_max), 3.0 * lam - 1.0, fill=0.0, eps=eps)
    return finish_diffuse(image - spec[..., None], image)


def dark_mask(image: np.ndarray, threshold: float) -> np.ndarray:
    """Pixels too dark for chromaticity analysis: ``max_c I <= threshold``.

    Parameters
    ----------
    image
        (..., 3) intensities in [0, 1].
    threshold
        Intensity in [0, 1].

    Returns
    -------
    numpy.ndarray
        (...) bool, True where dark.
    """
    return channel_max(image) <= threshold


def finish_diffuse(diffuse: np.ndarray, image: np.ndarray) -> np.ndarray:
    """Make a diffuse estimate finite and clip it to ``[0, image]``.

    Parameters
    ----------
    diffuse
        (H, W, 3) estimate (may hold NaN/inf from a method's arithmetic).
    image
        (H, W, 3) input in [0, 1].

    Returns
    -------
    numpy.ndarray
        (H, W, 3) float64 with ``0 <= diffuse <= image``; non-finite values
        become 0.
    """
    xp, diffuse = _float64(diffuse)
    return xp.clip(xp.nan_to_num(diffuse), 0.0, xp.asarray(image, like=diffuse))
