"""The paper's synthetic scene sets, as data, so that anyone regenerates the same images.

Shakeri & Zhang (section 4.1, Tables 1 and 2) evaluate on Bunny1..Bunny7
("under different illumination and specular reflections", weak to strong,
Bunny7 "in the presence of saturated regions under varying albedo"), and on
Dragon1, Dragon2 and Armadillo ("under different conditions with saturated
regions").  The paper gives none of the rendering parameters; the values below
are polcam's choices, tabulated with their measured specular-to-diffuse ratio
and saturated fraction in docs/synthetic.md.  Along Bunny1..Bunny7 the
specular strength rises (``ks`` and light intensity up, ``shininess`` down:
wider, brighter lobes) and so does the share of saturated pixels.

Every scene has white light (the dichromatic model's neutral illuminant, as the
chromaticity-based baselines assume), a black background, sensor noise
(:data:`SENSOR`: 20000 electrons full well, 4 electrons read noise) and
12-bit quantisation; the noise is seeded by :func:`polcam.synth.render.render`.

Usage::

    from polcam.synth.scenes import scene
    from polcam.synth.render import render
    r = render(scene("Bunny4"), size=256, seed=0)

``polcam bench scenes [--size 256] [--seed 0]`` prints the measured
statistics of every scene as a Markdown table (docs/synthetic.md).
"""

from __future__ import annotations

from polcam.errors import PolcamError
from polcam.synth.render import SceneSpec, Texture, render

__all__ = ["BUNNY", "SCENES", "STRESS", "SENSOR", "scene", "scene_names", "statistics_table"]

#: Sensor settings shared by the paper's scenes.
SENSOR: dict = {"full_well": 20000.0, "read_noise": 4.0, "bit_depth": 12}

_BUNNY_VIEW = {"mesh": "bunny", "rotation": (0.0, -25.0, 0.0), "focal": 2.0, "camera_distance": 2.5}
_DRAGON_VIEW = {"mesh": "dragon", "rotation": (0.0, 90.0, 0.0), "focal": 1.4, "camera_distance": 1.6}
_ARMADILLO_VIEW = {"mesh": "armadillo", "rotation": (0.0, -20.0, 0.0), "focal": 2.0, "camera_distance": 2.6}

_MULTI = Texture(
    kind="noise",
    colors=((0.80, 0.35, 0.25), (0.85, 0.70, 0.30), (0.35, 0.65, 0.40), (0.30, 0.45, 0.80), (0.65, 0.40, 0.70)),
    scale=0.18,
    seed=7,
)
_CHECKER = Texture(
    kind="checker",
    colors=((0.75, 0.30, 0.25), (0.30, 0.60, 0.35), (0.30, 0.40, 0.80), (0.80, 0.70, 0.30)),
    scale=0.12,
    seed=3,
)
_STRIPES = Texture(
    kind="stripes",
    colors=((0.70, 0.55, 0.35), (0.40, 0.30, 0.25), (0.55, 0.60, 0.50)),
    scale=0.06,
    direction=(0.2, 1.0, 0.1),
)


def _spec(name: str, view: dict, description: str, **kw) -> SceneSpec:
    return SceneSpec(name=name, description=description, **view, **SENSOR, **kw)


def _build() -> dict[str, SceneSpec]:
    s: dict[str, SceneSpec] = {}
    s["Bunny1"] = _spec(
        "Bunny1", _BUNNY_VIEW, "weak, tight highlights; no saturation",
        albedo=(0.70, 0.50, 0.35), light_position=(2.0, 2.0, 4.0), light_intensity=0.75,
        ks=0.10, shininess=90.0,
    )
    s["Bunny2"] = _spec(
        "Bunny2", _BUNNY_VIEW, "weak highlights, light from the upper left",
        albedo=(0.45, 0.55, 0.75), light_position=(-2.0, 2.5, 3.5), light_intensity=0.75,
        ks=0.20, shininess=70.0,
    )
    s["Bunny3"] = _spec(
        "Bunny3", _BUNNY_VIEW, "moderate highlights, frontal light",
        albedo=(0.60, 0.65, 0.40), light_position=(0.8, 1.5, 4.0), light_intensity=0.8,
        ks=0.35, shininess=50.0,
    )
    s["Bunny4"] = _spec(
        "Bunny4", _BUNNY_VIEW, "strong highlights, light from the upper right",
        albedo=(0.75, 0.40, 0.40), light_position=(2.5, 2.5, 2.5), light_intensity=0.8,
        ks=0.50, shininess=35.0,
    )
    s["Bunny5"] = _spec(
        "Bunny5", _BUNNY_VIEW, "strong, wide highlights; some saturation",
        albedo=(0.40, 0.60, 0.55), light_position=(-1.5, 3.0, 3.0), light_intensity=0.85,
        ks=0.60, shininess=22.0,
    )
    s["Bunny6"] = _spec(
        "Bunny6", _BUNNY_VIEW, "very strong, wide highlights; saturated regions",
        albedo=(0.65, 0.50, 0.30), light_position=(1.0, 2.0, 3.5), light_intensity=0.9,
        ks=0.90, shininess=14.0,
    )
    s["Bunny7"] = _spec(
        "Bunny7", _BUNNY_VIEW, "varying albedo (smooth multi-colour noise) with saturated highlights",
        albedo=_MULTI, light_position=(1.5, 2.5, 3.0), light_intensity=1.0,
        ks=1.00, shininess=12.0,
    )
    s["Dragon1"] = _spec(
        "Dragon1", _DRAGON_VIEW, "uniform albedo, strong highlights with saturated regions",
        albedo=(0.55, 0.60, 0.40), light_position=(1.0, 3.0, 3.0), light_intensity=0.9,
        ks=0.60, shininess=25.0,
    )
    s["Dragon2"] = _spec(
        "Dragon2", _DRAGON_VIEW, "checker albedo, grazing light, very strong saturated highlights",
        albedo=_CHECKER, light_position=(-3.0, 1.5, 2.0), light_intensity=1.0,
        ks=1.00, shininess=10.0,
    )
    s["Armadillo"] = _spec(
        "Armadillo", _ARMADILLO_VIEW, "striped albedo, strong highlights with saturated regions",
        albedo=_STRIPES, light_position=(2.0, 2.0, 3.0), light_intensity=0.9,
        ks=0.70, shininess=20.0,
    )
    return s


#: The paper's scenes by name: Bunny1..Bunny7, Dragon1, Dragon2, Armadillo.
SCENES: dict[str, SceneSpec] = _build()

def _build_stress() -> dict[str, SceneSpec]:
    """Scenes that break one method assumption each (polcam's own set, beyond the paper)."""
    s: dict[str, SceneSpec] = {}
    s["WhiteGrey"] = _spec(
        "WhiteGrey", _BUNNY_VIEW, "white and grey checker albedo on a grey backdrop: the dichromatic "
        "model's blind spot (a white surface has the illuminant's colour)",
        albedo=Texture(kind="checker", colors=((0.85, 0.85, 0.85), (0.45, 0.45, 0.45), (0.70, 0.70, 0.70)),
                       scale=0.2, seed=5),
        light_position=(1.5, 2.0, 3.0), light_intensity=0.8, ks=0.5, shininess=30.0,
        background="plane", background_albedo=(0.5, 0.5, 0.5),
    )
    s["Multicolour"] = _spec(
        "Multicolour", _BUNNY_VIEW, "multi-coloured checker texture (six hues and white): no single "
        "diffuse colour per neighbourhood",
        albedo=Texture(kind="checker", colors=((0.8, 0.2, 0.2), (0.2, 0.7, 0.25), (0.2, 0.3, 0.85),
                                               (0.85, 0.75, 0.2), (0.7, 0.25, 0.75), (0.2, 0.7, 0.75),
                                               (0.8, 0.8, 0.8)), scale=0.1, seed=11),
        light_position=(1.0, 2.0, 3.5), light_intensity=0.8, ks=0.6, shininess=25.0,
    )
    s["Brewster"] = _spec(
        "Brewster", _BUNNY_VIEW, "light from behind the object's side: specular seen near Brewster's "
        "angle, strongly polarized",
        albedo=(0.6, 0.45, 0.3), light_position=(3.0, 0.8, -1.0), light_intensity=0.9, ambient=0.15,
        ks=0.8, shininess=20.0,
    )
    s["Normal"] = _spec(
        "Normal", _BUNNY_VIEW, "light beside the camera: specular near normal incidence, weakly polarized",
        albedo=(0.3, 0.5, 0.6), light_position=(0.3, 0.4, 3.5), light_intensity=0.8,
        ks=0.6, shininess=30.0,
    )
    s["Tinted"] = _spec(
        "Tinted", _BUNNY_VIEW, "a warm tinted illuminant (1.0, 0.75, 0.5) on a uniform albedo",
        albedo=(0.5, 0.6, 0.7), light_position=(1.5, 2.5, 3.0), light_color=(1.0, 0.75, 0.5),
        light_intensity=0.9, ks=0.6, shininess=25.0,
    )
    s["DiffusePol"] = _spec(
        "DiffusePol", _BUNNY_VIEW, "partially polarized diffuse light (AoLP perpendicular to the "
        "specular's), refractive index 1.8, side light",
        albedo=(0.7, 0.35, 0.25), light_position=(2.5, 1.5, 2.0), light_intensity=0.9,
        ks=0.4, shininess=30.0, refractive_index=1.8, diffuse_polarization=True,
    )
    s["Saturated"] = _spec(
        "Saturated", _BUNNY_VIEW, "bright light, strong wide highlights clipped at the sensor's white level",
        albedo=(0.55, 0.35, 0.6), light_position=(1.0, 2.0, 3.0), light_intensity=1.3,
        ks=1.5, shininess=12.0,
    )
    s["Noise8"] = SceneSpec(
        name="Noise8", description="8-bit quantisation and a noisy sensor (2000 electrons full well, "
        "8 electrons read noise)", **_BUNNY_VIEW,
        albedo=_MULTI, light_position=(1.5, 2.5, 3.0), light_intensity=0.8, ks=0.5, shininess=25.0,
        full_well=2000.0, read_noise=8.0, bit_depth=8,
    )
    return s


#: Scenes beyond the paper, each breaking one method assumption (docs/benchmarks.md lists them).
STRESS: dict[str, SceneSpec] = _build_stress()

#: The Bunny series, weak to strong specular reflection.
BUNNY: tuple[str, ...] = tuple(f"Bunny{i}" for i in range(1, 8))


def scene_names() -> tuple[str, ...]:
    """Names of :data:`SCENES`, in the paper's order."""
    return tuple(SCENES)


def scene(name: str) -> SceneSpec:
    """The scene called ``name`` (case-insensitive), from :data:`SCENES` or :data:`STRESS`.

    Raises
    ------
    PolcamError
        An unknown name; the message lists the known ones.
    """
    for key, spec in {**SCENES, **STRESS}.items():
        if key.lower() == str(name).lower():
            return spec
    raise PolcamError(f"synthetic scene {name!r} is not known; expected one of "
                      f"{', '.join([*SCENES, *STRESS])}")


def statistics_table(*, size: int = 256, seed: int = 0) -> str:
    """Render every scene and tabulate its measured statistics (Markdown).

    Columns: saturated fraction (object pixels with any polarizer image
    channel at 1), specular-to-diffuse ratio (noise-free radiance summed over
    the object), object coverage, and the render time.

    Parameters
    ----------
    size
        Image side in pixels.
    seed
        Noise seed.

    Returns
    -------
    str
        The table, one line per scene.
    """
    lines = [
        f"| scene (size {size}, seed {seed}) | saturated fraction | specular / diffuse | object pixels | seconds |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, spec in SCENES.items():
        r = render(spec, size=size, seed=seed)
        i = r.info
        lines.append(
            f"| {name} | {i['saturated_fraction']:.4f} | {i['specular_ratio']:.3f} | "
            f"{i['object_pixels'] / size**2:.1%} | {i['seconds']:.2f} |"
        )
    return "\n".join(lines)
