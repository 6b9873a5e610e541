"""The analytic scene family: a second renderer, checked against closed forms and the first one's Fresnel code."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polcam.errors import PolcamError
from polcam.polarimetry import aolp, dolp
from polcam.synth import analytic
from polcam.synth.analytic import SHAPES, draw, reflectances, render_analytic, transmission_dolp
from polcam.synth.fresnel import diffuse_dolp, fresnel_reflectance


def test_fresnel_in_angle_form_agrees_with_the_first_renderers_cosine_form():
    theta = np.linspace(0.0, np.pi / 2 - 1e-3, 200)
    for n in (1.3, 1.5, 1.9):
        rs, rp = reflectances(theta, n)
        ref_s, ref_p = fresnel_reflectance(theta, n)
        np.testing.assert_allclose(rs, ref_s, atol=1e-12)
        np.testing.assert_allclose(rp, ref_p, atol=1e-12)
        # Brewster's angle: no p reflection
        assert reflectances(np.array([math.atan(n)]), n)[1][0] == pytest.approx(0.0, abs=1e-12)
        # Atkinson & Hancock's closed form against (Rs - Rp) / (2 - Rs - Rp) of the refracted ray
        np.testing.assert_allclose(transmission_dolp(theta, n), diffuse_dolp(theta, n), atol=1e-12)


def _params(**over) -> dict:
    p = {"seed": 0, "shape": "sphere", "shape_params": {"radius": 0.5}, "rotation": np.eye(3).tolist(),
         "materials": [(0.6, 0.6, 0.6)], "material_kinds": ["achromatic"], "planes": [], "ks": 0.0,
         "alpha": 0.15, "refractive_index": 1.5, "light": "white",
         "lights": [{"direction": (0.0, 0.0, 1.0), "color": (1.0, 1.0, 1.0), "intensity": 1.0}],
         "ambient": 0.05, "exposure": 0.7, "background": "black", "background_rgb": (0.0, 0.0, 0.0),
         "full_well": 20000.0, "read_noise": 3.0, "bit_depth": 12, "noise_seed": 1}
    p.update(over)
    return p


def _sphere_geometry(size: int, radius: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form ray-sphere hits of the renderer's camera at cell resolution (centres of 2 x 2 sensor
    pixels): emission angle, image-plane angle of the normal (x right, y up) and a hit mask."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    yy, xx = np.meshgrid(-c, c, indexing="ij")
    d = np.stack([xx * analytic.TAN_HALF_FIELD, yy * analytic.TAN_HALF_FIELD, -np.ones_like(xx)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = np.array([0.0, 0.0, analytic.CAMERA_DISTANCE])
    b = (d * o).sum(-1)
    disc = b * b - (o @ o - radius**2)
    hit = disc > 0
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    nrm = (o + t[..., None] * d) / radius
    emission = np.arccos(np.clip((nrm * -d).sum(-1), 0.0, 1.0))
    return emission, np.mod(np.arctan2(nrm[..., 1], nrm[..., 0]), np.pi), hit


def test_a_matte_sphere_polarizes_its_rims_radially_by_the_transmission_degree():
    size = 64
    s = analytic._render(_params(), size)
    grey = s.ideal.mean(axis=-1).astype(np.float64)                 # (4, H, W), before the camera
    emission, radial, hit = _sphere_geometry(size)
    inner = hit & (emission < np.radians(75)) & (emission > np.radians(35))
    assert inner.sum() > 300 and s.mask[inner].all()
    np.testing.assert_allclose(dolp(grey)[inner], transmission_dolp(emission[inner], 1.5), atol=0.01)
    # AoLP along the normal's azimuth (image y up): the rims are polarized radially
    diff = np.angle(np.exp(2j * (aolp(grey)[inner] - radial[inner]))) / 2
    assert np.degrees(np.abs(diff)).max() < 2.0
    # no specular light: the mean over the angles is the diffuse (the truth, before clipping)
    np.testing.assert_allclose(s.ideal.mean(axis=0)[s.mask], s.diffuse[s.mask], atol=1e-5)


def test_a_glossy_highlight_has_fresnels_specular_degree_across_the_plane_of_incidence():
    size = 64
    light = (math.sin(math.radians(60)), 0.0, math.cos(math.radians(60)))   # 60 degrees towards +x
    s = analytic._render(_params(materials=[(0.01, 0.01, 0.01)], ks=3.0, alpha=0.12,
                                 lights=[{"direction": light, "color": (1.0, 1.0, 1.0), "intensity": 1.0}]), size)
    grey = s.ideal.mean(axis=-1).astype(np.float64)
    peak = np.unravel_index(np.argmax(grey.mean(axis=0)), grey.shape[1:])
    assert peak[1] > size // 2                                         # the highlight leans towards the light
    # the angle of incidence on the facets is half the angle between view and light at the point seen
    # (a little over 30 degrees off the axis, where the view leans back towards the camera)
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    d = np.array([c[peak[1]] * analytic.TAN_HALF_FIELD, -c[peak[0]] * analytic.TAN_HALF_FIELD, -1.0])
    d /= np.linalg.norm(d)
    o = np.array([0.0, 0.0, analytic.CAMERA_DISTANCE])
    b = d @ o
    point = o + (-b - math.sqrt(b * b - (o @ o - 0.25))) * d
    view = (o - point) / np.linalg.norm(o - point)
    half = 0.5 * math.acos(float(view @ np.asarray(light)))
    assert 30.5 < math.degrees(half) < 34.0
    rs, rp = reflectances(np.array([half]), 1.5)
    assert dolp(grey)[peak] == pytest.approx(float(((rs - rp) / (rs + rp))[0]), abs=0.01)
    # s-polarized: perpendicular to the plane of incidence (x, z), so along the image's vertical
    assert abs(np.degrees(aolp(grey)[peak]) - 90.0) < 3.0


def test_exposure_sets_the_objects_brightest_diffuse():
    s = analytic._render(_params(exposure=0.6, materials=[(0.8, 0.5, 0.3)]), 64)
    level = np.quantile(s.diffuse[s.mask].max(axis=-1), 0.995)
    assert level == pytest.approx(0.6, rel=0.03)
    assert s.stack.min() >= 0.0 and s.stack.max() <= 1.0 and s.stack.dtype == np.float32


def test_every_shape_renders_and_a_seed_is_one_scene():
    seen = set()
    for seed in range(40):
        p = draw(seed)
        if p["shape"] in seen:
            continue
        seen.add(p["shape"])
        s = render_analytic(seed, size=32)
        assert s.name == f"ana-{seed}" and s.stack.shape == (4, 32, 32, 3) and s.mono_stack.shape == (4, 32, 32)
        assert 0.05 < s.mask.mean() < 0.9
        assert 0.0 <= s.diffuse.min() and s.diffuse.max() <= 1.0
    assert seen == set(SHAPES)
    a, b = render_analytic(7, size=32), render_analytic(7, size=32)
    assert np.array_equal(a.stack, b.stack) and np.array_equal(a.diffuse, b.diffuse)
    assert not np.array_equal(render_analytic(8, size=32).diffuse, a.diffuse)


def test_bad_seeds_and_sizes_are_refused():
    with pytest.raises(PolcamError, match="seed"):
        draw(-1)
    with pytest.raises(PolcamError, match="size 31"):
        render_analytic(0, size=31)
