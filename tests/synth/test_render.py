"""Tests of polcam.synth.render: the polarization model, ground truth, sensor, mosaics and files.

The references are independent of the renderer: Fresnel degrees of polarization
in the closed forms of Atkinson & Hancock (IEEE TIP 2006), the geometry of the
plane of incidence seen by a pinhole camera, and the sensors' documented cells (docs/guide/cameras.md).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from polcam.errors import LayoutError, PolcamError
from polcam.mosaic import parse_layout
from polcam.polarimetry import aolp, dolp, fit_sinusoid
from polcam.synth.mesh import Camera, icosphere
from polcam.synth.render import (
    SceneSpec,
    Texture,
    diffuse_dolp,
    fresnel_reflectance,
    mosaic,
    render,
    specular_dolp,
    write_scene,
)

N_REF = 1.5
SPHERE = icosphere(4, radius=0.5)


# ----------------------------------------------------------------- references
def rho_spec_closed(theta: np.ndarray, n: float) -> np.ndarray:
    """Specular DoLP, Atkinson & Hancock 2006 (eq. for reflection)."""
    s2 = np.sin(theta) ** 2
    return 2 * s2 * np.cos(theta) * np.sqrt(n**2 - s2) / (n**2 - s2 - n**2 * s2 + 2 * s2**2)


def rho_diff_closed(theta: np.ndarray, n: float) -> np.ndarray:
    """Diffuse DoLP, Atkinson & Hancock 2006 (eq. for emission)."""
    s2 = np.sin(theta) ** 2
    return ((n - 1 / n) ** 2 * s2) / (
        2 + 2 * n**2 - (n + 1 / n) ** 2 * s2 + 4 * np.cos(theta) * np.sqrt(n**2 - s2)
    )


def back_project(depth: np.ndarray, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """World points from a depth map (pinhole written out here), and unit vectors to the camera."""
    h, w = depth.shape
    f = cam.focal * w
    rr, cc = np.mgrid[0:h, 0:w] + 0.5
    x = (cc - w / 2) / f
    y = -(rr - h / 2) / f
    d = np.where(np.isfinite(depth), depth, 0.0).astype(np.float64)
    pts = np.stack([x * d, y * d, cam.distance - d], axis=-1)
    to_cam = np.array([0, 0, cam.distance]) - pts
    ln = np.linalg.norm(to_cam, axis=-1, keepdims=True)
    return pts, to_cam / np.where(ln > 0, ln, 1)


def angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Absolute difference of axial angles (period pi), in [0, pi/2]."""
    return np.abs(np.angle(np.exp(2j * (a - b)))) / 2


def clean(**kw) -> SceneSpec:
    """A noise-free sphere scene."""
    base = dict(name="test", mesh=SPHERE, albedo=(0.0, 0.0, 0.0), ks=0.45, shininess=4.0,
                light_position=(1.5, 1.0, 2.0), focal=2.0, camera_distance=2.5)
    base.update(kw)
    return SceneSpec(**base)


# -------------------------------------------------------------------- Fresnel
def test_fresnel_reflectance_known_values() -> None:
    rs, rp = fresnel_reflectance(np.array([0.0, np.arctan(N_REF), np.pi / 2]), N_REF)
    normal = ((N_REF - 1) / (N_REF + 1)) ** 2  # 0.04
    assert rs[0] == pytest.approx(normal) and rp[0] == pytest.approx(normal)
    assert rp[1] == pytest.approx(0.0, abs=1e-15)  # Brewster's angle
    assert rs[2] == pytest.approx(1.0) and rp[2] == pytest.approx(1.0)
    assert specular_dolp(np.arctan(N_REF), N_REF) == pytest.approx(1.0)


@pytest.mark.parametrize("n", [1.3, 1.5, 1.8])
def test_dolp_functions_match_atkinson_hancock_closed_forms(n: float) -> None:
    theta = np.linspace(0.0, np.deg2rad(89.0), 60)
    np.testing.assert_allclose(specular_dolp(theta, n), rho_spec_closed(theta, n), atol=1e-12)
    np.testing.assert_allclose(diffuse_dolp(theta, n), rho_diff_closed(theta, n), atol=1e-12)


# -------------------------------------------------------- polarization model
def test_specular_only_sphere_dolp_and_aolp_follow_fresnel_and_the_plane_of_incidence() -> None:
    spec = clean()
    r = render(spec, size=64)
    stack = r.stack.astype(np.float64)
    assert stack.max() < 1.0  # no saturation in this scene
    m = r.mask & (r.stack.mean(axis=0)[..., 0] > 1e-3)
    assert m.sum() > 800
    # incidence angle: half the angle between the directions to the light and to the camera
    pts, v = back_project(r.depth, spec.camera)
    l_dir = np.asarray(spec.light_position) - pts
    l_dir /= np.linalg.norm(l_dir, axis=-1, keepdims=True)
    theta = 0.5 * np.arccos(np.clip(np.einsum("ijk,ijk->ij", l_dir, v), -1, 1))
    expect = rho_spec_closed(theta, N_REF)
    assert np.ptp(expect[m]) > 0.05  # a range of incidence angles is covered
    for c in range(3):
        np.testing.assert_allclose(dolp(stack)[..., c][m], expect[m], atol=2e-4)
    np.testing.assert_allclose(r.dolp_spec[m], expect[m], atol=2e-4)
    # the plane of incidence holds the camera centre and the light, so it projects onto the image
    # line from the pixel to the light's image; s-polarization is perpendicular to it
    cam = spec.camera
    f = cam.focal * 64
    lx, ly, lz = spec.light_position
    u_l = 32 + f * lx / (cam.distance - lz)
    v_l = 32 - f * ly / (cam.distance - lz)
    rr, cc = np.mgrid[0:64, 0:64] + 0.5
    line = np.arctan2(-(v_l - rr), u_l - cc)  # counter-clockwise on the displayed image
    expect_aolp = np.mod(line + np.pi / 2, np.pi)
    for c in range(3):
        assert angle_diff(aolp(stack)[..., c], expect_aolp)[m].max() < 1e-3
    assert angle_diff(r.aolp_true, expect_aolp)[m].max() < 1e-4
    # Ic is the whole radiance: the sinusoid's mean equals the stack mean and the GT specular
    np.testing.assert_allclose(fit_sinusoid(stack).ic[m], r.specular.astype(np.float64)[m], atol=1e-6)


def test_diffuse_only_is_unpolarized_and_follows_lambert() -> None:
    spec = clean(albedo=(0.8, 0.5, 0.3), ks=0.0, light_intensity=0.9)
    r = render(spec, size=64)
    stack = r.stack.astype(np.float64)
    assert np.all(dolp(stack)[r.mask] < 1e-6)
    for k in range(4):
        np.testing.assert_allclose(r.stack[k], r.diffuse, atol=1e-7)
    np.testing.assert_allclose(r.specular, 0, atol=1e-7)
    pts, _ = back_project(r.depth, spec.camera)
    l_dir = np.asarray(spec.light_position) - pts
    l_dir /= np.linalg.norm(l_dir, axis=-1, keepdims=True)
    ndl = np.maximum(np.einsum("ijk,ijk->ij", r.normal.astype(np.float64), l_dir), 0)
    expect = 0.9 * ndl[..., None] * np.array([0.8, 0.5, 0.3])
    np.testing.assert_allclose(r.diffuse[r.mask], expect[r.mask], atol=1e-5)
    assert np.all(r.diffuse[~r.mask] == 0)


def test_blinn_phong_specular_radiance() -> None:
    spec = clean(ks=0.3, shininess=12.0, light_intensity=0.8, albedo=(0.2, 0.3, 0.4))
    r = render(spec, size=48)
    pts, v = back_project(r.depth, spec.camera)
    l_dir = np.asarray(spec.light_position) - pts
    l_dir /= np.linalg.norm(l_dir, axis=-1, keepdims=True)
    hv = l_dir + v
    hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
    n = r.normal.astype(np.float64)
    ndl = np.einsum("ijk,ijk->ij", n, l_dir)
    ndh = np.maximum(np.einsum("ijk,ijk->ij", n, hv), 0)
    expect = np.where(ndl > 0, 0.3 * ndh**12 * 0.8, 0.0)
    assert r.stack.max() < 1
    for c in range(3):
        np.testing.assert_allclose(r.specular[..., c][r.mask], expect[r.mask], atol=2e-5)


def test_diffuse_polarization_option_transmission_fresnel_and_normal_azimuth() -> None:
    # near-orthographic camera so that the p direction is the image projection of the normal
    spec = clean(albedo=(0.6, 0.6, 0.6), ks=0.0, diffuse_polarization=True, focal=400.0,
                 camera_distance=500.0, light_position=(0.0, 0.0, 1000.0))
    r = render(spec, size=64)
    stack = r.stack.astype(np.float64)
    _, v = back_project(r.depth, spec.camera)
    n = r.normal.astype(np.float64)
    theta_e = np.arccos(np.clip(np.einsum("ijk,ijk->ij", n, v), 0, 1))
    expect = rho_diff_closed(theta_e, N_REF)
    m = r.mask & (r.diffuse[..., 0] > 0.02)
    np.testing.assert_allclose(dolp(stack)[..., 0][m], expect[m], atol=1e-4)
    strong = m & (expect > 0.01)
    assert strong.sum() > 200
    azimuth = np.mod(np.arctan2(n[..., 1], n[..., 0]), np.pi)
    assert angle_diff(aolp(stack)[..., 0], azimuth)[strong].max() < 0.01
    # the diffuse ground truth is still the mean over the four angles (the cosines cancel)
    np.testing.assert_allclose(stack.mean(axis=0)[m], r.diffuse.astype(np.float64)[m], atol=1e-6)
    # and it is off by default
    r0 = render(dataclasses.replace(spec, diffuse_polarization=False), size=64)
    assert np.all(dolp(r0.stack.astype(np.float64))[r0.mask] < 1e-6)


# --------------------------------------------------------------- ground truth
def saturating(**kw) -> SceneSpec:
    base = dict(name="sat", mesh=SPHERE, albedo=Texture("checker", ((0.8, 0.3, 0.2), (0.2, 0.5, 0.9)), 0.2),
                ks=1.2, shininess=8.0, light_intensity=1.3, full_well=5000.0, read_noise=3.0, bit_depth=12)
    base.update(kw)
    return SceneSpec(**base)


def test_contract_diffuse_plus_specular_is_stack_mean_with_noise_and_saturation() -> None:
    r = render(saturating(), size=64, seed=3)
    assert r.stack.shape == (4, 64, 64, 3) and r.stack.dtype == np.float32
    for a in (r.diffuse, r.specular):
        assert a.shape == (64, 64, 3) and a.dtype == np.float32
    assert r.mask.shape == (64, 64) and r.mask.dtype == bool
    assert r.aolp_true.shape == r.dolp_spec.shape == (64, 64)
    assert 0 <= r.stack.min() and r.stack.max() <= 1
    assert 0 <= r.diffuse.min() and r.diffuse.max() <= 1
    np.testing.assert_allclose(r.diffuse + r.specular, r.stack.mean(axis=0), atol=1e-6, rtol=0)
    assert r.info["saturated_fraction"] > 0.05
    assert np.all((r.aolp_true >= 0) & (r.aolp_true < np.pi))
    assert np.all((r.dolp_spec >= 0) & (r.dolp_spec <= 1))


def test_saturation_clips_stack_but_ground_truth_diffuse_is_unclipped_then_clipped() -> None:
    spec = saturating(full_well=None, read_noise=0.0, bit_depth=None, ks=0.5, light_intensity=1.6,
                      albedo=(0.9, 0.5, 0.2))
    r = render(spec, size=48)
    ref = render(dataclasses.replace(spec, ks=0.0), size=48)  # same diffuse, no specular
    # the diffuse truth does not depend on the specular layer, even under it and where it saturates
    np.testing.assert_array_equal(r.diffuse, ref.diffuse)
    over = r.mask & (r.diffuse[..., 0] >= 1)  # 0.9 * 1.6 * n.l > 1 somewhere: clipped to 1
    assert over.sum() > 20
    assert np.all(r.stack[:, over, 0] == 1)
    # unclipped diffuse values are the Lambert values (checked in the test above) below 1
    lam = ref.stack.mean(axis=0)
    below = r.mask & (lam[..., 1] < 0.99)
    np.testing.assert_allclose(r.diffuse[below], lam[below], atol=1e-6)
    assert r.info["saturated_fraction"] > 0


def test_seeded_noise_is_deterministic_and_has_the_stated_statistics() -> None:
    spec = saturating(ks=0.0, light_intensity=0.8, bit_depth=None, full_well=2000.0, read_noise=5.0)
    a, b = render(spec, size=64, seed=11), render(spec, size=64, seed=11)
    np.testing.assert_array_equal(a.stack, b.stack)
    c = render(spec, size=64, seed=12)
    assert not np.array_equal(a.stack, c.stack)
    np.testing.assert_array_equal(a.diffuse, c.diffuse)  # the ground truth has no noise
    clean_spec = dataclasses.replace(spec, full_well=None, read_noise=0.0)
    truth = render(clean_spec, size=64).stack.astype(np.float64)
    m = np.broadcast_to(a.mask[None, ..., None], truth.shape) & (truth > 0.05) & (truth < 0.8)
    sigma = np.sqrt(truth / 2000.0 + (5.0 / 2000.0) ** 2)
    z = (a.stack.astype(np.float64) - truth)[m] / sigma[m]
    assert m.sum() > 5000
    assert abs(z.mean()) < 0.05
    assert z.std() == pytest.approx(1.0, abs=0.05)


def test_quantisation_to_bit_depth() -> None:
    r = render(clean(ks=0.3, albedo=(0.5, 0.4, 0.3), bit_depth=8), size=32)
    counts = r.stack.astype(np.float64) * 255
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-3)


def test_textures_are_deterministic_and_use_their_palette() -> None:
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (4000, 3))
    pal = ((0.9, 0.1, 0.1), (0.1, 0.9, 0.1), (0.1, 0.1, 0.9))
    for kind in ("checker", "stripes", "noise"):
        t = Texture(kind, pal, 0.1, seed=5)
        a, b = t.evaluate(pts), t.evaluate(pts)
        np.testing.assert_array_equal(a, b)
        assert np.all((a >= 0.1 - 1e-12) & (a <= 0.9 + 1e-12))
        assert len(np.unique(a.round(6), axis=0)) >= 3  # more than one colour is used
    # checker and stripes take palette colours only; stripes repeat every len(palette) * scale
    chk = Texture("checker", pal, 0.1, seed=5).evaluate(pts)
    assert {tuple(x) for x in chk.round(6)} <= {tuple(p) for p in pal}
    st = Texture("stripes", pal, 0.1, direction=(1, 0, 0))
    shifted = pts + np.array([0.3, 0, 0])
    np.testing.assert_array_equal(st.evaluate(pts), st.evaluate(shifted))
    # a different seed moves the noise
    assert not np.array_equal(Texture("noise", pal, 0.1, seed=1).evaluate(pts),
                              Texture("noise", pal, 0.1, seed=2).evaluate(pts))


def test_plane_background_is_lambertian_and_outside_the_mask() -> None:
    spec = clean(albedo=(0.5, 0.5, 0.5), ks=0.2, light_position=(0.0, 0.0, 4.0),
                 background="plane", background_albedo=(0.2, 0.1, 0.3))
    r = render(spec, size=48)
    black = render(dataclasses.replace(spec, background="black"), size=48)
    np.testing.assert_array_equal(r.mask, black.mask)
    np.testing.assert_array_equal(r.stack[:, r.mask], black.stack[:, r.mask])
    # plane z = -0.75 facing +z, lit from (0, 0, 4): albedo * cos(incidence)
    pts, _ = back_project(np.full((48, 48), spec.camera_distance + 0.75), spec.camera)
    l_dir = np.array([0.0, 0.0, 4.0]) - pts
    cos_in = l_dir[..., 2] / np.linalg.norm(l_dir, axis=-1)
    expect = cos_in[..., None] * np.array([0.2, 0.1, 0.3])
    np.testing.assert_allclose(r.diffuse[~r.mask], expect[~r.mask], atol=1e-6)
    np.testing.assert_allclose(r.specular[~r.mask], 0, atol=1e-7)
    assert np.all(black.stack[:, ~black.mask] == 0)


def test_render_rejects_bad_input() -> None:
    with pytest.raises(PolcamError, match="size"):
        render(clean(), size=0)
    with pytest.raises(PolcamError, match="SceneSpec"):
        render({"mesh": "bunny"}, size=8)  # type: ignore[arg-type]
    with pytest.raises(PolcamError, match="refractive_index"):
        clean(refractive_index=0.9)
    with pytest.raises(PolcamError, match="albedo"):
        clean(albedo=(1.2, 0, 0))
    with pytest.raises(PolcamError, match="full_well"):
        clean(read_noise=3.0)
    with pytest.raises(PolcamError, match="background"):
        clean(background="white")
    with pytest.raises(PolcamError, match="texture kind"):
        Texture("marble")


# --------------------------------------------------------------------- mosaic
def test_mosaic_mono_imx250mzr_samples_the_design_cell() -> None:
    stack = np.random.default_rng(1).random((4, 8, 12, 3)).astype(np.float32)
    raw = mosaic(stack, "imx250mzr")
    assert raw.shape == (8, 12) and raw.dtype == np.float32
    mono = stack.mean(axis=-1)
    # IMX250MZR: 2x2 cell row 0 = 90 45, row 1 = 135 0; stack order 0, 45, 90, 135
    cell = {(0, 0): 2, (0, 1): 1, (1, 0): 3, (1, 1): 0}
    for (dr, dc), k in cell.items():
        np.testing.assert_allclose(raw[dr::2, dc::2], mono[k, dr::2, dc::2], rtol=1e-6)
    # and against polcam.mosaic's own maps
    a = parse_layout("imx250mzr").angle_index(8, 12)
    rr, cc = np.indices((8, 12))
    np.testing.assert_allclose(raw, mono[a, rr, cc], rtol=1e-6)
    # a mono stack is sampled as it is
    np.testing.assert_array_equal(mosaic(mono, "imx250mzr"), mono[a, rr, cc].astype(np.float32))


def test_mosaic_color_imx250myr_samples_angle_and_colour() -> None:
    stack = np.random.default_rng(2).random((4, 8, 8, 3)).astype(np.float32)
    raw = mosaic(stack, "imx250myr")
    # IMX250MYR 4x4 cell: R90 R45 G90 G45 / R135 R0 G135 G0 / G90 G45 B90 B45 / G135 G0 B135 B0
    ang = {90: 2, 45: 1, 135: 3, 0: 0}
    col = {"R": 0, "G": 1, "B": 2}
    cell = [["R90", "R45", "G90", "G45"], ["R135", "R0", "G135", "G0"],
            ["G90", "G45", "B90", "B45"], ["G135", "G0", "B135", "B0"]]
    for r in range(8):
        for c in range(8):
            name = cell[r % 4][c % 4]
            assert raw[r, c] == stack[ang[int(name[1:])], r, c, col[name[0]]]
    lay = parse_layout("imx250myr")
    a, ch = lay.angle_index(8, 8), lay.channel_index(8, 8)
    rr, cc = np.indices((8, 8))
    np.testing.assert_array_equal(raw, stack[a, rr, cc, ch])


def test_mosaic_rejects_bad_input() -> None:
    with pytest.raises(LayoutError, match="RGB stack"):
        mosaic(np.zeros((4, 4, 4)), "imx250myr")
    with pytest.raises(PolcamError, match="expected"):
        mosaic(np.zeros((3, 4, 4, 3)), "imx250mzr")
    with pytest.raises(LayoutError):
        mosaic(np.zeros((4, 4, 4, 3)), "nonsense")


# ---------------------------------------------------------------------- files
def read_exr(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    arr = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    inp.close()
    return np.asarray(arr, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)


def test_write_scene_round_trips(tmp_path: Path) -> None:
    r = render(saturating(), size=32, seed=4)
    out = tmp_path / "scene"
    written = write_scene(r, out, bit_depth=12)
    for k, ang in enumerate((0, 45, 90, 135)):
        np.testing.assert_array_equal(read_exr(out / f"angle_{ang:03d}.exr"), r.stack[k])
    diffuse, specular = read_exr(out / "diffuse.exr"), read_exr(out / "specular.exr")
    np.testing.assert_array_equal(diffuse, r.diffuse)
    np.testing.assert_array_equal(specular, r.specular)
    np.testing.assert_array_equal(read_exr(out / "aolp_true.exr")[..., 0], r.aolp_true)
    np.testing.assert_array_equal(read_exr(out / "dolp_spec.exr")[..., 0], r.dolp_spec)
    mask = cv2.imread(str(out / "mask.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(mask > 0, r.mask)
    assert cv2.imread(str(out / "preview.png")).shape == (32, 32, 3)
    for name in ("imx250mzr", "imx250myr"):
        raw = cv2.imread(str(out / f"raw_{name}.png"), cv2.IMREAD_UNCHANGED)
        assert raw.dtype == np.uint16 and raw.shape == (32, 32)
        expect = np.round(np.clip(mosaic(r.stack, name), 0, 1) * 4095).astype(np.uint16)
        np.testing.assert_array_equal(raw, expect)
        side = json.loads((out / f"raw_{name}.json").read_text())
        assert parse_layout(side["layout"]) == parse_layout(name)
        assert (side["width"], side["height"], side["bit_depth"]) == (32, 32, 12)
        assert side["black_level"] == 0 and side["white_level"] == 4095
        assert side.get("msb_aligned", False) is False
    doc = json.loads((out / "scene.json").read_text())
    assert doc["info"]["seed"] == 4 and doc["info"]["spec"]["ks"] == pytest.approx(1.2)
    assert set(written) >= {"angle_000", "diffuse", "specular", "mask", "raw_imx250mzr", "raw_imx250myr", "scene"}
    assert all(p.is_file() for p in written.values())
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_write_scene_8_bit_and_bad_depth(tmp_path: Path) -> None:
    r = render(clean(ks=0.3, albedo=(0.4, 0.4, 0.4)), size=16)
    write_scene(r, tmp_path / "s8", bit_depth=8)
    raw = cv2.imread(str(tmp_path / "s8" / "raw_imx250mzr.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint8
    np.testing.assert_array_equal(raw, np.round(mosaic(r.stack, "imx250mzr") * 255).astype(np.uint8))
    with pytest.raises(PolcamError, match="bit_depth"):
        write_scene(r, tmp_path / "bad", bit_depth=4)
