"""The randomized scene family: determinism, disjoint splits, and the properties it claims."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from polcam.errors import PolcamError
from polcam.polarimetry import dolp
from polcam.synth.family import (
    TEST_SEED_MIN,
    MaterialTexture,
    draw,
    render_family,
    seed_of,
    split_seeds,
)
from polcam.synth.render import diffuse_dolp


def test_a_seed_gives_the_same_scene_and_another_seed_another():
    a, b = render_family(3, size=32), render_family(3, size=32)
    for f in ("stack", "mono_stack", "diffuse", "ideal", "mask", "clipped", "dolp_diffuse"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert a.params == b.params == draw(3)
    c = render_family(4, size=32)
    assert not np.array_equal(a.stack, c.stack)
    assert a.name == "rand-3" and seed_of(a.name) == 3 and seed_of("Bunny1") is None


def test_splits_are_disjoint_and_test_seeds_reproduce_from_the_master():
    val, none = split_seeds("validation", 40)
    assert val == list(range(40)) and none is None
    t1, m1 = split_seeds("test", 40)
    t2, m2 = split_seeds("test", 40)
    assert m1 != m2 and t1 != t2                                   # fresh at every run
    assert split_seeds("test", 40, seed=m1) == (t1, m1)            # reproduced from the printed seed
    for seeds in (t1, t2):
        assert len(set(seeds)) == 40 and min(seeds) >= TEST_SEED_MIN > max(val)
    with pytest.raises(PolcamError, match="fixed"):
        split_seeds("validation", 5, seed=1)
    with pytest.raises(PolcamError, match="split 'train'"):
        split_seeds("train", 5)


def test_the_draws_cover_what_the_family_claims():
    ps = [draw(s) for s in range(40)]
    kinds = {m["material"] for p in ps for m in p["materials"]}
    assert kinds == {"photo", "achromatic", "pale", "colour"}
    assert {p["light"] for p in ps} == {"white", "tinted", "mixed"}
    assert {p["shape"] for p in ps} == {"bunny", "dragon", "armadillo", "sphere"}
    assert any(len(p["materials"]) >= 3 for p in ps) and any(p["ks"] == 0 for p in ps)
    assert min(p["exposure"] for p in ps) < 0.4 and max(p["exposure"] for p in ps) > 2.0


def test_overexposed_draws_clip_and_the_camera_reads_white_there():
    clipped = []
    for s in range(40):
        if draw(s)["exposure"] < 1.5:
            continue
        sc = render_family(s, size=64)
        frac = float(sc.clipped[sc.mask].mean())
        clipped.append(frac)
        if frac > 0.05:
            # the sensor saturates: where the ideal light is over 1 at every sample, the raw reads 1;
            # the demosaicing's interpolation moves a few samples near the region's edge
            every = (sc.ideal >= 1.05).all(axis=(0, 3)) & sc.mask
            every = ndimage.binary_erosion(every, iterations=2)
            if every.any():
                assert np.median(sc.stack[:, every]) == 1.0 and sc.stack[:, every].mean() >= 0.98
    assert len(clipped) >= 5
    assert np.mean([c > 0.01 for c in clipped]) >= 0.5


def test_diffuse_light_is_polarized_at_the_rims_by_fresnel():
    seed = next(s for s in range(40) if draw(s)["shape"] == "sphere")
    sc = render_family(seed, size=96)
    n_r = sc.params["refractive_index"]
    inner = ndimage.binary_erosion(sc.mask, iterations=4)
    rim = sc.mask & ~inner
    centre = ndimage.binary_erosion(sc.mask, iterations=25)
    assert centre.any()
    assert np.median(sc.dolp_diffuse[rim]) > 0.05
    # the centre faces the camera: Fresnel's diffuse DoLP there is below its value at 30 degrees
    assert np.median(sc.dolp_diffuse[centre]) < float(diffuse_dolp(np.deg2rad(30.0), n_r))
    # and the polarization reaches the camera: the mono stack's DoLP is larger on the rim
    cam = dolp(sc.mono_stack.astype(np.float64))
    assert np.median(cam[rim & (sc.diffuse_mono > 0.05)]) > np.median(cam[centre]) + 0.02


def test_truth_is_the_noise_free_diffuse_under_the_light():
    seed = next(s for s in range(40) if draw(s)["ks"] == 0)
    sc = render_family(seed, size=48)
    # no specular: the diffuse truth is the mean of the ideal stack wherever nothing clips
    ok = ~sc.clipped
    assert ok.mean() > 0.5
    np.testing.assert_allclose(sc.diffuse[ok], sc.ideal.mean(axis=0)[ok], atol=1e-5)
    np.testing.assert_allclose(sc.diffuse_mono, sc.diffuse.mean(axis=-1), atol=1e-6)
    assert sc.stack.shape == (4, 48, 48, 3) and sc.mono_stack.shape == (4, 48, 48)
    assert 0 <= sc.stack.min() and sc.stack.max() <= 1


def test_material_texture_splits_the_object_into_cells_and_samples_photos():
    tex = MaterialTexture(centers=((-0.3, 0, 0), (0.3, 0, 0)),
                          materials=({"kind": "uniform", "rgb": (0.5, 0.5, 0.5)},
                                     {"kind": "photo", "photo": "astronaut", "axis": 2, "origin": (0, 0),
                                      "side": 512, "gain": 1.0, "desaturate": 0.0}))
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.5, 0.5, 400), rng.uniform(-0.5, 0.5, 400), np.zeros(400)])
    alb = tex.evaluate(pts)
    left = pts[:, 0] < 0
    np.testing.assert_allclose(alb[left], 0.5)
    assert alb[~left].std(axis=0).min() > 0.02        # the photograph's texture, not a flat colour
    assert alb.max() <= 0.95
    with pytest.raises(PolcamError, match="one centre per material"):
        MaterialTexture(centers=((0, 0, 0),), materials=())
