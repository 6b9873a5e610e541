"""Photograph-like training and validation scenes: public-domain / CC0 photographs with
simulated polarization.

The rendered scenes of :mod:`polcam.bench.lmmse_training` are shapes with synthetic
textures; real frames have natural textures, colour detail that follows the photograph's
own structure, and polarization edges that coincide with the intensity's edges.  This
module takes colour photographs that ship with scikit-image (a pinned dependency: they are
read from the installed package, never copied into polcam) and gives them a polarization
state per pixel and per colour:

* **diffuse** polarization everywhere: the angle follows the direction of the gradient of
  the blurred luminance (a stand-in for the azimuth of the surface normal, which is what
  sets the angle of diffuse polarization), the degree grows with that gradient's strength
  and is larger in the colours where the albedo is low (Umov's effect), so the three
  colours of one pixel do **not** share one polarization; DoLP at most about 0.3;
* **specular** polarization in the photograph's bright, near-white (unsaturated) regions
  and in a few added highlights of a near-white illuminant colour: DoLP 0.3 to 0.9, angle
  across the diffuse one;
* sometimes a **strongly polarized region** (a smooth random field above a threshold:
  sky, screens, filters), DoLP 0.3 to 0.7, the same in every colour;

then mild optical blur (sigma up to 1 pixel) and an exposure scale with clipping at 1.
The raw noise is added by the callers (:func:`polcam.bench.lmmse_training.noisy_raw`).

Photographs and licences (from the scikit-image docstrings): training uses
``astronaut`` (NASA, public domain), ``rocket`` (SpaceX, released into the public
domain), ``retina`` (CC0 1.0, M. Haggstrom) and ``hubble_deep_field`` (NASA, public
domain); validation uses the disjoint ``coffee`` (CC0, R. Michetti) and ``chelsea``
(CC0, S. van der Walt).
"""

from __future__ import annotations

import cv2
import numpy as np

from polcam.errors import MethodError

__all__ = ["TRAINING_PHOTOS", "VALIDATION_PHOTOS", "load_photo", "photo_stack", "polarize"]

#: Photographs the training scenes are cut from (all public domain or CC0).
TRAINING_PHOTOS = ("astronaut", "rocket", "retina", "hubble_deep_field")
#: Photographs of the validation set (CC0), disjoint from :data:`TRAINING_PHOTOS`.
VALIDATION_PHOTOS = ("coffee", "chelsea")

_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


def load_photo(name: str) -> np.ndarray:
    """One of the photographs of :data:`TRAINING_PHOTOS` or :data:`VALIDATION_PHOTOS`.

    Returns
    -------
    numpy.ndarray
        (H, W, 3) float32 RGB in [0, 1] (the 8-bit values / 255).

    Raises
    ------
    MethodError
        ``name`` is not one of the listed photographs.
    """
    if name not in TRAINING_PHOTOS + VALIDATION_PHOTOS:
        raise MethodError(f"photo {name!r}: expected one of {list(TRAINING_PHOTOS + VALIDATION_PHOTOS)}")
    import skimage.data

    img = np.asarray(getattr(skimage.data, name)())
    return (img[..., :3].astype(np.float32) / 255).astype(np.float32)


def _smooth_field(rng: np.random.Generator, h: int, w: int, *, sigma: float) -> np.ndarray:
    """A smooth random field, zero mean, unit standard deviation, (h, w)."""
    f = cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    return (f - f.mean()) / max(float(f.std()), 1e-6)


def polarize(rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Give a photograph a simulated per-pixel, per-colour polarization (module docstring).

    Parameters
    ----------
    rgb
        (H, W, 3) float32 in [0, 1], the scene's intensity (S0 up to the exposure).
    rng
        Random generator (the result is a function of its state).

    Returns
    -------
    numpy.ndarray
        (4, H, W, 3) float32 in [0, 1], angles 0, 45, 90, 135, RGB.
    """
    h, w = rgb.shape[:2]
    lum = rgb @ _LUMA
    smooth = cv2.GaussianBlur(lum, (0, 0), float(rng.uniform(1.5, 5)), borderType=cv2.BORDER_REFLECT)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REFLECT)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REFLECT)
    mag = np.hypot(gx, gy)
    strength = mag / (mag + max(float(np.median(mag)), 1e-4))  # [0, 1)
    phi_d = np.arctan2(gy, gx) + 0.3 * _smooth_field(rng, h, w, sigma=20)
    rho0 = rng.uniform(0.03, 0.3)
    umov = 1 - rng.uniform(0.3, 0.8) * rgb  # darker colours polarize more
    rho_d = np.clip(rho0 * (0.3 + 0.7 * strength)[..., None] * umov
                    * (1 + 0.3 * _smooth_field(rng, h, w, sigma=15))[..., None], 0, 1)
    layers = [(rgb, rho_d, np.broadcast_to(phi_d[..., None], rgb.shape))]
    # specular: the photograph's own bright unsaturated regions, and added near-white highlights
    sat = 1 - rgb.min(axis=2) / np.maximum(rgb.max(axis=2), 1e-3)
    thr = float(np.percentile(lum, 90))
    m = np.clip((lum - thr) / max(1 - thr, 1e-3) * 2, 0, 1) * np.clip(1 - 3 * sat, 0, 1)
    m = cv2.GaussianBlur(m.astype(np.float32), (0, 0), 1.0, borderType=cv2.BORDER_REFLECT)
    spec = np.zeros((h, w), np.float32)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    for _ in range(int(rng.integers(0, 4))):
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        sig = rng.uniform(1.5, max(2.0, min(h, w) / 12))
        spec += rng.uniform(0.1, 0.8) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sig**2))
    light = (1 + rng.uniform(-0.1, 0.1, 3)).astype(np.float32)
    rho_s = rng.uniform(0.3, 0.9)
    phi_s = phi_d + np.pi / 2 + rng.uniform(-0.3, 0.3)
    frac = rng.uniform(0.3, 0.8) * m  # the part of a bright pixel that is specular
    diffuse = rgb * (1 - frac)[..., None]
    layers[0] = (diffuse, rho_d, layers[0][2])
    layers.append(((rgb * frac[..., None]) + spec[..., None] * light, np.full((h, w, 1), rho_s, np.float32),
                   phi_s[..., None]))
    if rng.random() < 0.5:  # a strongly polarized region
        region = _smooth_field(rng, h, w, sigma=float(rng.uniform(8, 25))) > rng.uniform(0.5, 1.5)
        region = cv2.GaussianBlur(region.astype(np.float32), (0, 0), 0.7)[..., None]
        base, rb, pb = layers[0]
        rho_r = rng.uniform(0.3, 0.7)
        phi_r = rng.uniform(0, np.pi) + 0.2 * _smooth_field(rng, h, w, sigma=30)
        layers[0] = (base * (1 - region), rb, pb)
        layers.append((base * region, np.full((h, w, 1), rho_r, np.float32), phi_r[..., None]))
    s = np.zeros((3, h, w, 3), np.float32)
    for inten, r, p in layers:
        s[0] += inten
        s[1] += inten * r * np.cos(2 * p)
        s[2] += inten * r * np.sin(2 * p)
    blur = rng.uniform(0, 1.0)
    if blur > 0.3:
        s = np.stack([cv2.GaussianBlur(c, (0, 0), blur, borderType=cv2.BORDER_REFLECT) for c in s])
    theta = np.deg2rad([0, 45, 90, 135]).astype(np.float32)
    stack = 0.5 * (s[0][None] + np.cos(2 * theta)[:, None, None, None] * s[1][None]
                   + np.sin(2 * theta)[:, None, None, None] * s[2][None])
    stack *= np.float32(rng.uniform(0.5, 1.1) / max(float(np.percentile(stack, 99.5)), 1e-3))
    return np.clip(stack, 0, 1).astype(np.float32)


def photo_stack(rng: np.random.Generator, size: int, *, photos: tuple[str, ...] = TRAINING_PHOTOS,
                scale: tuple[float, float] = (0.35, 1.0)) -> np.ndarray:
    """A random ``size`` x ``size`` crop of one of ``photos``, area-downscaled by a random
    factor in ``scale``, randomly flipped / transposed, with simulated polarization.

    Returns
    -------
    numpy.ndarray
        (4, size, size, 3) float32 in [0, 1], angles 0, 45, 90, 135, RGB.
    """
    img = load_photo(photos[int(rng.integers(0, len(photos)))])
    f = max(rng.uniform(*scale), (size + 1) / min(img.shape[:2]))
    if f < 1:
        img = cv2.resize(img, (max(size, round(img.shape[1] * f)), max(size, round(img.shape[0] * f))),
                         interpolation=cv2.INTER_AREA)
    y0 = int(rng.integers(0, img.shape[0] - size + 1))
    x0 = int(rng.integers(0, img.shape[1] - size + 1))
    crop = img[y0:y0 + size, x0:x0 + size]
    if rng.random() < 0.5:
        crop = crop.transpose(1, 0, 2)
    if rng.random() < 0.5:
        crop = crop[::-1]
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    return polarize(np.ascontiguousarray(crop), rng)
