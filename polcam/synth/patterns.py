"""Synthetic full-resolution polarization scenes with ground truth.

Each scene is a set of per-pixel Stokes maps of *linearly* polarized light,
turned into the four images an ideal polarizer at 0, 45, 90 and 135 degrees
would record (Malus' law for partially polarized light)::

    I(t) = S0 / 2 * (1 + DoLP * cos(2 t - 2 AoLP))

so ``S0 = (I0 + I45 + I90 + I135) / 2 = I0 + I90``, ``S1 = I0 - I90``,
``S2 = I45 - I135`` exactly, the conventions of :mod:`polcam.polarimetry`.  The
scenes exist to measure demosaicing and the stages after it against a known
answer: they are full-resolution stacks with every angle (and colour) at every
pixel, which a sensor never gives.

Scenes (:data:`SCENES`), all deterministic for a given ``seed``:

``smooth``
    Smooth albedo, DoLP and AoLP (sums of a few random low-frequency
    cosines): DoLP spans [0, 1], AoLP wraps over [0, pi).
``textured``
    Albedo with a natural-image-like 1/f amplitude spectrum (fine texture up
    to the pixel scale) under smooth DoLP and AoLP fields spanning their ranges.
``edges``
    Random discs, rotated rectangles and half-planes, each with its own
    constant albedo, DoLP and AoLP: sharp edges in intensity *and* in
    polarization.  Rendered at 4x4 supersampling, the Stokes vectors averaged
    over each pixel (what a pixel of finite area records), so edges are sharp
    but not aliased.
``sweep``
    DoLP rising linearly from 0 to 1 along x, AoLP from 0 to pi along y, on
    an albedo that carries a radial chirp (zone plate) whose frequency rises
    to 0.25 cycles per pixel at the corners.

Colour scenes (``color=True``) give each region or texture its own RGB albedo
(the three channels are different but correlated, as in natural images) and
share the DoLP and AoLP across channels, except where supersampled edges mix
regions; the ground-truth maps are always derived from the final stack.

The module needs only numpy (and :mod:`polcam.errors` for its error type).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from polcam.errors import MethodError

__all__ = [
    "SCENES",
    "PolarizationScene",
    "make_scene",
    "stack_from_stokes",
    "uniform_scene",
]

#: Names of the synthetic scenes :func:`make_scene` builds.
SCENES: tuple[str, ...] = ("smooth", "textured", "edges", "sweep")

_ANGLES = np.deg2rad(np.array([0.0, 45.0, 90.0, 135.0]))

# range of S0 the scenes use: I(t) <= S0 <= 1 keeps every image in [0, 1]
_S0_LO, _S0_HI = 0.04, 0.96


@dataclass(frozen=True)
class PolarizationScene:
    """A full-resolution polarization stack and its ground truth.

    Attributes
    ----------
    name
        Scene name (one of :data:`SCENES` or ``"uniform"``).
    stack
        (4, H, W) mono or (4, H, W, 3) RGB float32 intensities in [0, 1],
        angle order 0, 45, 90, 135 degrees.
    s0
        (H, W) or (H, W, 3) float32 total intensity ``S0 = I0 + I90`` in [0, 1].
    dolp
        Degree of linear polarization in [0, 1], shape of ``s0``.
    aolp
        Angle of linear polarization in radians in [0, pi), shape of ``s0``,
        measured from the image x axis towards the 45-degree polarizer.
    seed
        The seed it was built from (``None`` for :func:`uniform_scene`).
    """

    name: str
    stack: np.ndarray
    s0: np.ndarray
    dolp: np.ndarray
    aolp: np.ndarray
    seed: int | None = None

    @property
    def is_color(self) -> bool:
        """True for an RGB scene."""
        return self.stack.ndim == 4

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the scene."""
        return int(self.stack.shape[1]), int(self.stack.shape[2])


def stack_from_stokes(s0: np.ndarray, dolp: np.ndarray, aolp: np.ndarray) -> np.ndarray:
    """The four polarizer images of light with given S0, DoLP and AoLP.

    Parameters
    ----------
    s0
        (H, W) or (H, W, 3) total intensity, >= 0.
    dolp
        Degree of linear polarization in [0, 1], broadcastable to ``s0``.
    aolp
        Angle of linear polarization in radians, broadcastable to ``s0``.

    Returns
    -------
    numpy.ndarray
        ``(4, *s0.shape)`` float32, ``I(t) = s0 / 2 (1 + dolp cos(2 t - 2 aolp))`` for
        t = 0, 45, 90, 135 degrees; in [0, max(s0)].

    Raises
    ------
    MethodError
        Negative ``s0`` or ``dolp`` outside [0, 1].
    """
    s0 = np.asarray(s0, dtype=np.float64)
    dolp = np.broadcast_to(np.asarray(dolp, dtype=np.float64), s0.shape)
    aolp = np.broadcast_to(np.asarray(aolp, dtype=np.float64), s0.shape)
    if np.any(s0 < 0) or np.any(dolp < 0) or np.any(dolp > 1):
        raise MethodError("stack_from_stokes: expected s0 >= 0 and dolp in [0, 1]")
    t = _ANGLES.reshape((4,) + (1,) * s0.ndim)
    stack = 0.5 * s0[None] * (1.0 + dolp[None] * np.cos(2.0 * t - 2.0 * aolp[None]))
    return stack.astype(np.float32)


def uniform_scene(
    height: int,
    width: int,
    *,
    s0: float | tuple[float, float, float] = 0.6,
    dolp: float = 0.5,
    aolp: float = 0.5,
) -> PolarizationScene:
    """A scene of one constant polarization state.

    Parameters
    ----------
    height, width
        Size in pixels.
    s0
        Total intensity in [0, 1]; a 3-tuple gives an RGB scene.
    dolp
        Degree of linear polarization in [0, 1].
    aolp
        Angle of linear polarization in radians (wrapped to [0, pi)).

    Returns
    -------
    PolarizationScene
        ``stack`` is (4, height, width) or (4, height, width, 3).

    Raises
    ------
    MethodError
        A size under 8, ``s0`` that is neither a number nor a triple, or values
        outside [0, 1].
    """
    _check_size(height, width)
    s0_arr = np.asarray(s0, dtype=np.float64)
    if s0_arr.ndim not in (0, 1) or (s0_arr.ndim == 1 and s0_arr.shape != (3,)):
        raise MethodError(f"uniform_scene: s0 {s0!r}: expected a number or an (R, G, B) triple")
    if np.any(s0_arr < 0) or np.any(s0_arr > 1) or not 0 <= dolp <= 1:
        raise MethodError(f"uniform_scene: s0 {s0!r} and dolp {dolp!r} must lie in [0, 1]")
    shape = (height, width) + ((3,) if s0_arr.ndim == 1 else ())
    s0_map = np.broadcast_to(s0_arr, shape)
    stack = stack_from_stokes(s0_map, np.float64(dolp), np.float64(aolp))
    return _scene_from_stack("uniform", stack, None)


def make_scene(
    name: str,
    *,
    height: int = 256,
    width: int = 256,
    seed: int = 0,
    color: bool = False,
) -> PolarizationScene:
    """Build one of the synthetic scenes.

    Parameters
    ----------
    name
        One of :data:`SCENES`.
    height, width
        Size in pixels (at least 8 each).
    seed
        Seed of the random content; the same seed gives the same scene.
    color
        RGB scene ((4, H, W, 3) stack) instead of mono ((4, H, W)).

    Returns
    -------
    PolarizationScene
        The stack and its ground truth, float32.

    Raises
    ------
    MethodError
        An unknown ``name`` or a size under 8.
    """
    if name not in _BUILDERS:
        raise MethodError(f"synthetic scene {name!r} is unknown; expected one of {', '.join(SCENES)}")
    _check_size(height, width)
    # one stream per (scene, seed): scenes of the same seed do not share content
    rng = np.random.default_rng([int(seed), SCENES.index(name)])
    s0, s1, s2 = _BUILDERS[name](rng, height, width, color)
    lin = np.hypot(s1, s2)
    with np.errstate(divide="ignore", invalid="ignore"):
        dolp = np.where(s0 > 0, lin / np.where(s0 > 0, s0, 1.0), 0.0)
    aolp = np.mod(0.5 * np.arctan2(s2, s1), np.pi)
    stack = stack_from_stokes(s0, np.clip(dolp, 0.0, 1.0), aolp)
    return _scene_from_stack(name, stack, int(seed))


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------

def _check_size(height: int, width: int) -> None:
    if int(height) != height or int(width) != width or height < 8 or width < 8:
        raise MethodError(f"scene size {width}x{height}: expected integers of at least 8")


def _scene_from_stack(name: str, stack: np.ndarray, seed: int | None) -> PolarizationScene:
    st = stack.astype(np.float64)
    s0 = st[0] + st[2]
    s1 = st[0] - st[2]
    s2 = st[1] - st[3]
    with np.errstate(divide="ignore", invalid="ignore"):
        dolp = np.where(s0 > 0, np.hypot(s1, s2) / np.where(s0 > 0, s0, 1.0), 0.0)
    aolp = np.mod(0.5 * np.arctan2(s2, s1), np.pi)
    aolp = np.where(aolp >= np.pi, 0.0, aolp)
    return PolarizationScene(
        name=name,
        stack=np.ascontiguousarray(stack, dtype=np.float32),
        s0=s0.astype(np.float32),
        dolp=np.clip(dolp, 0.0, 1.0).astype(np.float32),
        aolp=aolp.astype(np.float32),
        seed=seed,
    )


def _unit(field: np.ndarray) -> np.ndarray:
    """Affine map of ``field`` onto [0, 1] (min to 0, max to 1)."""
    lo, hi = float(field.min()), float(field.max())
    if hi - lo < 1e-12:
        return np.zeros_like(field)
    return (field - lo) / (hi - lo)


def _cosines(rng: np.random.Generator, h: int, w: int, *, n: int = 6,
             max_cycles: float = 3.0) -> np.ndarray:
    """Smooth random field: sum of ``n`` plane cosines of at most ``max_cycles`` over the image, in [0, 1]."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    size = float(max(h, w))
    f = np.zeros((h, w))
    for _ in range(n):
        cycles = rng.uniform(0.3, max_cycles)
        theta = rng.uniform(0, np.pi)
        phase = rng.uniform(0, 2 * np.pi)
        amp = rng.uniform(0.5, 1.0)
        k = 2 * np.pi * cycles / size
        f += amp * np.cos(k * (x * np.cos(theta) + y * np.sin(theta)) + phase)
    return _unit(f)


def _pink(rng: np.random.Generator, h: int, w: int, *, beta: float = 1.0) -> np.ndarray:
    """Noise with an isotropic 1/f**beta amplitude spectrum, mapped to [0, 1] by its 1st/99th percentiles."""
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    f = np.hypot(fy, fx)
    f[0, 0] = 1.0
    amp = f ** (-beta)
    amp[0, 0] = 0.0
    phase = rng.uniform(0, 2 * np.pi, size=amp.shape)
    mag = rng.rayleigh(1.0, size=amp.shape)
    field = np.fft.irfft2(amp * mag * np.exp(1j * phase), s=(h, w))
    lo, hi = np.percentile(field, [1, 99])
    return np.clip((field - lo) / max(hi - lo, 1e-12), 0.0, 1.0)


def _albedo_to_s0(albedo: np.ndarray) -> np.ndarray:
    return _S0_LO + (_S0_HI - _S0_LO) * albedo


def _tint(rng: np.random.Generator, h: int, w: int, lum: np.ndarray) -> np.ndarray:
    """RGB albedo: a luminance field times a smooth random chromaticity, in [0, 1]."""
    chroma = np.stack([_cosines(rng, h, w, n=3, max_cycles=2.0) for _ in range(3)], axis=-1)
    chroma = 0.35 + 0.65 * chroma
    chroma /= chroma.max(axis=-1, keepdims=True)
    return lum[..., None] * chroma


def _stokes(s0: np.ndarray, dolp: np.ndarray, aolp: np.ndarray) -> tuple[np.ndarray, ...]:
    if s0.ndim == 3 and dolp.ndim == 2:
        dolp = dolp[..., None]
        aolp = aolp[..., None]
    lin = s0 * dolp
    return s0, lin * np.cos(2 * aolp), lin * np.sin(2 * aolp)


def _smooth(rng: np.random.Generator, h: int, w: int, color: bool) -> tuple[np.ndarray, ...]:
    lum = _cosines(rng, h, w)
    albedo = _tint(rng, h, w, lum) if color else lum
    dolp = _cosines(rng, h, w)
    aolp = np.pi * _cosines(rng, h, w) * 1.999 % np.pi  # wraps once: covers [0, pi)
    return _stokes(_albedo_to_s0(albedo), dolp, aolp)


def _textured(rng: np.random.Generator, h: int, w: int, color: bool) -> tuple[np.ndarray, ...]:
    lum = _pink(rng, h, w)
    if color:
        # channels share most of the texture and differ by their own texture and tint
        own = np.stack([_pink(rng, h, w) for _ in range(3)], axis=-1)
        albedo = _tint(rng, h, w, np.ones((h, w))) * (0.75 * lum[..., None] + 0.25 * own)
    else:
        albedo = lum
    dolp = _cosines(rng, h, w, max_cycles=2.0)
    aolp = np.pi * _cosines(rng, h, w, max_cycles=2.0) * 1.999 % np.pi
    return _stokes(_albedo_to_s0(albedo), dolp, aolp)


def _edges(rng: np.random.Generator, h: int, w: int, color: bool) -> tuple[np.ndarray, ...]:
    ss = 4  # supersampling factor
    hs, ws = h * ss, w * ss
    y = ((np.arange(hs, dtype=np.float32) + 0.5) / ss)[:, None]
    x = ((np.arange(ws, dtype=np.float32) + 0.5) / ss)[None, :]
    nch = 3 if color else 1
    label = np.zeros((hs, ws), dtype=np.int32)
    n_planes, n_shapes = 3, 24
    size = float(max(h, w))
    for i in range(1, n_shapes + 1):
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        if i <= n_planes:  # half-planes first: a background of a few large regions
            th = rng.uniform(0, 2 * np.pi)
            inside = (x - cx) * np.cos(th) + (y - cy) * np.sin(th) > 0
        elif rng.integers(0, 2) == 0:  # disc
            r = rng.uniform(0.03, 0.15) * size
            inside = (y - cy) ** 2 + (x - cx) ** 2 <= r * r
        else:  # rotated rectangle
            a, b = rng.uniform(0.02, 0.2, size=2) * size
            th = rng.uniform(0, np.pi)
            u = (x - cx) * np.cos(th) + (y - cy) * np.sin(th)
            v = -(x - cx) * np.sin(th) + (y - cy) * np.cos(th)
            inside = (np.abs(u) <= a) & (np.abs(v) <= b)
        label[inside] = i
    # region 0 is the background; every region its own constant state
    albedo = rng.uniform(0.0, 1.0, size=(n_shapes + 1, nch))
    if color:
        albedo = albedo * rng.uniform(0.4, 1.0, size=(n_shapes + 1, 1))
    dolp = rng.uniform(0.0, 1.0, size=n_shapes + 1)
    aolp = rng.uniform(0.0, np.pi, size=n_shapes + 1)
    s0 = _albedo_to_s0(albedo[label])  # (hs, ws, nch)
    lin = s0 * dolp[label][..., None]
    s1 = lin * np.cos(2 * aolp[label])[..., None]
    s2 = lin * np.sin(2 * aolp[label])[..., None]

    def down(a: np.ndarray) -> np.ndarray:
        out = a.reshape(h, ss, w, ss, nch).mean(axis=(1, 3))
        return out if color else out[..., 0]

    return down(s0), down(s1), down(s2)


def _sweep(rng: np.random.Generator, h: int, w: int, color: bool) -> tuple[np.ndarray, ...]:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    dolp = x / (w - 1)
    aolp = np.pi * y / h  # [0, pi)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    r2 = (y - cy) ** 2 + (x - cx) ** 2
    # zone plate cos(pi k r^2): local frequency k r cycles/pixel, 0.25 at the corners
    k = 0.25 / np.sqrt(cy**2 + cx**2)
    lum = 0.5 + 0.35 * np.cos(np.pi * k * r2 + rng.uniform(0, 2 * np.pi))
    lum = lum * (0.6 + 0.4 * _cosines(rng, h, w, n=3, max_cycles=1.5))
    albedo = _tint(rng, h, w, lum) if color else lum
    return _stokes(_albedo_to_s0(albedo), dolp, aolp)


_BUILDERS: dict[str, Callable[[np.random.Generator, int, int, bool], tuple[np.ndarray, ...]]] = {
    "smooth": _smooth,
    "textured": _textured,
    "edges": _edges,
    "sweep": _sweep,
}
