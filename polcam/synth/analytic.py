"""A second scene family, from a renderer that shares no scene code with the first: analytic shapes, microfacet light.

The randomized family (:mod:`polcam.synth.family`) trains polarized-residual's learned stage and is
where its constants were chosen.  A method fitted to one renderer can learn that renderer: its lobe
shape, its shading, its shapes.  This family checks the methods on scenes made otherwise, and is
used for no choice (``polcam bench quality --set analytic``):

* **shape**: a sphere, a torus, a blob (a sphere whose radius is modulated by three sinusoids) or a
  wave (a square tile whose top is a sinusoidal height field), ray-marched per sensor pixel
  through their signed distance functions (no mesh, no rasterizer), each turned at random;
* **materials**: 1 to 3 per object, split by random planes through it (patches with sharp
  borders); each achromatic (grey to white), pale (a faint tint) or coloured, uniform;
* **diffuse**: Lambertian (``albedo / pi`` of the irradiance), with the light's transmission into
  the surface and the emitted light's out of it weighted by Fresnel's ``1 - F`` (so grazing light
  and grazing views are dimmer than Lambert's cosine alone), polarized along the normal's azimuth
  by the transmission degree at the emission angle (Atkinson & Hancock 2006);
* **specular**: none on 15 % of scenes (matte), else a Trowbridge-Reitz (GGX) microfacet
  reflection of roughness ``alpha`` log-uniform in [0.04, 0.5], ``L_s = ks E D G F / (4 n.v)``
  with Smith's masking ``G`` and Fresnel's reflectance ``F`` at the angle between view and
  half-vector, energy-conserving as a real interface is (a rough lobe is broad and faint, a smooth
  one small and bright: with ``ks`` 1 and index 1.5, at normal incidence, it peaks at a white
  Lambertian surface's radiance for ``alpha`` 0.1, at a 25th of it for 0.5, at 6 times it for
  0.04), ``ks`` log-uniform in [0.5, 2] (a coat that reflects more or less than a bare interface); polarized by Fresnel's ``(Rs - Rp) / (Rs + Rp)``
  at that angle, perpendicular to the plane of view and half-vector; refractive index uniform in
  [1.3, 1.9];
* **light**: one or two directional lights (not the first family's point lights), at 2-110
  degrees from the camera's axis, white (45 %), tinted (35 %) or two of different colours (20 %),
  plus an unpolarized ambient term;
* **exposure**: the object's brightest diffuse channel (its 99.5th percentile) at a level
  log-uniform in [0.2, 1.3]: dark scenes to scenes whose diffuse clips, with highlights above;
* **background**: black, or an unpolarized uniform grey or tint;
* **camera**: the first family's (:func:`polcam.synth.family.render_family`): a sensor twice the
  stack's side, shot and read noise, clipping, 12-bit quantisation of the raw IMX250MYR (and, for
  the mono stack, IMX250MZR) mosaic, polcam's default demosaicing at the polarizer-cell resolution.

No cast shadows and no interreflection.  Ground truth: the diffuse radiance clipped at 1, averaged
over 2 x 2 sensor pixels, as the first family's.  Seeds and splits are the first family's
(:func:`polcam.synth.family.split_seeds`); a scene is named ``ana-<seed>``.

Usage::

    from polcam.synth.analytic import render_analytic
    s = render_analytic(3, size=128)
    s.stack, s.diffuse, s.mask          # camera stack (4, H, W, 3), truth (H, W, 3), object
"""

from __future__ import annotations

import colorsys
import math
from typing import Any

import numpy as np

from polcam.demosaicing import mosaic_stack
from polcam.errors import PolcamError
from polcam.synth.family import FamilyScene, cell_means, hue, loguniform
from polcam.synth.family import camera as camera_of  # the same camera as the first family's

__all__ = ["SHAPES", "draw", "render_analytic", "reflectances", "transmission_dolp", "scene_name"]

#: The shapes of :func:`draw`.
SHAPES = ("sphere", "torus", "blob", "wave")
#: The camera: at (0, 0, CAMERA_DISTANCE) looking at the origin, half the image's side at
#: TAN_HALF_FIELD (the object, about 1 across, fills most of the frame).
CAMERA_DISTANCE = 3.0
TAN_HALF_FIELD = 0.25
_ANGLES = np.deg2rad(np.array([0.0, 45.0, 90.0, 135.0]))
_MARCH_STEPS = 160
_HIT = 2e-4


def scene_name(seed: int) -> str:
    """``ana-<seed>``."""
    return f"ana-{int(seed)}"


def reflectances(theta: np.ndarray, n: float) -> tuple[np.ndarray, np.ndarray]:
    """Fresnel's power reflectances ``(Rs, Rp)`` at incidence ``theta`` (radians, [0, pi/2]) from air.

    In the angle form ``Rs = sin^2(ti - tt) / sin^2(ti + tt)``, ``Rp = tan^2(ti - tt) / tan^2(ti + tt)``
    with ``sin tt = sin ti / n``; at normal incidence both are ``((n - 1) / (n + 1))^2``.

    Examples
    --------
    >>> rs, rp = reflectances(np.array([0.0, np.arctan(1.5)]), 1.5)
    >>> bool(np.allclose(rs[0], 0.04) and np.allclose(rp, [0.04, 0.0]))
    True
    """
    ti = np.clip(np.asarray(theta, np.float64), 0.0, np.pi / 2)
    tt = np.arcsin(np.sin(ti) / n)
    r0 = ((n - 1.0) / (n + 1.0)) ** 2
    small = ti < 1e-6
    d, s = ti - tt, np.where(small, 1.0, ti + tt)
    rs = np.where(small, r0, np.sin(d) ** 2 / np.maximum(np.sin(s) ** 2, 1e-300))
    # tan(ti + tt) is infinite at Brewster's angle, where Rp = 0
    rp = np.where(small, r0, np.tan(d) ** 2 / np.maximum(np.tan(s) ** 2, 1e-300))
    return rs, np.where(np.abs(s - np.pi / 2) < 1e-12, 0.0, rp)


def transmission_dolp(theta: np.ndarray, n: float) -> np.ndarray:
    """Degree of polarization of diffuse light leaving a dielectric at emission angle ``theta``.

    Atkinson & Hancock (IEEE TIP 15(6) 2006, eq. 3)::

        rho = (n - 1/n)^2 sin^2 t / (2 + 2 n^2 - (n + 1/n)^2 sin^2 t + 4 cos t sqrt(n^2 - sin^2 t))
    """
    t = np.clip(np.asarray(theta, np.float64), 0.0, np.pi / 2)
    s2 = np.sin(t) ** 2
    num = (n - 1.0 / n) ** 2 * s2
    den = 2.0 + 2.0 * n * n - (n + 1.0 / n) ** 2 * s2 + 4.0 * np.cos(t) * np.sqrt(n * n - s2)
    return num / den


def _colour(rng: np.random.Generator, kind: str) -> tuple[float, float, float]:
    if kind == "achromatic":
        v = float(rng.uniform(0.15, 0.9))
        return (v, v, v)
    sat = float(rng.uniform(0.04, 0.2)) if kind == "pale" else float(rng.uniform(0.35, 0.9))
    val = float(rng.uniform(0.5, 0.9)) if kind == "pale" else float(rng.uniform(0.3, 0.85))
    return hue(rng, sat, val)


def _direction(rng: np.random.Generator, lo_deg: float, hi_deg: float) -> tuple[float, float, float]:
    """A unit vector at an angle in [lo, hi] degrees from the camera's axis (+z), any azimuth."""
    th = math.radians(float(rng.uniform(lo_deg, hi_deg)))
    az = float(rng.uniform(0.0, 2 * math.pi))
    return (math.sin(th) * math.cos(az), math.sin(th) * math.sin(az), math.cos(th))


def _rotation(rng: np.random.Generator) -> list[list[float]]:
    """A rotation matrix: uniform over the sphere of orientations (a normalised Gaussian quaternion)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]


def draw(seed: int) -> dict[str, Any]:
    """The parameters of scene ``seed`` (module docstring), as JSON-serialisable data.

    Returns
    -------
    dict
        ``shape``, ``shape_params``, ``rotation`` (3 x 3), ``materials`` (RGB albedos, 1-3),
        ``planes`` (the material split), ``ks`` (the specular scale; 0 when matte), ``alpha``,
        ``refractive_index``, ``light``, ``lights`` (``direction``, ``color``, ``intensity``),
        ``ambient``, ``exposure`` (the diffuse level), ``background``, ``background_rgb``,
        ``full_well``, ``read_noise``, ``bit_depth``, ``noise_seed``.
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise PolcamError(f"scene seed {seed!r}: expected a non-negative integer")
    rng = np.random.default_rng([int(seed), 0xA7A1])
    shape = SHAPES[int(rng.integers(len(SHAPES)))]
    if shape == "sphere":
        sp: dict[str, Any] = {"radius": float(rng.uniform(0.45, 0.6))}
    elif shape == "torus":
        sp = {"major": float(rng.uniform(0.32, 0.45)), "minor": float(rng.uniform(0.1, 0.2))}
    elif shape == "blob":
        sp = {"radius": float(rng.uniform(0.42, 0.52)), "amplitude": float(rng.uniform(0.1, 0.25)),
              "frequency": [float(f) for f in rng.uniform(2.5, 5.5, 3)],
              "phase": [float(f) for f in rng.uniform(0, 2 * math.pi, 3)]}
    else:
        sp = {"half": 0.55, "amplitude": float(rng.uniform(0.04, 0.1)),
              "frequency": [float(f) for f in rng.uniform(3.0, 8.0, 2)],
              "phase": [float(f) for f in rng.uniform(0, 2 * math.pi, 2)]}
    rot = _rotation(rng)
    if shape == "wave":      # the tile's top towards the camera, tilted by up to 55 degrees
        tilt, spin = math.radians(float(rng.uniform(0, 55))), float(rng.uniform(0, 2 * math.pi))
        c, s, cz, sz = math.cos(tilt), math.sin(tilt), math.cos(spin), math.sin(spin)
        rot = (np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])).tolist()
    k = int(rng.integers(1, 4))
    kinds = [("achromatic", "pale", "colour")[int(rng.choice(3, p=(0.35, 0.3, 0.35)))] for _ in range(k)]
    materials = [_colour(rng, kd) for kd in kinds]
    planes = [{"normal": [float(x) for x in rng.normal(size=3)], "offset": float(rng.uniform(-0.25, 0.25))}
              for _ in range(k - 1)]
    ks = 0.0 if rng.random() < 0.15 else loguniform(rng, 0.5, 2.0)
    alpha = loguniform(rng, 0.04, 0.5)
    light = ("white", "tinted", "two")[int(rng.choice(3, p=(0.45, 0.35, 0.2)))]

    def tint() -> tuple[float, float, float]:
        return tuple(float(c) for c in colorsys.hsv_to_rgb(float(rng.uniform()), float(rng.uniform(0.1, 0.5)), 1.0))  # type: ignore[return-value]

    if light == "white":
        lights = [{"direction": _direction(rng, 2, 110), "color": (1.0, 1.0, 1.0), "intensity": 1.0}]
    elif light == "tinted":
        lights = [{"direction": _direction(rng, 2, 110), "color": tint(), "intensity": 1.0}]
    else:
        share = float(rng.uniform(0.3, 0.7))
        lights = [{"direction": _direction(rng, 2, 110), "color": tint(), "intensity": share},
                  {"direction": _direction(rng, 2, 110), "color": tint(), "intensity": 1.0 - share}]
    background = "black" if rng.random() < 0.5 else "uniform"
    bg = (0.0, 0.0, 0.0) if background == "black" else tuple(
        float(c) for c in colorsys.hsv_to_rgb(float(rng.uniform()), float(rng.uniform(0, 0.3)), float(rng.uniform(0.05, 0.3))))
    return {
        "seed": int(seed), "shape": shape, "shape_params": sp, "rotation": rot, "materials": materials,
        "material_kinds": kinds, "planes": planes, "ks": ks, "alpha": alpha,
        "refractive_index": float(rng.uniform(1.3, 1.9)), "light": light, "lights": lights,
        "ambient": float(rng.uniform(0.0, 0.12)), "exposure": loguniform(rng, 0.2, 1.3),
        "background": background, "background_rgb": bg,
        "full_well": loguniform(rng, 4000.0, 30000.0), "read_noise": float(rng.uniform(2.0, 10.0)),
        "bit_depth": 12, "noise_seed": int(rng.integers(2**31)),
    }


def _sdf(p: np.ndarray, shape: str, sp: dict[str, Any]) -> np.ndarray:
    """Signed distance (or a lower bound of it, scaled to be 1-Lipschitz) of object-frame points (N, 3)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if shape == "sphere":
        return np.sqrt(x * x + y * y + z * z) - sp["radius"]
    if shape == "torus":
        q = np.sqrt(x * x + z * z) - sp["major"]
        return np.sqrt(q * q + y * y) - sp["minor"]
    if shape == "blob":
        f, ph, a = sp["frequency"], sp["phase"], sp["amplitude"]
        r = np.sqrt(x * x + y * y + z * z)
        mod = sp["radius"] * (1 + a * np.sin(f[0] * x + ph[0]) * np.sin(f[1] * y + ph[1]) * np.sin(f[2] * z + ph[2]))
        # |grad mod| <= radius * a * sqrt(sum f^2): divide by 1 + that to stay below the distance
        lip = 1.0 + sp["radius"] * a * math.sqrt(sum(v * v for v in f))
        return (r - mod) / lip
    f, ph, a, h = sp["frequency"], sp["phase"], sp["amplitude"], sp["half"]
    top = a * np.sin(f[0] * x + ph[0]) * np.cos(f[1] * y + ph[1])
    lip = math.sqrt(1.0 + (a * f[0]) ** 2 + (a * f[1]) ** 2)
    return np.maximum.reduce([(z - top) / lip, np.abs(x) - h, np.abs(y) - h, -z - 0.2])


def _march(origin: np.ndarray, dirs: np.ndarray, rot: np.ndarray, shape: str, sp: dict[str, Any]
           ) -> tuple[np.ndarray, np.ndarray]:
    """Sphere tracing from ``origin`` along unit ``dirs`` (N, 3): the hit points (N, 3) and a hit mask (N,)."""
    n = dirs.shape[0]
    t = np.full(n, CAMERA_DISTANCE - 1.0)                    # every object lies within the unit ball
    active = np.ones(n, bool)
    hit = np.zeros(n, bool)
    for _ in range(_MARCH_STEPS):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        pts = origin + t[idx, None] * dirs[idx]
        d = _sdf(pts @ rot, shape, sp)                       # world -> object frame: p_obj = R^T p_world
        t[idx] += d
        done = d < _HIT
        hit[idx[done]] = True
        far = t[idx] > CAMERA_DISTANCE + 1.0
        active[idx[done | far]] = False
    return origin + t[:, None] * dirs, hit


def _normals(pts: np.ndarray, rot: np.ndarray, shape: str, sp: dict[str, Any]) -> np.ndarray:
    """Unit world normals at world points (N, 3): the SDF's central-difference gradient."""
    e = 1e-4
    obj = pts @ rot
    g = np.stack([_sdf(obj + e * ax, shape, sp) - _sdf(obj - e * ax, shape, sp) for ax in np.eye(3)], axis=-1)
    g = g @ rot.T                                            # object -> world
    return g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-12)


def _material_index(obj_pts: np.ndarray, planes: list[dict[str, Any]], k: int) -> np.ndarray:
    """Each point's material: the side of each splitting plane, as bits, folded onto ``k`` materials."""
    code = np.zeros(obj_pts.shape[0], np.int64)
    for i, pl in enumerate(planes):
        nrm = np.asarray(pl["normal"], np.float64)
        code += ((obj_pts @ (nrm / np.linalg.norm(nrm)) - pl["offset"]) > 0).astype(np.int64) << i
    return code % k


def _angle(e: np.ndarray) -> np.ndarray:
    """Image-plane orientation in [0, pi) of world vectors (image x right, y up, as the camera sees)."""
    return np.mod(np.arctan2(e[:, 1], e[:, 0]), np.pi)


def _shade(p: dict[str, Any], pts: np.ndarray, nrm: np.ndarray, view: np.ndarray, rot: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The four polarizer images (4, N, 3), the diffuse radiance (N, 3) at the hit points (before
    exposure) and the diffuse light's degree of polarization (N,)."""
    n_r = p["refractive_index"]
    alb = np.asarray(p["materials"], np.float64)[_material_index(pts @ rot, p["planes"], len(p["materials"]))]
    ndv = np.clip((nrm * view).sum(-1), 1e-4, 1.0)
    t0 = 1.0 - reflectances(np.zeros(1), n_r)[0][0]          # 1 - F at normal incidence

    def trans(c: np.ndarray) -> np.ndarray:                  # 1 - F(theta), unpolarized, over its normal value
        rs, rp = reflectances(np.arccos(np.clip(c, 0.0, 1.0)), n_r)
        return (1.0 - 0.5 * (rs + rp)) / t0

    irr = np.full(alb.shape, p["ambient"])
    spec = np.zeros(alb.shape)
    s_q = np.zeros(alb.shape)
    s_u = np.zeros(alb.shape)
    a2 = p["alpha"] ** 2

    def g1(c: np.ndarray) -> np.ndarray:                     # Smith's masking of one direction (GGX)
        c = np.clip(c, 1e-4, 1.0)
        return 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))

    for lt in p["lights"]:
        ldir = np.asarray(lt["direction"], np.float64)
        e = lt["intensity"] * np.asarray(lt["color"], np.float64)
        ndl = (nrm @ ldir)
        lit = ndl > 0
        irr += np.where(lit, ndl * trans(ndl) * trans(ndv), 0.0)[:, None] * e
        if p["ks"] <= 0:
            continue
        h = view + ldir
        h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
        ndh = np.clip((nrm * h).sum(-1), 0.0, 1.0)
        dist = a2 / (np.pi * (ndh * ndh * (a2 - 1.0) + 1.0) ** 2)
        cd = np.clip((view * h).sum(-1), 0.0, 1.0)
        rs, rp = reflectances(np.arccos(cd), n_r)
        mag = p["ks"] * dist * g1(ndl) * g1(ndv) * 0.5 * (rs + rp) / (4.0 * ndv)
        mag = np.where(lit, mag, 0.0)
        rho = np.divide(rs - rp, rs + rp, out=np.zeros_like(rs), where=(rs + rp) > 0)
        phi = _angle(np.cross(view, h))
        spec += mag[:, None] * e
        s_q += (mag * rho * np.cos(2 * phi))[:, None] * e
        s_u += (mag * rho * np.sin(2 * phi))[:, None] * e
    dif = alb * irr / np.pi
    rho_d = transmission_dolp(np.arccos(ndv), n_r)
    phi_d = _angle(nrm - ndv[:, None] * view)
    d_q = (rho_d * np.cos(2 * phi_d))[:, None] * dif
    d_u = (rho_d * np.sin(2 * phi_d))[:, None] * dif
    c2, s2 = np.cos(2 * _ANGLES)[:, None, None], np.sin(2 * _ANGLES)[:, None, None]
    stack = (dif + spec)[None] + c2 * (d_q + s_q)[None] + s2 * (d_u + s_u)[None]
    return stack, dif, rho_d


def render_analytic(seed: int, *, size: int = 128) -> FamilyScene:
    """Render scene ``seed`` of this family and pass it through the colour and mono cameras.

    Parameters
    ----------
    seed
        Scene seed, >= 0 (the first family's splits: :func:`polcam.synth.family.split_seeds`).
    size
        Side of the stacks in pixels, even, at least 16 (the sensor is twice that).

    Returns
    -------
    FamilyScene
        As :func:`polcam.synth.family.render_family` gives it, named ``ana-<seed>``: ``stack``
        (4, size, size, 3) and ``mono_stack`` (4, size, size) in [0, 1], ``diffuse`` (size, size, 3)
        in [0, 1], ``mask``, ``clipped``, ``dolp_diffuse``, ``ideal`` and ``params``
        (:func:`draw`).  Deterministic for ``(seed, size)``.

    Examples
    --------
    >>> s = render_analytic(0, size=32)
    >>> s.stack.shape, s.name
    ((4, 32, 32, 3), 'ana-0')
    """
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 16 or size % 2:
        raise PolcamError(f"size {size!r}: expected an even integer, at least 16 (the sensor is twice that, "
                          "a whole number of 4 x 4 IMX250MYR cells)")
    return _render(draw(seed), int(size))


def _render(p: dict[str, Any], size: int) -> FamilyScene:
    """:func:`render_analytic` of the parameters ``p`` (:func:`draw`'s form)."""
    seed = p["seed"]
    n = 2 * int(size)
    rot = np.asarray(p["rotation"], np.float64)
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    yy, xx = np.meshgrid(-c, c, indexing="ij")               # row 0 at the top: image y up
    dirs = np.stack([xx * TAN_HALF_FIELD, yy * TAN_HALF_FIELD, -np.ones_like(xx)], axis=-1).reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    origin = np.array([0.0, 0.0, CAMERA_DISTANCE])
    pts, hit = _march(origin, dirs, rot, p["shape"], p["shape_params"])
    if not hit.any():                                        # pragma: no cover - every shape fills the frame's centre
        raise AssertionError(f"scene {seed}: the object is not seen")
    nrm = _normals(pts[hit], rot, p["shape"], p["shape_params"])
    stack, dif, rho_hit = _shade(p, pts[hit], nrm, -dirs[hit], rot)
    level = float(np.quantile(dif.max(axis=-1), 0.995))
    # the background's radiance relative to the object's brightest diffuse
    ideal = np.zeros((4, n * n, 3)) + level * np.asarray(p["background_rgb"], np.float64)
    diffuse = np.zeros((n * n, 3)) + level * np.asarray(p["background_rgb"], np.float64)
    ideal[:, hit] = stack
    diffuse[hit] = dif
    gain = p["exposure"] / max(level, 1e-9)
    ideal = (ideal * gain).reshape(4, n, n, 3)
    diffuse = (diffuse * gain).reshape(n, n, 3)
    mask = hit.reshape(n, n)
    rho = np.zeros(n * n)
    rho[hit] = rho_hit
    rho = rho.reshape(n, n)
    rng = np.random.default_rng(p["noise_seed"])
    cam = {"full_well": p["full_well"], "read_noise": p["read_noise"], "bit_depth": p["bit_depth"]}
    stack_c = camera_of(mosaic_stack(ideal, layout="imx250myr"), "imx250myr", rng, cam)
    mono = camera_of(mosaic_stack(ideal.mean(axis=-1), layout="imx250mzr"), "imx250mzr", rng, cam)
    truth = cell_means(np.clip(diffuse, 0.0, 1.0), (0, 1)).astype(np.float32)
    obj = cell_means(mask.astype(np.float64), (0, 1)) >= 0.5
    clipped = cell_means((ideal >= 1.0).any(axis=(0, 3)).astype(np.float64), (0, 1)) > 0
    return FamilyScene(
        name=scene_name(seed), seed=int(seed), stack=stack_c, mono_stack=mono, diffuse=truth,
        diffuse_mono=truth.mean(axis=-1), ideal=cell_means(ideal, (1, 2)).astype(np.float32), mask=obj,
        clipped=clipped, dolp_diffuse=np.where(obj, cell_means(rho, (0, 1)), 0.0).astype(np.float32), params=p,
    )
