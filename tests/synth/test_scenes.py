"""Tests of polcam.synth.scenes: the paper's scene sets (Shakeri & Zhang, section 4.1)."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import PolcamError
from polcam.synth.render import SceneSpec, Texture, render
from polcam.synth.scenes import BUNNY, SCENES, scene, scene_names

SIZE = 64


@pytest.fixture(scope="module")
def rendered() -> dict:
    return {name: render(spec, size=SIZE, seed=0) for name, spec in SCENES.items()}


def test_the_papers_scene_names() -> None:
    # Tables 1 and 2 of the paper
    assert scene_names() == ("Bunny1", "Bunny2", "Bunny3", "Bunny4", "Bunny5", "Bunny6", "Bunny7",
                             "Dragon1", "Dragon2", "Armadillo")
    assert BUNNY == scene_names()[:7]
    assert all(isinstance(s, SceneSpec) and s.name == n for n, s in SCENES.items())


def test_scene_lookup() -> None:
    assert scene("bunny3") is SCENES["Bunny3"]
    assert scene("ARMADILLO") is SCENES["Armadillo"]
    with pytest.raises(PolcamError, match="Bunny1, Bunny2"):
        scene("Teapot")


def test_objects_are_the_papers() -> None:
    for name, spec in SCENES.items():
        assert spec.mesh == name.rstrip("0123456789").lower()


def test_bunny_series_goes_from_weak_to_strong_specular(rendered: dict) -> None:
    ratios = [rendered[n].info["specular_ratio"] for n in BUNNY]
    sat = [rendered[n].info["saturated_fraction"] for n in BUNNY]
    assert all(a < b for a, b in zip(ratios, ratios[1:])), ratios
    assert all(a <= b for a, b in zip(sat, sat[1:])), sat
    assert sat[0] == 0  # weak specular: nothing saturates
    assert sat[6] > 0 and sat[5] > 0  # the paper: Bunny6 and Bunny7 have saturated regions


def test_specular_ratio_matches_the_ground_truth_layers(rendered: dict) -> None:
    # the reported ratio is the noise-free specular over diffuse radiance on the object; where
    # nothing saturates it equals the ground-truth layers' ratio up to the (zero-mean) sensor noise
    r = rendered["Bunny2"]
    assert r.info["saturated_fraction"] == 0
    m = r.mask
    measured = r.specular[m].astype(np.float64).sum() / r.diffuse[m].astype(np.float64).sum()
    assert measured == pytest.approx(r.info["specular_ratio"], rel=0.05, abs=2e-3)


def test_varying_albedo_and_saturation_where_the_paper_says(rendered: dict) -> None:
    # Bunny7: "saturated regions under varying albedo"; Dragon/Armadillo: "with saturated regions"
    assert isinstance(SCENES["Bunny7"].albedo, Texture) and SCENES["Bunny7"].albedo.kind != "uniform"
    for name in ("Bunny7", "Dragon1", "Dragon2", "Armadillo"):
        assert rendered[name].info["saturated_fraction"] > 0, name
    d = rendered["Bunny7"].diffuse[rendered["Bunny7"].mask].astype(np.float64)
    chroma = d / np.maximum(d.sum(axis=1, keepdims=True), 1e-6)
    lit = d.sum(axis=1) > 0.1
    assert chroma[lit].std(axis=0).max() > 0.03  # the diffuse colour varies over the object
    d1 = rendered["Bunny1"].diffuse[rendered["Bunny1"].mask].astype(np.float64)
    c1 = d1 / np.maximum(d1.sum(axis=1, keepdims=True), 1e-6)
    assert c1[d1.sum(axis=1) > 0.1].std(axis=0).max() < 1e-3  # uniform albedo: one chromaticity


def test_scenes_are_reproducible() -> None:
    a = render(scene("Dragon2"), size=32, seed=5)
    b = render(scene("Dragon2"), size=32, seed=5)
    np.testing.assert_array_equal(a.stack, b.stack)
    np.testing.assert_array_equal(a.diffuse, b.diffuse)


def test_scenes_fill_the_frame_without_cropping(rendered: dict) -> None:
    for name, r in rendered.items():
        m = r.mask
        assert m.mean() > 0.1, name
        assert not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any()), name


def test_stress_scenes_break_the_assumptions_they_name() -> None:
    import numpy as np

    from polcam.synth.render import render
    from polcam.synth.scenes import STRESS, scene

    assert set(STRESS) == {"WhiteGrey", "Multicolour", "Brewster", "Normal", "Tinted", "DiffusePol",
                           "Saturated", "Noise8"}
    assert scene("brewster") is STRESS["Brewster"]
    r = {n: render(STRESS[n], size=48, seed=0) for n in ("Brewster", "Normal", "DiffusePol", "WhiteGrey")}

    def spec_dolp(x):
        w = np.maximum(x.specular.sum(-1), 0)[x.mask]
        return float((x.dolp_spec[x.mask] * w).sum() / w.sum())

    assert spec_dolp(r["Brewster"]) > 0.8          # near Brewster's angle: strongly polarized
    assert spec_dolp(r["Normal"]) < 0.05           # near normal incidence: weakly polarized
    assert STRESS["DiffusePol"].diffuse_polarization
    assert STRESS["Tinted"].light_color != (1.0, 1.0, 1.0)
    assert STRESS["Noise8"].bit_depth == 8
    d = r["WhiteGrey"].diffuse[r["WhiteGrey"].mask]
    assert np.abs(d - d.mean(-1, keepdims=True)).max() < 1e-6   # achromatic albedo under white light
