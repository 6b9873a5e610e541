"""A randomized scene family for separation: scenes drawn from wide distributions, seen through a camera.

The paper's scenes and polcam's stress scenes (:mod:`polcam.synth.scenes`) are
few and fixed, so a method can be tuned to them.  This family draws every
scene from a seed, over wide distributions, so a method is chosen on one set
of seeds (the ``validation`` split, fixed) and reported on another (the
``test`` split, fresh seeds at every run):

* **shape**: the Stanford bunny, dragon, armadillo or a sphere
  (:func:`polcam.synth.mesh.load_mesh`), turned about the vertical axis by
  up to 60 degrees and tilted by up to 15;
* **materials**: 1 to 4 per object, the object split into solid Voronoi
  cells (:class:`MaterialTexture`); each material is a public-domain
  photograph used as albedo (the ones the demosaicing trains on,
  :mod:`polcam.synth.photos`: linearised, projected along an axis,
  rescaled and sometimes desaturated), achromatic (grey to white), pale (a
  faint tint) or saturated;
* **specular**: none on 15 % of scenes (matte), else Blinn-Phong strength
  ``ks`` log-uniform in [0.1, 2] and exponent log-uniform in [3, 100]
  (rough to glossy); refractive index uniform in [1.3, 1.9];
* **diffuse polarization** always on: the transmission Fresnel degree at the
  emission angle (:func:`polcam.synth.render.diffuse_dolp`), so rims are
  polarized along the normal's azimuth;
* **light**: white (40 %), tinted (40 %: one light of a random colour of
  saturation 0.1-0.5) or mixed (20 %: two lights of different colours from
  different directions), plus a small unpolarized ambient;
* **exposure**: log-uniform in [0.25, 3]: dark scenes to scenes whose
  diffuse clips (``exposure`` in :attr:`FamilyScene.params`);
* **background**: black, or a Lambertian grey or tinted backdrop plane;
* **camera**: the scene rendered on a sensor twice the stack's side; shot
  noise (full well log-uniform in [4000, 30000] electrons), read noise (2-10
  electrons), clipping at 1 and 12-bit quantisation applied to the raw
  IMX250MYR mosaic (and, for the mono stack, an IMX250MZR mosaic of the
  luminance), then polcam's default demosaicing at the polarizer-cell
  resolution (what ``polcam process`` separates by default), clipped to
  [0, 1]: what a camera gives polcam.

Ground truth: ``diffuse = clip(L_d, 0, 1)``, the noise-free diffuse radiance
(the mean of its four polarizer images; :mod:`polcam.synth.render`), summed
over the lights, averaged over 2 x 2 sensor pixels; ``diffuse_mono`` its mean over R, G and B (the luminance a
mono sensor with a flat response sees).

Splits (:func:`split_seeds`): ``validation`` is the seeds 0, 1, 2, ...
(fixed; below :data:`TRAINING_SEED_MIN`); ``test`` draws its scene seeds from
``numpy.random.default_rng(master)`` in ``[TEST_SEED_MIN, 2**31)``, the master
seed fresh from the operating system unless given, so the two never share a
scene and a test run is reproduced from its printed master seed.  Learned
stages train on a third, disjoint range (:func:`training_seeds`, from
:data:`TRAINING_SEED_MIN`).

Usage::

    from polcam.synth.family import render_family, split_seeds
    seeds, master = split_seeds("validation", 40)
    s = render_family(seeds[0], size=128)
    s.stack, s.diffuse, s.mask          # camera stack (4, H, W, 3), truth (H, W, 3), object

The draw of a seed is stable: changing a distribution changes the scenes, and
the figures recorded in docs/benchmarks.md must then be measured again.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from polcam.demosaicing import demosaic, mosaic_stack
from polcam.errors import PolcamError
from polcam.polarimetry import dolp
from polcam.synth.photos import TRAINING_PHOTOS, VALIDATION_PHOTOS, load_photo
from polcam.synth.render import SceneSpec, Texture, render

__all__ = ["SPLITS", "TEST_SEED_MIN", "TRAINING_SEED_MIN", "training_seeds", "SHAPES", "PHOTOS", "MaterialTexture", "FamilyScene",
           "draw", "render_family", "split_seeds", "scene_name", "seed_of", "camera", "cell_means",
           "loguniform", "hue"]

#: The splits of :func:`split_seeds`.
SPLITS = ("validation", "test")
#: Test scene seeds are at least this; validation seeds are below it.
TEST_SEED_MIN = 1_000_000
#: First seed of the training scenes (:func:`training_seeds`): above any validation seed
#: (``n`` is at most this) and below every test seed.
TRAINING_SEED_MIN = 500_000
#: Shapes and their views (rotation about x, y, z in degrees; focal; camera distance).
SHAPES: dict[str, dict[str, Any]] = {
    "bunny": {"rotation": (0.0, -25.0, 0.0), "focal": 2.0, "camera_distance": 2.5},
    "dragon": {"rotation": (0.0, 90.0, 0.0), "focal": 1.4, "camera_distance": 1.6},
    "armadillo": {"rotation": (0.0, -20.0, 0.0), "focal": 2.0, "camera_distance": 2.6},
    "sphere": {"rotation": (0.0, 0.0, 0.0), "focal": 2.0, "camera_distance": 2.2},
}
#: Public-domain / CC0 photographs used as albedo (shipped with scikit-image).
PHOTOS = ("astronaut", "rocket", "retina", "hubble_deep_field", "coffee", "chelsea")
_MATERIAL_KINDS = ("photo", "achromatic", "pale", "colour")
_RGB = tuple[float, float, float]
# every light is rendered this much dimmer and scaled back, so no sample clips before the camera
_HEADROOM = 64.0


@lru_cache(maxsize=len(PHOTOS))
def _photo(name: str) -> np.ndarray:
    """A photograph as linear RGB in [0, 1] (sRGB decoded), (H, W, 3) float32."""
    assert name in TRAINING_PHOTOS + VALIDATION_PHOTOS
    c = load_photo(name).astype(np.float64)
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return lin.astype(np.float32)


@dataclass(frozen=True)
class MaterialTexture(Texture):
    """An albedo of several materials: solid Voronoi cells, each a photograph or a uniform colour.

    Attributes
    ----------
    centers
        (K, 3) cell centres in the object's unit box; a surface point takes the
        material of its nearest centre.
    materials
        K dicts: ``{"kind": "uniform", "rgb": (r, g, b)}`` or ``{"kind": "photo",
        "photo": name, "axis": 0|1|2, "origin": (row, col), "side": pixels,
        "gain": g, "desaturate": d}``: the photograph's window of ``side``
        pixels at ``origin`` projected along ``axis`` over the unit box,
        ``albedo = clip(gain * ((1 - d) * rgb + d * luminance), 0, 0.95)``.
    """

    centers: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),)
    materials: tuple[dict[str, Any], ...] = ({"kind": "uniform", "rgb": (0.6, 0.6, 0.6)},)

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "materials")
        if len(self.centers) != len(self.materials) or not self.materials:
            raise PolcamError(f"material texture: {len(self.centers)} centres for {len(self.materials)} "
                              "materials: expected one centre per material, at least one")

    def evaluate(self, points: np.ndarray) -> np.ndarray:
        """Albedo at object-frame points: (N, 3) in the unit box -> (N, 3) float64 in [0, 0.95]."""
        p = np.asarray(points, dtype=np.float64)
        c = np.asarray(self.centers, dtype=np.float64)
        label = np.argmin(((p[:, None, :] - c[None]) ** 2).sum(-1), axis=1) if len(p) else np.zeros(0, int)
        out = np.zeros((len(p), 3))
        for k, mat in enumerate(self.materials):
            sel = label == k
            if not sel.any():
                continue
            if mat["kind"] == "uniform":
                out[sel] = mat["rgb"]
                continue
            img = _photo(mat["photo"])
            uv = np.delete(p[sel], mat["axis"], axis=1) + 0.5       # [0, 1]^2 over the box
            y = mat["origin"][0] + (1.0 - uv[:, 1]) * (mat["side"] - 1)
            x = mat["origin"][1] + uv[:, 0] * (mat["side"] - 1)
            y = np.clip(y, 0, img.shape[0] - 1.001)
            x = np.clip(x, 0, img.shape[1] - 1.001)
            y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
            fy, fx = (y - y0)[:, None], (x - x0)[:, None]
            rgb = ((img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx) * (1 - fy)
                   + (img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx) * fy)
            lum = rgb.mean(axis=1, keepdims=True)
            d = mat["desaturate"]
            out[sel] = np.clip(mat["gain"] * ((1 - d) * rgb + d * lum), 0.0, 0.95)
        return out


@dataclass
class FamilyScene:
    """One scene of the family as a camera gives it, with its ground truth.

    Attributes
    ----------
    name
        ``rand-<seed>``.
    seed
        The scene's seed (:func:`draw`).
    stack
        (4, H, W, 3) float32 in [0, 1]: the IMX250MYR camera's stack (noise,
        clipping, 12-bit raw, default demosaicing), angles 0, 45, 90, 135.
    mono_stack
        (4, H, W) float32 in [0, 1]: the IMX250MZR camera's stack of the same
        light (flat spectral response), its own noise.
    diffuse
        (H, W, 3) float32 in [0, 1]: true diffuse radiance, clipped at 1.
    diffuse_mono
        (H, W) float32: ``diffuse.mean(-1)``.
    ideal
        (4, H, W, 3) float32: the noise-free stack before the camera, 2 x 2
        means (not clipped: values above 1 are light the sensor clips).
    mask
        (H, W) bool, the object (at least half of the 2 x 2 sensor pixels).
    clipped
        (H, W) bool: pixels where any of the 12 samples of any of their 2 x 2
        sensor pixels is at or above 1 (the sensor's white level).
    dolp_diffuse
        (H, W) float32: the diffuse light's degree of linear polarization
        (grey, noise-free).
    params
        The drawn parameters (JSON-serialisable).
    """

    name: str
    seed: int
    stack: np.ndarray
    mono_stack: np.ndarray
    diffuse: np.ndarray
    diffuse_mono: np.ndarray
    ideal: np.ndarray
    mask: np.ndarray
    clipped: np.ndarray
    dolp_diffuse: np.ndarray
    params: dict[str, Any] = field(default_factory=dict)


def scene_name(seed: int) -> str:
    """``rand-<seed>``."""
    return f"rand-{int(seed)}"


def seed_of(name: str) -> int | None:
    """The seed of a ``rand-<seed>`` name, or None for any other name."""
    text = str(name)
    if text.startswith("rand-") and text[5:].isdigit():
        return int(text[5:])
    return None


def split_seeds(split: str, n: int = 40, *, seed: int | None = None) -> tuple[list[int], int | None]:
    """The scene seeds of a split.

    Parameters
    ----------
    split
        ``validation``: the seeds ``0 .. n-1`` (fixed; ``seed`` must be None).
        ``test``: ``n`` seeds drawn by ``numpy.random.default_rng(seed)`` from
        ``[TEST_SEED_MIN, 2**31)``, without repeats.
    n
        Number of scenes, 1 to ``TRAINING_SEED_MIN`` (validation) or ``TEST_SEED_MIN`` (test).
    seed
        The test split's master seed; None: a fresh one from the operating
        system.

    Returns
    -------
    seeds : list of int
    master : int or None
        The master seed used (test), None for validation.

    Raises
    ------
    PolcamError
        An unknown split, a bad ``n``, or a master seed given for validation.
    """
    if split not in SPLITS:
        raise PolcamError(f"split {split!r}: expected one of {', '.join(SPLITS)}")
    most = TRAINING_SEED_MIN if split == "validation" else TEST_SEED_MIN
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or not 1 <= n <= most:
        raise PolcamError(f"number of scenes {n!r}: expected an integer in 1..{most}")
    if split == "validation":
        if seed is not None:
            raise PolcamError(f"seed {seed!r}: the validation split's seeds are fixed (0..n-1); "
                              "expected no seed")
        return list(range(int(n))), None
    master = int(np.random.SeedSequence().entropy % (2**63)) if seed is None else int(seed)
    if master < 0:
        raise PolcamError(f"seed {seed!r}: expected a non-negative integer")
    rng = np.random.default_rng(master)
    seeds = rng.choice(2**31 - TEST_SEED_MIN, size=int(n), replace=False) + TEST_SEED_MIN
    return [int(s) for s in seeds], master



def training_seeds(n: int, *, start: int = 0) -> list[int]:
    """The seeds of the scenes learned stages are trained on: ``TRAINING_SEED_MIN + start + i``.

    Disjoint from both splits of :func:`split_seeds` (validation seeds are below
    :data:`TRAINING_SEED_MIN`, test seeds at least :data:`TEST_SEED_MIN`).

    Parameters
    ----------
    n
        Number of scenes, >= 1.
    start
        Offset of the first seed, >= 0; ``start + n`` at most ``TEST_SEED_MIN - TRAINING_SEED_MIN``.

    Returns
    -------
    list of int

    Raises
    ------
    PolcamError
        ``n`` or ``start`` out of range.

    Examples
    --------
    >>> training_seeds(2)
    [500000, 500001]
    """
    room = TEST_SEED_MIN - TRAINING_SEED_MIN
    ok = all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in (n, start))
    if not ok or n < 1 or start < 0 or start + n > room:
        raise PolcamError(f"training scenes n={n!r}, start={start!r}: expected n >= 1, start >= 0 "
                          f"and start + n <= {room}")
    return [TRAINING_SEED_MIN + int(start) + i for i in range(int(n))]

def loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A draw from ``rng`` log-uniform in [lo, hi] (lo > 0)."""
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def hue(rng: np.random.Generator, saturation: float, value: float) -> _RGB:
    """An RGB colour of random hue (drawn from ``rng``) at this HSV saturation and value."""
    import colorsys

    r, g, b = colorsys.hsv_to_rgb(float(rng.uniform()), saturation, value)
    return (float(r), float(g), float(b))


def _material(rng: np.random.Generator) -> dict[str, Any]:
    kind = _MATERIAL_KINDS[int(rng.choice(4, p=(0.35, 0.25, 0.2, 0.2)))]
    if kind == "achromatic":
        v = float(rng.uniform(0.15, 0.9))
        return {"kind": "uniform", "material": kind, "rgb": (v, v, v)}
    if kind == "pale":
        return {"kind": "uniform", "material": kind,
                "rgb": hue(rng, float(rng.uniform(0.04, 0.2)), float(rng.uniform(0.5, 0.9)))}
    if kind == "colour":
        return {"kind": "uniform", "material": kind,
                "rgb": hue(rng, float(rng.uniform(0.4, 0.9)), float(rng.uniform(0.3, 0.85)))}
    name = PHOTOS[int(rng.integers(len(PHOTOS)))]
    h, w = _photo(name).shape[:2]
    side = int(rng.uniform(0.3, 1.0) * min(h, w))
    origin = (int(rng.integers(0, h - side + 1)), int(rng.integers(0, w - side + 1)))
    mean = float(_photo(name)[origin[0]:origin[0] + side, origin[1]:origin[1] + side].mean())
    gain = float(rng.uniform(0.2, 0.7)) / max(mean, 0.02)
    return {"kind": "photo", "material": kind, "photo": name, "axis": int(rng.integers(3)), "origin": origin,
            "side": side, "gain": gain, "desaturate": float(rng.choice([0.0, rng.uniform(0.3, 0.9)]))}


def _light_direction(rng: np.random.Generator) -> tuple[float, float, float]:
    """A light position 4 units from the origin, in front of the object (towards the camera's side)."""
    az = rng.uniform(-np.pi * 0.75, np.pi * 0.75)    # 0: from the camera's side
    el = rng.uniform(-0.2, 1.1)
    d = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    return tuple(float(x) for x in 4.0 * d)


def draw(seed: int) -> dict[str, Any]:
    """The parameters of the family's scene ``seed`` (module docstring), as JSON-serialisable data.

    Parameters
    ----------
    seed
        Non-negative integer.

    Returns
    -------
    dict
        ``shape``, ``rotation``, ``materials``, ``centers``, ``ks``, ``shininess``,
        ``refractive_index``, ``light`` (``white``, ``tinted`` or ``mixed``),
        ``lights`` (list of ``{"position", "color", "intensity"}``), ``ambient``,
        ``exposure``, ``background`` / ``background_albedo``, ``full_well``,
        ``read_noise``, ``bit_depth``, ``noise_seed``.
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise PolcamError(f"scene seed {seed!r}: expected a non-negative integer")
    rng = np.random.default_rng([int(seed), 28])
    shape = list(SHAPES)[int(rng.integers(len(SHAPES)))]
    base = SHAPES[shape]["rotation"]
    rotation = (base[0] + float(rng.uniform(-15, 15)), base[1] + float(rng.uniform(-60, 60)), base[2])
    k = int(rng.integers(1, 5))
    centers = [tuple(float(x) for x in rng.uniform(-0.45, 0.45, 3)) for _ in range(k)]
    materials = [_material(rng) for _ in range(k)]
    ks = 0.0 if rng.random() < 0.15 else loguniform(rng, 0.1, 2.0)
    shininess = loguniform(rng, 3.0, 100.0)
    n_r = float(rng.uniform(1.3, 1.9))
    exposure = loguniform(rng, 0.25, 3.0)
    light = ("white", "tinted", "mixed")[int(rng.choice(3, p=(0.4, 0.4, 0.2)))]
    if light == "white":
        lights = [{"position": _light_direction(rng), "color": (1.0, 1.0, 1.0), "intensity": 1.0}]
    elif light == "tinted":
        lights = [{"position": _light_direction(rng), "intensity": 1.0,
                   "color": hue(rng, float(rng.uniform(0.1, 0.5)), 1.0)}]
    else:
        share = float(rng.uniform(0.3, 0.7))
        lights = [{"position": _light_direction(rng), "intensity": share,
                   "color": hue(rng, float(rng.uniform(0.1, 0.5)), 1.0)},
                  {"position": _light_direction(rng), "intensity": 1.0 - share,
                   "color": hue(rng, float(rng.uniform(0.1, 0.5)), 1.0)}]
    ambient = float(rng.uniform(0.0, 0.1))
    if rng.random() < 0.5:
        background, bg_albedo = "black", (0.15, 0.15, 0.15)
    else:
        background = "plane"
        bg_albedo = (hue(rng, float(rng.uniform(0.0, 0.3)), float(rng.uniform(0.1, 0.6))))
    return {
        "seed": int(seed), "shape": shape, "rotation": rotation, "view": dict(SHAPES[shape]),
        "centers": centers, "materials": materials, "ks": ks, "shininess": shininess,
        "refractive_index": n_r, "light": light, "lights": lights, "ambient": ambient,
        "exposure": exposure, "background": background, "background_albedo": bg_albedo,
        "full_well": loguniform(rng, 4000.0, 30000.0), "read_noise": float(rng.uniform(2.0, 10.0)),
        "bit_depth": 12, "noise_seed": int(rng.integers(2**31)),
    }


def _specs(p: dict[str, Any]) -> list[SceneSpec]:
    """One noise-free SceneSpec per light, dimmed by the headroom factor."""
    tex = MaterialTexture(centers=tuple(p["centers"]), materials=tuple(p["materials"]))
    view = {**p["view"], "rotation": p["rotation"]}
    out = []
    for i, lt in enumerate(p["lights"]):
        out.append(SceneSpec(
            name=f"rand-{p['seed']}", mesh=p["shape"], **view, albedo=tex,
            light_position=lt["position"], light_color=lt["color"],
            light_intensity=p["exposure"] * lt["intensity"] / _HEADROOM,
            ambient=(p["exposure"] * p["ambient"] / _HEADROOM) if i == 0 else 0.0,
            ks=p["ks"], shininess=p["shininess"], refractive_index=p["refractive_index"],
            diffuse_polarization=True, background=p["background"],
            background_albedo=p["background_albedo"], full_well=None, read_noise=0.0, bit_depth=None,
        ))
    return out


def camera(raw_clean: np.ndarray, layout: str, rng: np.random.Generator, p: dict[str, Any]) -> np.ndarray:
    """The family's camera: a noise-free raw mosaic as the sensor and polcam give it.

    Shot noise (``p["full_well"]`` electrons at 1), read noise (``p["read_noise"]`` electrons),
    clipping at 1 and quantisation to ``p["bit_depth"]`` bits of ``raw_clean`` ((H, W) >= 0, 1 the
    white level, in ``layout``), drawn from ``rng``; then the default demosaicing at the
    polarizer-cell resolution (``polcam process``'s default), clipped to [0, 1]: (4, H/2, W/2[, 3])
    float32.
    """
    fw = p["full_well"]
    e = rng.poisson(np.maximum(raw_clean, 0.0) * fw).astype(np.float64)
    e += rng.normal(0.0, p["read_noise"], size=e.shape)
    top = float(2 ** p["bit_depth"] - 1)
    raw = np.round(np.clip(e / fw, 0.0, 1.0) * top) / top
    return np.clip(demosaic(raw.astype(np.float32), layout=layout, resolution="cell"), 0.0, 1.0
                   ).astype(np.float32)


def cell_means(a: np.ndarray, axes: tuple[int, int]) -> np.ndarray:
    """Mean over 2 x 2 blocks along two axes of ``a`` (those sides halved; they must be even)."""
    y, x = axes
    shp = list(a.shape)
    shp[y:y + 1] = [shp[y] // 2, 2]
    shp[x + 1:x + 2] = [shp[x + 1] // 2, 2]
    return a.reshape(shp).mean(axis=(y + 1, x + 2))


def render_family(seed: int, *, size: int = 128) -> FamilyScene:
    """Render the family's scene ``seed`` and pass it through the colour and mono cameras.

    The scene is rendered on a sensor of ``2 size`` pixels a side and demosaiced at the
    polarizer-cell resolution, as ``polcam process`` does by default, to ``size``; the truth
    is the 2 x 2 mean of the rendered truth.

    Parameters
    ----------
    seed
        Scene seed (:func:`split_seeds`), >= 0.
    size
        Side of the stacks in pixels, even, at least 16.

    Returns
    -------
    FamilyScene
        Deterministic for ``(seed, size)``.

    Raises
    ------
    PolcamError
        A bad seed or size.
    """
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 16 or size % 2:
        raise PolcamError(f"size {size!r}: expected an even integer, at least 16 (the sensor is twice that, "
                          "a whole number of 4 x 4 IMX250MYR cells)")
    p = draw(seed)
    n = 2 * int(size)
    ideal = diffuse = mask = None
    for spec in _specs(p):
        r = render(spec, size=n, seed=0)
        if r.info["max_radiance"] * 2 >= 1.0:  # (1 + DoLP) <= 2: no sample reached the render's clip
            raise AssertionError(f"scene {p['seed']}: headroom too small")  # pragma: no cover
        stack = r.stack.astype(np.float64) * _HEADROOM
        ideal = stack if ideal is None else ideal + stack
        d = r.diffuse.astype(np.float64) * _HEADROOM
        diffuse = d if diffuse is None else diffuse + d
        mask = r.mask
    assert ideal is not None and diffuse is not None and mask is not None
    # the diffuse DoLP depends on the emission angle and the refractive index only, not on the light:
    # take it from a matte copy lit by the ambient term alone (every object pixel lit)
    matte = render(dataclasses.replace(_specs(p)[0], ks=0.0, light_intensity=0.0, ambient=0.5 / _HEADROOM),
                   size=n, seed=0)
    dpol = dolp(cell_means(matte.stack.astype(np.float64).mean(axis=-1), (1, 2))).astype(np.float32)
    rng = np.random.default_rng(p["noise_seed"])
    stack = camera(mosaic_stack(ideal, layout="imx250myr"), "imx250myr", rng, p)
    mono = camera(mosaic_stack(ideal.mean(axis=-1), layout="imx250mzr"), "imx250mzr", rng, p)
    truth = cell_means(np.clip(diffuse, 0.0, 1.0), (0, 1)).astype(np.float32)
    clipped = cell_means((ideal >= 1.0).any(axis=(0, 3)).astype(np.float64), (0, 1)) > 0
    obj = cell_means(mask.astype(np.float64), (0, 1)) >= 0.5
    return FamilyScene(
        name=scene_name(seed), seed=int(seed), stack=stack, mono_stack=mono, diffuse=truth,
        diffuse_mono=truth.mean(axis=-1), ideal=cell_means(ideal, (1, 2)).astype(np.float32), mask=obj,
        clipped=clipped, dolp_diffuse=np.where(obj, dpol, 0.0).astype(np.float32), params=p,
    )


def describe(scenes: Sequence[FamilyScene]) -> str:
    """A Markdown table of scenes: shape, materials, light, exposure, ks, shininess, n, clipped share."""
    lines = ["| scene | shape | materials | light | exposure | ks | shininess | n | clipped (object) |",
             "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for s in scenes:
        p = s.params
        mats = "+".join(m["material"] for m in p["materials"])
        clip = float(s.clipped[s.mask].mean()) if s.mask.any() else 0.0
        lines.append(f"| {s.name} | {p['shape']} | {mats} | {p['light']} | {p['exposure']:.2f} | {p['ks']:.2f} | "
                     f"{p['shininess']:.0f} | {p['refractive_index']:.2f} | {clip:.1%} |")
    return "\n".join(lines)
