"""The learned unpolarized-specular stage of polarized-residual: where it acts, what it removes, its weights."""

from __future__ import annotations

import json

import numpy as np
import pytest

import polcam
from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation import _learned_residual as lr
from polcam.separation.polarized_residual import learned_inputs, separate_polarized_residual
from polcam.synth.family import render_family, split_seeds


def test_shipped_weights_load_and_name_this_polcams_features() -> None:
    w = lr.load_weights()
    assert int(w["layers"]) == 3 and w["mu"].shape == (len(lr.FEATURES),)
    with np.load(lr.WEIGHTS_FILE) as z:
        info = json.loads(str(z["info"]))
    assert info["command"].startswith("polcam bench train-residual")     # how they were made


def test_weights_of_other_features_are_refused_naming_the_file(tmp_path) -> None:
    w = {k: v for k, v in lr.load_weights().items() if k != "features"}
    bad = tmp_path / "old.npz"
    np.savez(bad, features=np.array(json.dumps(["a", "b"])), **w)
    with pytest.raises(MethodError, match="old.npz.*do not match"):
        lr.load_weights(bad)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not an npz")
    with pytest.raises(MethodError, match="junk.npz.*unreadable"):
        lr.load_weights(junk)


def test_a_stack_without_polarized_light_is_left_as_it_is() -> None:
    """No coherent polarized light, no zone: a matte textured patch is never thinned by the stage."""
    rng = np.random.default_rng(3)
    d = np.clip(0.3 + 0.2 * rng.random((48, 48, 3)), 0, 1).astype(np.float32)
    stack = np.broadcast_to(d, (4, 48, 48, 3)).copy()
    none, _ = separate_polarized_residual(stack, unpolarized="none")
    learned, info = separate_polarized_residual(stack, unpolarized="learned")
    np.testing.assert_array_equal(learned, none)
    assert info["learned_specular"] == 0.0


@pytest.fixture(scope="module")
def scene():
    return render_family(split_seeds("validation", 6)[0][5], size=96)       # a glossy validation scene


def test_the_removal_is_one_colour_bounded_by_the_layer_and_inside_the_zone(scene) -> None:
    inputs = learned_inputs(scene.stack)
    none = np.asarray(inputs["diffuse"])                                # the layer before the stage
    np.testing.assert_allclose(none, polcam.separate(scene.stack, method="polarized-residual",
                                                     unpolarized="none").diffuse, rtol=0, atol=1e-6)
    learned, info = separate_polarized_residual(scene.stack, unpolarized="learned")
    removed = none - learned
    assert removed.min() >= 0 and (learned >= 0).all()
    g = np.asarray(inputs["g"])
    share = removed / g                                                 # one multiple of G per pixel
    assert np.abs(share - share.mean(-1, keepdims=True)).max() < 1e-5
    # never more than the pixel rises above its surroundings (the evidence bound), which is > 0
    # somewhere and 0 somewhere in this scene
    bound = np.asarray(inputs["bound"])
    assert (share[..., 0] <= bound + 1e-6).all() and (bound > 0).any() and (bound == 0).any()
    assert not removed[~np.asarray(inputs["zone"])].any()
    assert 0 < info["learned_specular"] < 0.5
    np.testing.assert_allclose(info["learned_specular"], removed.sum() / none.sum(), rtol=1e-4)


def test_partly_blind_pixels_are_separated_in_one_colour() -> None:
    """A highlight that clipped some channels of a pale blue sphere (validation seed 85): the stage
    acts on its partly blind pixels (not where every channel is blind), takes one multiple of ``G``
    from every channel there, the blind ones too, and brings the seeing channels closer to the
    truth."""
    sc = render_family(85, size=128)
    inputs = learned_inputs(sc.stack)
    zone, g = np.asarray(inputs["zone"]), np.asarray(inputs["g"])
    blind = sc.stack.mean(axis=0) >= 0.98
    part = zone & blind.any(-1) & ~blind.all(-1)
    assert part.sum() > 300 and not (zone & blind.all(-1)).any()
    learned, _ = separate_polarized_residual(sc.stack)
    before = np.asarray(inputs["diffuse"])
    share = (before - learned)[part] / g
    assert np.abs(share - share.mean(-1, keepdims=True)).max() < 1e-5 and share.max() > 0
    seeing = part[..., None] & ~blind
    assert (before - learned)[seeing].sum() > 0.1 * before[seeing].sum()
    assert ((learned - sc.diffuse)[seeing] ** 2).mean() < 0.7 * ((before - sc.diffuse)[seeing] ** 2).mean()


def test_the_stage_brings_glossy_validation_scenes_closer_to_the_truth() -> None:
    """Ground truth of the randomized family (validation seeds, never trained on): the glossy scenes'
    diffuse gets closer to the truth with the stage than without it, on the mean."""
    gain = []
    for sd in split_seeds("validation", 10)[0]:
        sc = render_family(sd, size=96)
        if sc.params["ks"] < 0.3:
            continue
        none = polcam.separate(sc.stack, method="polarized-residual", unpolarized="none").diffuse
        learned = polcam.separate(sc.stack, method="polarized-residual", unpolarized="learned").diffuse
        gain.append(psnr(learned, sc.diffuse, sc.mask) - psnr(none, sc.diffuse, sc.mask))
    assert len(gain) >= 3 and float(np.mean(gain)) > 0.3


def test_kernels_scale_with_the_image() -> None:
    assert lr._k(9, lr.TRAIN_SIDE) == 9 and lr._k(9, 4 * lr.TRAIN_SIDE) == 37 and lr._k(1, 64) == 3


def test_the_bound_is_the_rise_or_the_polarized_light_and_never_more_than_the_layer() -> None:
    """``removal_bound`` in closed form: a narrow peak is bounded by its rise above the floor of its
    surroundings, never beyond what the layer holds in its least channel; a highlight as broad as the
    image does not rise above its surroundings, and only its polarized light seen bounds it."""
    g = np.array([1.1, 1.0, 0.9], np.float32)
    h, w = 64, 64
    diffuse = np.broadcast_to(0.3 * g, (h, w, 3)).astype(np.float32).copy()
    unpolarized = np.zeros((h, w), np.float32)
    # a 7 x 7 peak: wider than the 5 x 5 median, inside the window (0.12 of the side)
    peak = diffuse.copy()
    peak[28:35, 28:35] += 0.25 * g
    b = np.asarray(lr.removal_bound(peak, peak, g, w, unpolarized))
    assert b[31, 31] == pytest.approx(0.25, rel=1e-4) and b[10, 10] == 0.0
    thin = diffuse * 0.1                                    # a layer that holds less than the rise
    assert np.asarray(lr.removal_bound(thin, peak, g, w, unpolarized))[31, 31] == pytest.approx(0.03, rel=1e-4)
    flat = diffuse + 0.2 * g                                # a flat "highlight" over the whole image
    np.testing.assert_allclose(np.asarray(lr.removal_bound(diffuse, flat, g, w, unpolarized)), 0.0, atol=1e-6)
    # where its polarization is seen, the polarized light bounds it: POLARIZED_RATIO times it
    polarized = np.zeros((h, w), np.float32)
    polarized[:, 32:] = 0.1
    b = np.asarray(lr.removal_bound(diffuse, flat, g, w, polarized))
    np.testing.assert_allclose(b[:, :32], 0.0, atol=1e-6)
    np.testing.assert_allclose(b[:, 32:], lr.POLARIZED_RATIO * 0.1, rtol=1e-5)
    assert np.asarray(lr.removal_bound(thin, flat, g, w, polarized))[5, 40] == pytest.approx(0.03, rel=1e-4)
    # the rise alone (evidence=True on a colour stack) does not count the polarized light
    b = np.asarray(lr.removal_bound(peak, peak, g, w, polarized, evidence="rise"))
    assert b[31, 31] == pytest.approx(0.25, rel=1e-4) and b[10, 40] == 0.0


def test_without_colour_a_rise_without_polarized_light_is_not_removed() -> None:
    """Mono stacks (``"polarized"``): the peak of the test above, a pale matte patch as much as a
    highlight, keeps its light where no polarized light is seen, and loses at most ``r p`` where it is;
    ``"both"`` (mono with evidence=True) bounds by the lesser of the rise and ``r p``."""
    g = np.ones(3, np.float32)
    h, w = 64, 64
    peak = np.full((h, w, 3), 0.3, np.float32)
    peak[28:35, 28:35] += 0.25
    np.testing.assert_allclose(np.asarray(lr.removal_bound(peak, peak, g, w, np.zeros((h, w), np.float32),
                                                           evidence="polarized")), 0.0, atol=1e-7)
    polarized = np.zeros((h, w), np.float32)
    polarized[:, 31:] = 0.4                                 # more than the peak's rise of 0.25
    b = np.asarray(lr.removal_bound(peak, peak, g, w, polarized, evidence="polarized"))
    assert b[31, 31] == pytest.approx(0.4 * lr.POLARIZED_RATIO, rel=1e-5) and b[31, 29] == 0.0
    assert b[10, 40] == pytest.approx(min(0.3, 0.4 * lr.POLARIZED_RATIO), rel=1e-5)  # flat surround: at most D
    both = np.asarray(lr.removal_bound(peak, peak, g, w, polarized, evidence="both"))
    assert both[31, 31] == pytest.approx(min(0.25, 0.4 * lr.POLARIZED_RATIO), rel=1e-4) and both[10, 40] == 0.0
    with pytest.raises(ValueError, match="evidence='loud'"):
        lr.removal_bound(peak, peak, g, w, polarized, evidence="loud")
