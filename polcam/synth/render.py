"""Synthetic polarization images with ground truth: the paper's protocol (section 4.1).

Shakeri & Zhang render the Stanford Bunny, Dragon and Armadillo "with the
Blinn-Phong reflectance model under different arbitrary point lighting source
using the pinhole camera model, with uniform and non-uniform albedo texture",
at polarizer angles 0, 45, 90 and 135 degrees.  The paper gives no light
positions, shininess, refractive index, textures, resolution or noise, nor how
polarization enters the rendering; this module fixes them (docs/synthetic.md).

Model
-----
Geometry comes from :func:`polcam.synth.mesh.rasterize` (pinhole camera at
``(0, 0, distance)`` looking down ``-z``; x right, y up).  At each visible
point ``X`` with unit normal ``n``, with ``l`` the unit vector towards the
point light, ``v`` towards the camera and ``h = (l + v) / |l + v|``:

* diffuse radiance ``L_d = albedo * (E * max(n.l, 0) + ambient)`` with
  ``E = light_intensity * light_color``; unpolarized by default;
* specular radiance ``L_s = ks * max(n.h, 0)^shininess * E`` where ``n.l > 0``
  (Blinn-Phong), white when the light is white.

Polarization.  Blinn-Phong's lobe is a distribution of microfacet normals
``h``: the light reaching the camera is mirrored by facets whose normal is
``h``, so the angle of incidence is ``theta_i = angle(v, h)`` (half the angle
between view and light) and the plane of incidence is the plane of ``v`` and
``h`` (which holds ``l``).  Fresnel's equations at refractive index ``n_r``
give the reflectances ``Rs`` (perpendicular, s) and ``Rp`` (parallel, p); the
reflected light has

* degree of linear polarization ``rho_s = (Rs - Rp) / (Rs + Rp)`` (1 at
  Brewster's angle ``atan(n_r)``, 0 at normal and grazing incidence);
* angle of polarization along the s direction ``e_s = v x h``, perpendicular to
  the plane of incidence, because ``Rs >= Rp``: the s component dominates.

The AoLP is the image-plane direction of ``e_s``:
``phi_s = atan2(e_s . y, e_s . x) mod pi``.  Under orthographic viewing this is
the azimuth of ``h`` plus 90 degrees, and at the centre of a highlight
(``n = h``) the azimuth of the surface normal plus 90 degrees.  Under
perspective the plane of incidence contains the camera centre and the light,
so it projects to the image line through the pixel and the light's image: the
specular AoLP is perpendicular to that line.  Only the polarization *state*
comes from Fresnel: the specular *intensity* stays Blinn-Phong's.

Diffuse polarization (``SceneSpec.diffuse_polarization``, off by default):
light scattered below the surface leaves it refracted, with the transmission
Fresnel coefficients ``Ts = 1 - Rs``, ``Tp = 1 - Rp`` at the emission angle
``theta_e = angle(n, v)`` (reciprocity lets the air-side angle be used), so
``rho_d = (Tp - Ts) / (Tp + Ts) = (Rs - Rp) / (2 - Rs - Rp)`` and the p
component dominates: the AoLP is the direction of ``n - (n.v) v`` in the
image, i.e. the azimuth of the normal.  (Atkinson & Hancock 2006 give the
same ``rho_d`` in closed form.)

Polarizer images.  A component of radiance ``L``, degree ``rho`` and angle
``phi`` gives behind a polarizer at angle ``t``::

    I(t) = L * (1 + rho * cos(2 t - 2 phi))

so the *mean of the four polarizer images equals the radiance* ``L`` (the
factor 1/2 of an ideal polarizer is taken into the exposure).  Angles ``t`` and
``phi`` are measured from the image x axis towards the image's up direction
(counter-clockwise on the displayed image), the 45-degree polarizer pointing
to the top-right: the convention of :mod:`polcam.polarimetry`, whose
``fit_sinusoid`` returns ``Ic = L_d + L_s`` and AoLP ``phi_s`` on pure
specular pixels.

Sensor.  The stack is ``I_d(t) + I_s(t)``; then, in this order: shot noise
(Poisson with ``full_well`` electrons at value 1) and Gaussian read noise
(``read_noise`` electrons), clipping to [0, 1] (saturation: the clipped value
stays in the stack), and quantisation to ``bit_depth`` bits.  Ground truth:
``diffuse = clip(L_d, 0, 1)`` (the mean of the four noise-free diffuse-only
polarizer images, clipped), ``specular = stack.mean(0) - diffuse``, so
``diffuse + specular == stack.mean(0)`` holds to float32 rounding; where noise
or saturation act, ``specular`` carries them (it can be slightly negative).

Not modelled: cast shadows, interreflections, light fall-off with distance,
Fresnel modulation of the specular intensity, circular polarization.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from polcam.errors import PolcamError
from polcam.mosaic import ANGLES
from polcam.synth.fresnel import diffuse_dolp, fresnel_reflectance, specular_dolp
from polcam.synth.mesh import Camera, Mesh, load_mesh, rasterize, rotation_matrix
from polcam.synth.output import RAW_LAYOUTS, mosaic, write_scene

__all__ = [
    "RAW_LAYOUTS",
    "Rendered",
    "SceneSpec",
    "Texture",
    "diffuse_dolp",
    "fresnel_reflectance",
    "mosaic",
    "render",
    "specular_dolp",
    "write_scene",
]

RGB = tuple[float, float, float]

_TEXTURE_KINDS = ("uniform", "noise", "stripes", "checker")
_BACKGROUNDS = ("black", "plane")
# depth of the backdrop plane behind the origin (the object fills [-0.5, 0.5]^3)
_PLANE_Z = -0.75


# ---------------------------------------------------------------- scene specs
def _rgb(value: Any, what: str, *, lo: float = 0.0, hi: float | None = 1.0) -> RGB:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        arr = np.array([])
    if arr.size == 1:
        arr = np.repeat(arr, 3)
    if arr.size != 3 or not np.all(np.isfinite(arr)) or np.any(arr < lo) or (hi is not None and np.any(arr > hi)):
        rng = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise PolcamError(f"{what} {value!r}: expected an RGB triple (or one number) with values in {rng}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _positive(value: Any, what: str, *, allow_zero: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = float("nan")
    if not math.isfinite(x) or x < 0 or (x == 0 and not allow_zero):
        raise PolcamError(f"{what} {value!r}: expected a {'non-negative' if allow_zero else 'positive'} number")
    return x


@dataclass(frozen=True)
class Texture:
    """A procedural albedo, evaluated on the object's surface (a solid texture).

    Textures are functions of the surface point in the object's own frame
    (the normalised mesh in the unit box, before the scene rotation), so they
    stick to the object and need no UV coordinates.

    Attributes
    ----------
    kind
        ``uniform``: ``colors[0]`` everywhere.
        ``noise``: smooth value noise (two octaves of a seeded random lattice
        with cell size ``scale``, smoothstep-interpolated) mapped through the
        colour ramp ``colors``.
        ``stripes``: bands of width ``scale`` across ``direction``, cycling
        through ``colors``.
        ``checker``: cubes of side ``scale``, each coloured with one of
        ``colors`` picked by a seeded hash of the cube.
    colors
        RGB albedos in [0, 1].
    scale
        Feature size in unit-box units (the object is 1 across), > 0.
    seed
        Seed of the noise lattice / checker hash (deterministic).
    direction
        Stripe direction (normalised internally).
    """

    kind: str = "uniform"
    colors: tuple[RGB, ...] = ((0.6, 0.6, 0.6),)
    scale: float = 0.15
    seed: int = 0
    direction: tuple[float, float, float] = (1.0, 0.3, 0.2)

    def __post_init__(self) -> None:
        if self.kind not in _TEXTURE_KINDS:
            raise PolcamError(f"texture kind {self.kind!r}: expected one of {', '.join(_TEXTURE_KINDS)}")
        cols = tuple(_rgb(c, "texture colour") for c in self.colors)
        if not cols:
            raise PolcamError("texture colors: expected at least one RGB colour")
        object.__setattr__(self, "colors", cols)
        object.__setattr__(self, "scale", _positive(self.scale, "texture scale"))
        d = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        if d.size != 3 or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise PolcamError(f"stripe direction {self.direction!r}: expected a non-zero 3-vector")
        object.__setattr__(self, "direction", tuple(float(x) for x in d))

    def evaluate(self, points: np.ndarray) -> np.ndarray:
        """Albedo at object-frame points.

        Parameters
        ----------
        points
            (N, 3) coordinates in the unit box.

        Returns
        -------
        numpy.ndarray
            (N, 3) float64 albedo in [0, 1].
        """
        p = np.asarray(points, dtype=np.float64)
        cols = np.asarray(self.colors, dtype=np.float64)
        if self.kind == "uniform" or len(p) == 0:
            return np.broadcast_to(cols[0], p.shape).copy()
        if self.kind == "stripes":
            d = np.asarray(self.direction) / np.linalg.norm(self.direction)
            idx = np.floor(p @ d / self.scale).astype(np.int64) % len(cols)
            return cols[idx]
        if self.kind == "checker":
            cell = np.floor(p / self.scale).astype(np.int64)
            rng = np.random.default_rng(self.seed)
            perm = rng.permutation(256)
            h = perm[(cell[:, 0] + perm[(cell[:, 1] + perm[cell[:, 2] & 255]) & 255]) & 255]
            return cols[h % len(cols)]
        # smooth value noise, two octaves, mapped through the colour ramp
        rng = np.random.default_rng(self.seed)
        t = np.zeros(len(p))
        weight_sum = 0.0
        for octave, weight in ((1.0, 1.0), (2.0, 0.5)):
            cell = self.scale / octave
            g = int(np.ceil(1.2 / cell)) + 3
            lattice = rng.random((g, g, g))
            q = (p + 0.6) / cell
            i0 = np.clip(np.floor(q).astype(np.int64), 0, g - 2)
            f = np.clip(q - i0, 0.0, 1.0)
            f = f * f * (3 - 2 * f)
            acc = np.zeros(len(p))
            for dx in (0, 1):
                wx = f[:, 0] if dx else 1 - f[:, 0]
                for dy in (0, 1):
                    wy = f[:, 1] if dy else 1 - f[:, 1]
                    for dz in (0, 1):
                        wz = f[:, 2] if dz else 1 - f[:, 2]
                        acc += wx * wy * wz * lattice[i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz]
            t += weight * acc
            weight_sum += weight
        t = np.clip(t / weight_sum, 0.0, 1.0)
        # value noise concentrates around 0.5: stretch its central range over the ramp
        t = np.clip((t - 0.25) / 0.5, 0.0, 1.0)
        if len(cols) == 1:
            return np.broadcast_to(cols[0], p.shape).copy()
        x = t * (len(cols) - 1)
        k = np.minimum(np.floor(x).astype(np.int64), len(cols) - 2)
        a = (x - k)[:, None]
        return cols[k] * (1 - a) + cols[k + 1] * a


@dataclass(frozen=True)
class SceneSpec:
    """Everything that defines a synthetic scene (see docs/synthetic.md).

    Attributes
    ----------
    name
        Label of the scene.
    mesh
        ``bunny``, ``dragon``, ``armadillo``, ``sphere``, an OBJ path, or a
        :class:`polcam.synth.mesh.Mesh` (used as given: not normalised).
    rotation
        Object rotation in degrees about x, then y, then z (world axes),
        applied to the normalised mesh.
    albedo
        Diffuse albedo: an RGB triple in [0, 1] or a :class:`Texture`.
    light_position
        Point light position in world coordinates (camera at (0, 0, distance)).
    light_color
        RGB colour of the light, in [0, 1] (white: (1, 1, 1)).
    light_intensity
        Irradiance scale ``E`` (>= 0): a white, fully lit surface facing the
        light with albedo 1 has diffuse radiance ``E``.
    ambient
        Unpolarized ambient term added to the diffuse: ``albedo * ambient``.
    ks, shininess
        Blinn-Phong specular coefficient (>= 0) and exponent (> 0).
    refractive_index
        Of the dielectric surface, > 1 (sets the Fresnel DoLP).
    diffuse_polarization
        Give the diffuse component its (weak) transmission-Fresnel polarization.
    focal, camera_distance
        Pinhole camera: focal length in image widths, distance to the origin.
    background
        ``black`` (nothing behind the object) or ``plane`` (a Lambertian,
        unpolarized backdrop plane facing the camera at z = -0.75, lit by
        the same light, part of the ground-truth diffuse, outside ``mask``).
    background_albedo
        RGB albedo of the backdrop plane.
    full_well
        Electrons at value 1.0 for shot noise (Poisson), or ``None`` for no
        noise at all.
    read_noise
        Gaussian read noise in electrons RMS (needs ``full_well``).
    bit_depth
        Quantisation of the stack to this many bits (1..16), or ``None``.
    normals
        ``vertex`` (smooth shading) or ``face`` (flat).
    description
        What the scene is for.
    """

    name: str = "scene"
    mesh: str | Mesh = "bunny"
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    albedo: RGB | Texture = (0.6, 0.6, 0.6)
    light_position: tuple[float, float, float] = (1.5, 2.0, 3.0)
    light_color: RGB = (1.0, 1.0, 1.0)
    light_intensity: float = 1.0
    ambient: float = 0.0
    ks: float = 0.3
    shininess: float = 40.0
    refractive_index: float = 1.5
    diffuse_polarization: bool = False
    focal: float = 2.0
    camera_distance: float = 2.5
    background: str = "black"
    background_albedo: RGB = (0.15, 0.15, 0.15)
    full_well: float | None = None
    read_noise: float = 0.0
    bit_depth: int | None = None
    normals: str = "vertex"
    description: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.albedo, Texture):
            object.__setattr__(self, "albedo", _rgb(self.albedo, f"scene {self.name!r}: albedo"))
        object.__setattr__(self, "light_color", _rgb(self.light_color, f"scene {self.name!r}: light_color"))
        object.__setattr__(self, "background_albedo",
                           _rgb(self.background_albedo, f"scene {self.name!r}: background_albedo"))
        for key in ("rotation", "light_position"):
            val = np.asarray(getattr(self, key), dtype=np.float64).reshape(-1)
            if val.size != 3 or not np.all(np.isfinite(val)):
                raise PolcamError(f"scene {self.name!r}: {key} {getattr(self, key)!r}: expected 3 finite numbers")
            object.__setattr__(self, key, tuple(float(x) for x in val))
        for key, zero in (("light_intensity", True), ("ambient", True), ("ks", True), ("shininess", False),
                          ("focal", False), ("camera_distance", False), ("read_noise", True)):
            object.__setattr__(self, key, _positive(getattr(self, key), f"scene {self.name!r}: {key}",
                                                    allow_zero=zero))
        n = _positive(self.refractive_index, f"scene {self.name!r}: refractive_index")
        if n <= 1:
            raise PolcamError(f"scene {self.name!r}: refractive_index {n}: expected a number > 1")
        if self.background not in _BACKGROUNDS:
            raise PolcamError(f"scene {self.name!r}: background {self.background!r}: "
                              f"expected one of {', '.join(_BACKGROUNDS)}")
        if self.normals not in ("vertex", "face"):
            raise PolcamError(f"scene {self.name!r}: normals {self.normals!r}: expected 'vertex' or 'face'")
        if self.full_well is not None:
            object.__setattr__(self, "full_well", _positive(self.full_well, f"scene {self.name!r}: full_well"))
        elif self.read_noise > 0:
            raise PolcamError(f"scene {self.name!r}: read_noise {self.read_noise} given without full_well: "
                              "expected full_well (electrons at value 1) to scale it")
        if self.bit_depth is not None and not (
            isinstance(self.bit_depth, (int, np.integer)) and 1 <= self.bit_depth <= 16
        ):
            raise PolcamError(f"scene {self.name!r}: bit_depth {self.bit_depth!r}: expected None or 1..16")
        if not isinstance(self.mesh, (str, Path, Mesh)):
            raise PolcamError(f"scene {self.name!r}: mesh {self.mesh!r}: expected a name, a path or a Mesh")

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON-serialisable data (a Mesh object is named, not stored)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            val = getattr(self, f.name)
            if isinstance(val, Texture):
                val = dataclasses.asdict(val)
            elif isinstance(val, Mesh):
                val = f"<mesh {val.name or 'unnamed'}: {len(val.vertices)} vertices, {len(val.faces)} faces>"
            elif isinstance(val, Path):
                val = str(val)
            out[f.name] = val
        return out

    @property
    def camera(self) -> Camera:
        """The scene's pinhole camera."""
        return Camera(self.focal, self.camera_distance)


@dataclass
class Rendered:
    """A rendered scene with its ground truth.

    Attributes
    ----------
    stack
        (4, H, W, 3) float32 in [0, 1]: the images behind polarizers at 0, 45,
        90, 135 degrees, RGB, after noise, saturation and quantisation.
    diffuse
        (H, W, 3) float32 in [0, 1]: noise-free diffuse radiance (the mean of
        the four diffuse-only polarizer images), clipped to [0, 1]; on the
        scale of one polarization image.
    specular
        (H, W, 3) float32: ``stack.mean(0) - diffuse`` (noise and clipping
        included, so it may dip slightly below 0).
    mask
        (H, W) bool, True on the object.
    aolp_true
        (H, W) float32 AoLP of the specular component in radians, [0, pi),
        image convention of :mod:`polcam.polarimetry`; 0 off the object.
    dolp_spec
        (H, W) float32 Fresnel DoLP of the specular component, [0, 1]; 0 off
        the object.
    info
        Scene parameters, seed, size, timing, and the measured statistics
        ``saturated_fraction`` (object pixels with any polarizer image channel
        at 1) and ``specular_ratio`` (sum of noise-free specular radiance over
        sum of diffuse radiance, object pixels, all channels).
    depth
        (H, W) float32 depth along the optical axis, ``inf`` where no surface.
    normal
        (H, W, 3) float32 unit world normals of the object, 0 off it.
    """

    stack: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    mask: np.ndarray
    aolp_true: np.ndarray
    dolp_spec: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)
    depth: np.ndarray | None = None
    normal: np.ndarray | None = None


def _unit(x: np.ndarray) -> np.ndarray:
    ln = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, ln, out=np.zeros_like(x), where=ln > 0)


def _image_angle(e: np.ndarray) -> np.ndarray:
    """Image-plane orientation in [0, pi) of world vectors (x right, y up)."""
    a = np.mod(np.arctan2(e[..., 1], e[..., 0]), np.pi)
    return np.where(a >= np.pi, 0.0, a)


def render(scene: SceneSpec, *, size: int = 256, seed: int = 0) -> Rendered:
    """Render a scene's four polarizer images and its ground truth.

    Parameters
    ----------
    scene
        The scene (:mod:`polcam.synth.scenes` holds the paper's).
    size
        Image side in pixels (square images), >= 1.
    seed
        Seed of the sensor noise (textures carry their own seed).

    Returns
    -------
    Rendered
        ``stack`` (4, size, size, 3) and the ground truth; see the module
        docstring for the model.

    Raises
    ------
    PolcamError
        A bad size, scene or mesh.
    """
    if not isinstance(scene, SceneSpec):
        raise PolcamError(f"scene of type {type(scene).__name__}: expected a SceneSpec")
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 1:
        raise PolcamError(f"size {size!r}: expected a positive integer (image side in pixels)")
    t_start = time.perf_counter()
    size = int(size)
    ras, pos, nrm, surf = _geometry(scene, size)
    mask = ras.mask
    light = np.asarray(scene.light_position, dtype=np.float64)
    l_dir = _unit(light - pos)
    v_dir = _unit(scene.camera.center - pos)
    h_dir = _unit(l_dir + v_dir)
    l_d, l_s = _radiance(scene, ras, nrm, surf, l_dir, h_dir)
    stack, rho_s, phi_s = _polarizer_images(scene, l_d, l_s, mask, surf, nrm, v_dir, h_dir)
    stack32 = _sensor(scene, stack, seed)
    diffuse = np.clip(l_d, 0.0, 1.0).astype(np.float32)
    specular = stack32.mean(axis=0, dtype=np.float32) - diffuse

    sat = (stack32 >= 1.0).any(axis=(0, 3)) & mask
    n_obj = int(mask.sum())
    sum_d = float(l_d[mask].sum())
    info: dict[str, Any] = {
        "scene": scene.name,
        "size": size,
        "seed": int(seed),
        "spec": scene.to_dict(),
        "object_pixels": n_obj,
        "saturated_fraction": float(sat.sum() / n_obj) if n_obj else 0.0,
        "specular_ratio": float(l_s[mask].sum() / sum_d) if sum_d > 0 else 0.0,
        "max_radiance": float((l_d + l_s).max()),
        "polarizer_model": "I(t) = L (1 + rho cos(2t - 2 phi)); mean of the four images = radiance L",
        "angles_deg": list(ANGLES),
        "seconds": time.perf_counter() - t_start,
    }
    return Rendered(
        stack=stack32,
        diffuse=diffuse,
        specular=specular,
        mask=mask,
        aolp_true=phi_s.astype(np.float32),
        dolp_spec=rho_s.astype(np.float32),
        info=info,
        depth=np.where(mask, ras.depth, np.inf).astype(np.float32),
        normal=np.where(mask[..., None], ras.normal, 0).astype(np.float32),
    )


def _geometry(scene: SceneSpec, size: int) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray]:
    """The rasterized object and, behind it, the backdrop plane (``background="plane"``).

    Returns the rasterization, the world position and unit normal of every pixel's surface point
    ((size, size, 3) float64; the object's only, zeros elsewhere, without a plane) and the (size,
    size) mask of pixels that see a surface.
    """
    cam = scene.camera
    base = scene.mesh if isinstance(scene.mesh, Mesh) else load_mesh(scene.mesh)
    rot = rotation_matrix(scene.rotation)
    world = base.transformed(rot)
    ras = rasterize(world, cam, size, normals=scene.normals, object_transform=(rot, np.zeros(3)))
    mask = ras.mask
    pos = ras.position.astype(np.float64)
    nrm = ras.normal.astype(np.float64)
    surf = mask.copy()
    if scene.background == "plane":
        rays = cam.rays(size, size)
        t = (_PLANE_Z - cam.distance) / rays[..., 2]
        bg = ~mask
        pos[bg] = cam.center + t[bg, None] * rays[bg]
        nrm[bg] = (0.0, 0.0, 1.0)
        surf[:] = True
    return ras, pos, nrm, surf


def _radiance(scene: SceneSpec, ras: Any, nrm: np.ndarray, surf: np.ndarray, l_dir: np.ndarray,
              h_dir: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Diffuse ``L_d = albedo (E max(n.l, 0) + ambient)`` and Blinn-Phong specular ``L_s = ks max(n.h, 0)^s E``.

    Each (H, W, 3) float64; the specular only on the object where ``n.l > 0``, the diffuse 0 where
    no surface is seen.
    """
    mask = ras.mask
    ndl = np.einsum("...d,...d->...", nrm, l_dir)
    ndh = np.einsum("...d,...d->...", nrm, h_dir)
    irr = scene.light_intensity * np.asarray(scene.light_color)
    albedo = np.zeros(mask.shape + (3,))
    if isinstance(scene.albedo, Texture):
        albedo[mask] = scene.albedo.evaluate(ras.object_position[mask].astype(np.float64))
    else:
        albedo[mask] = scene.albedo
    if scene.background == "plane":
        albedo[~mask] = scene.background_albedo
    lit = np.maximum(ndl, 0.0)
    l_d = albedo * (lit[..., None] * irr + scene.ambient)
    l_d[~surf] = 0.0
    lobe = np.where(mask & (ndl > 0), np.power(np.maximum(ndh, 0.0), scene.shininess), 0.0)
    l_s = scene.ks * lobe[..., None] * irr
    return l_d, l_s


def _polarizer_images(scene: SceneSpec, l_d: np.ndarray, l_s: np.ndarray, mask: np.ndarray, surf: np.ndarray,
                      nrm: np.ndarray, v_dir: np.ndarray,
                      h_dir: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The noise-free images behind the four polarizers, ``I(t) = L (1 + rho cos(2t - 2 phi))`` per component.

    Specular: microfacet normal ``h``, plane of incidence (v, h); diffuse (with
    ``diffuse_polarization``): the emission angle and the normal's azimuth.  Returns the stack (4,
    H, W, 3) float64 and the specular DoLP and AoLP (H, W; 0 off the object).
    """
    cos_i = np.clip(np.einsum("...d,...d->...", v_dir, h_dir), 0.0, 1.0)
    theta_i = np.arccos(cos_i)
    rho_s = np.where(mask, specular_dolp(theta_i, scene.refractive_index), 0.0)
    phi_s = np.where(mask, _image_angle(np.cross(v_dir, h_dir)), 0.0)
    angles = np.deg2rad(np.asarray(ANGLES, dtype=np.float64))
    cos_s = np.cos(2 * angles[:, None, None] - 2 * phi_s[None])  # (4, H, W)
    stack = l_s[None] * (1.0 + (rho_s[None] * cos_s)[..., None])
    if scene.diffuse_polarization:
        ndv = np.clip(np.einsum("...d,...d->...", nrm, v_dir), 0.0, 1.0)
        rho_d = np.where(surf, diffuse_dolp(np.arccos(ndv), scene.refractive_index), 0.0)
        phi_d = _image_angle(nrm - ndv[..., None] * v_dir)
        cos_d = np.cos(2 * angles[:, None, None] - 2 * phi_d[None])
        stack += l_d[None] * (1.0 + (rho_d[None] * cos_d)[..., None])
    else:
        stack += l_d[None]
    return stack, rho_s, phi_s


def _sensor(scene: SceneSpec, stack: np.ndarray, seed: int) -> np.ndarray:
    """Shot and read noise, saturation at 1 and quantisation to ``bit_depth`` bits; float32 in [0, 1]."""
    rng = np.random.default_rng(seed)
    if scene.full_well is not None:
        fw = scene.full_well
        electrons = rng.poisson(np.maximum(stack, 0.0) * fw).astype(np.float64)
        if scene.read_noise > 0:
            electrons += rng.normal(0.0, scene.read_noise, size=stack.shape)
        stack = electrons / fw
    stack = np.clip(stack, 0.0, 1.0)
    if scene.bit_depth is not None:
        top = float(2 ** int(scene.bit_depth) - 1)
        stack = np.round(stack * top) / top
    return stack.astype(np.float32)
