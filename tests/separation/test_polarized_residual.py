"""polarized-residual: each physical claim on a stack with planted truth.

The tests given ``**_STEPS`` check the optional steps for the unpolarized specular light
(``unpolarized="measured"``: one specular colour, k, the colour prior) without the highlight-evidence
bound, whose window (0.06 of the side: 3-6 pixels on these 48-96 pixel scenes) is narrower than their
planted highlights, and without the fit of demosaicing's edge polarization (these stacks are not
demosaiced); tests/separation/test_polarized_residual_physics.py covers the default path.
"""

from __future__ import annotations

import numpy as np
import pytest

import polcam
from polcam.demosaicing import mosaic_stack
from polcam.errors import MethodError
from polcam.polarimetry import synthesize
from polcam.separation import polarized_residual as pres
from polcam.separation._learned_residual import load_weights
from polcam.separation._polarization_noise import ALIASING, aliasing_deviation
from polcam.synth.photos import load_photo

#: The optional residual steps, unbounded (module docstring).
_STEPS = {"unpolarized": "measured", "evidence": False, "edge_polarization": False, "edge_fit": 0}


def _scene(h=48, w=64):
    """Red, green and blue matte patches plus a white one, on a grey background."""
    d = np.full((h, w, 3), 0.25)
    d[8:24, 4:20] = (0.55, 0.12, 0.10)
    d[8:24, 24:40] = (0.10, 0.45, 0.12)
    d[8:24, 44:60] = (0.12, 0.15, 0.55)
    d[28:44, 20:44] = (0.6, 0.6, 0.6)     # a white matte object
    return 0.7 * d


def _bump(h, w, cy, cx, r):
    yy, xx = np.mgrid[:h, :w]
    return np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r))


def _stack(diffuse, spec, gamma, *, rho_s, phi_s, rho_d=0.0):
    """Diffuse (optionally polarized at phi_s + 90 deg) plus a specular of colour gamma and DoLP rho_s."""
    s = spec[..., None] * np.asarray(gamma)
    phi = np.full(diffuse.shape, phi_s)
    st = synthesize(s, rho_s * s, phi)
    st = st + synthesize(diffuse, rho_d * diffuse, phi + np.pi / 2)
    return st


def test_planted_polarized_specular_is_removed_exactly():
    d = _scene()
    h, w = d.shape[:2]
    spec = 0.3 * (_bump(h, w, 16, 12, 3) + _bump(h, w, 16, 52, 3) + _bump(h, w, 36, 32, 4))
    st = _stack(d, spec, (1, 1, 1), rho_s=1.0, phi_s=0.4)
    res = polcam.separate(st, method="polarized-residual", **_STEPS)
    assert np.max(np.abs(res.diffuse - d)) < 2e-3
    # the imin diffuse is exact here too; a fully polarized specular needs no prior
    assert np.max(np.abs(polcam.separate(st, method="imin").diffuse - d)) < 1e-6


def test_a_highlight_that_dominates_its_pixels_is_removed_in_each_channel(monkeypatch):
    # a fully polarized highlight up to ten times the dark body's light, its colour 10 % off G's in red
    # and blue (as each channel's demosaicing error of a highlight leaves it): where polarization removes
    # most of a pixel's light, each channel's own removal is kept, so no coloured rest of the highlight
    # stays in the layer (step 4)
    h, w = 48, 48
    d = np.broadcast_to(np.array([0.06, 0.05, 0.04]), (h, w, 3)).copy()
    spec = 0.6 * _bump(h, w, 24, 24, 5)
    st = _stack(d, spec, (1.1, 1.0, 0.9), rho_s=1.0, phi_s=0.7)
    opts = dict(method="polarized-residual", illuminant=(1, 1, 1), unpolarized="none", edge_polarization=False,
                edge_fit=0)
    core = spec > 0.5 * spec.max()                               # over 80 % of the light is removed there
    assert np.abs(polcam.separate(st, **opts).diffuse[core] - d[core]).max() < 2e-3
    # one multiple of G alone (the ramp moved out of reach) leaves the red excess, >= 0.1 of the highlight
    from polcam.separation import _one_colour

    monkeypatch.setattr(_one_colour, "PER_CHANNEL_SHARE", (2.0, 3.0))
    one = polcam.separate(st, **opts).diffuse
    assert (one - d)[core][:, 0].min() > 0.1 * 0.3 - 1e-3


def test_white_unpolarized_object_is_kept():
    d = _scene()
    st = _stack(d, np.zeros(d.shape[:2]), (1, 1, 1), rho_s=0.0, phi_s=0.0)
    res = polcam.separate(st, method="polarized-residual")
    white = np.zeros(d.shape[:2], bool)
    white[28:44, 20:44] = True
    assert np.max(np.abs(res.diffuse[white] - 0.42)) < 1e-3
    assert np.max(np.abs(res.diffuse - d)) < 1e-3


def test_white_object_beside_a_partly_polarized_highlight_stays_white():
    d = _scene()
    h, w = d.shape[:2]
    spec = 0.35 * _bump(h, w, 16, 12, 3)            # highlight on the red patch, DoLP 0.5
    st = _stack(d, spec, (1, 1, 1), rho_s=0.5, phi_s=1.0)
    res = polcam.separate(st, method="polarized-residual", **_STEPS)
    white = np.zeros((h, w), bool)
    white[28:44, 20:44] = True
    assert np.max(np.abs(res.diffuse[white] - 0.42)) < 1e-3
    # the unpolarized half of the highlight is removed too, beyond what imin removes
    red = np.zeros((h, w), bool)
    red[8:24, 4:20] = True
    err_ours = np.abs(res.diffuse - d)[red].mean()
    err_imin = np.abs(polcam.separate(st, method="imin").diffuse - d)[red].mean()
    assert err_ours < 0.5 * err_imin


def test_tinted_illuminant_is_recovered():
    from polcam.separation._illuminant import estimate_illuminant

    d = _scene()
    h, w = d.shape[:2]
    gamma = np.array([1.2, 1.0, 0.7])
    gamma = gamma / gamma.mean()
    spec = 0.15 * (_bump(h, w, 16, 12, 3) + _bump(h, w, 16, 32, 3) + _bump(h, w, 16, 52, 3))
    st = _stack(d * gamma, spec, gamma, rho_s=0.8, phi_s=0.3)
    est = estimate_illuminant(st)
    assert est.source == "polarized"
    np.testing.assert_allclose(est.colour, gamma, atol=1e-3)
    res = polcam.separate(st, method="polarized-residual", **_STEPS)
    np.testing.assert_allclose(res.info["illuminant"], gamma, atol=1e-3)
    assert np.max(np.abs(res.diffuse - d * gamma)) < 0.02


def test_polarizer_efficiency_calibration_and_implied_efficiency():
    from polcam.separation._illuminant import estimate_illuminant

    d = _scene()
    h, w = d.shape[:2]
    spec = 0.25 * (_bump(h, w, 36, 32, 3) + _bump(h, w, 16, 32, 3))
    eff = np.array([0.6, 0.9, 1.0])
    st = _stack(d, spec, (1, 1, 1), rho_s=1.0, phi_s=0.2)
    # a sensor whose polarizers pass the polarized part per colour at eff
    mean = st.mean(axis=0)
    st_b = mean + (st - mean) * eff
    bad = estimate_illuminant(st_b)
    assert bad.source == "highlights"               # the polarized colour disagrees with the highlights
    assert np.linalg.norm(bad.colour / bad.colour.sum() - 1 / 3) < 0.03
    good = estimate_illuminant(st_b, efficiency=eff)
    assert good.source == "calibration"
    np.testing.assert_allclose(good.colour, 1.0, atol=1e-3)
    res = polcam.separate(st_b, method="polarized-residual", **_STEPS, efficiency=tuple(eff))
    assert np.max(np.abs(res.diffuse - d)) < 2e-3
    with pytest.raises(MethodError, match="efficiency"):
        estimate_illuminant(st_b, efficiency=(0.5, 0.0, 1.0))


def test_partially_polarized_diffuse_is_kept():
    d = _scene()
    h, w = d.shape[:2]
    spec = 0.3 * (_bump(h, w, 16, 12, 3) + _bump(h, w, 16, 52, 3))
    st = _stack(d, spec, (1, 1, 1), rho_s=1.0, phi_s=0.7, rho_d=0.15)
    res = polcam.separate(st, method="polarized-residual", **_STEPS)
    imin = polcam.separate(st, method="imin")
    patch = np.zeros((h, w), bool)
    patch[8:24, 4:20] = True                        # the red patch, under a highlight
    patch[8:24, 44:60] = True                       # the blue one
    err = np.abs(res.diffuse - d)[patch].mean()
    assert err < 0.01
    assert err < 0.5 * np.abs(imin.diffuse - d)[patch].mean()
    # with the option off, the perpendicular polarized diffuse light is treated as specular
    off = polcam.separate(st, method="polarized-residual", **_STEPS, diffuse_polarization=False)
    assert np.abs(off.diffuse - d)[patch].mean() > err


def test_diffuse_bounds_and_one_specular_colour():
    rng = np.random.default_rng(1)
    st = np.clip(rng.uniform(0, 1, (4, 24, 24, 3)), 0, 1)
    res = polcam.separate(st, method="polarized-residual")
    assert np.all(res.diffuse >= 0)
    assert np.all(res.diffuse <= st.mean(0) + 1e-6)
    # pure noise: its polarized colour is within its noise of white
    assert res.info["illuminant_source"] == "white balance"


def test_blind_channels_lose_the_seeing_channels_multiple_of_g_without_pits():
    # step 4 on pixels whose red channel is clipped at all four angles (blind: its removal reads 0).
    # Row 0: green and blue each lose 0.2 G of polarized light: red loses the same 0.2 G, where the
    # old reading (the least over all three channels, red's 0) removed nothing anywhere.  Row 1: red
    # and green blind, blue (under a weak blue illuminant) misreads a large removal, 0.38 of its 0.73:
    # the same multiple of G would take red and green to 0, a dark pit.  Per unit of G they measure
    # less than blue (0.83 and 0.77 against 1.83): the clipping hides more of them than the pixel's
    # colour shows, so the pixel is left as measured.  Row 2: every channel blind: nothing is
    # removed.
    g = np.array([1.2, 1.3, 0.4], np.float32)
    ic = np.array([[[1.0, 0.7, 0.4]], [[1.0, 1.0, 0.73]], [[1.0, 1.0, 1.0]]], np.float32)
    removed = np.array([[[0.0, 0.26, 0.08]], [[0.0, 0.0, 0.38]], [[0.0, 0.0, 0.0]]], np.float32)
    blind = np.array([[[True, False, False]], [[True, True, False]], [[True, True, True]]])
    coherent = np.zeros((3, 1), np.float32)
    args = (ic - removed, ic, g, 0.5, coherent)
    from polcam.separation._one_colour import one_specular_colour

    d = one_specular_colour(*args, blind=blind)
    old = one_specular_colour(*args)
    np.testing.assert_allclose(old[0], ic[0])                          # the blind red hid the rest
    np.testing.assert_allclose(d[0, 0], ic[0, 0] - 0.2 * g, atol=1e-5)  # one colour, red included
    np.testing.assert_allclose(d[1], ic[1])
    np.testing.assert_allclose(d[2], ic[2])


def test_noise_estimate_matches_the_planted_deviation():
    from polcam.separation._polarization_noise import stokes_noise

    rng = np.random.default_rng(5)
    d = _scene(96, 128)
    spec = 0.3 * (_bump(96, 128, 30, 30, 6) + _bump(96, 128, 60, 90, 8))
    st = _stack(d, spec, (1, 1, 1), rho_s=0.6, phi_s=0.4)
    sigma_i = 0.01
    noisy = st + rng.normal(0.0, sigma_i, st.shape)
    sig = stokes_noise(noisy.astype(np.float32), noisy.mean(0).astype(np.float32))
    # q = (I0 - I90) / 2 has deviation sigma_I / sqrt 2
    np.testing.assert_allclose(np.median(sig), sigma_i / np.sqrt(2), rtol=0.1)
    # a noise-free stack, highlights and all: no noise
    assert np.max(stokes_noise(st.astype(np.float32), st.mean(0).astype(np.float32))) < 1e-6
    # a stack whose four images have unequal gains breaks I0 + I90 = I45 + I135 everywhere, but the
    # spatial high-pass of q and u sees no noise: the estimate stays near zero
    gains = np.array([1.03, 1.0, 0.98, 1.0])[:, None, None, None]
    assert np.median(stokes_noise((st * gains).astype(np.float32), st.mean(0).astype(np.float32))) < 2e-3


def test_noise_is_not_removed_as_polarized_light():
    # an unpolarized scene with noise: Isv is the noise's amplitude, whose mean is positive; the
    # garrote takes it out, so the diffuse stays unbiased where Imin is biased low
    rng = np.random.default_rng(2)
    d = _scene(96, 128)
    st = _stack(d, np.zeros(d.shape[:2]), (1, 1, 1), rho_s=0.0, phi_s=0.0)
    noisy = st + rng.normal(0.0, 0.005, st.shape)
    ours = polcam.separate(noisy, method="polarized-residual").diffuse
    off = polcam.separate(noisy, method="polarized-residual", noise="off").diffuse
    imin = polcam.separate(noisy, method="imin").diffuse
    bias = lambda x: float(np.mean(x - d))  # noqa: E731
    assert bias(imin) < -0.004                        # the Rayleigh mean of the noise amplitude
    assert abs(bias(ours)) < 0.3 * abs(bias(off))
    assert abs(bias(ours)) < 0.0015


def test_clipped_strongly_polarized_highlight():
    # a bright, fully polarized white highlight on a coloured patch clips some angles of the red and
    # green channels: declipping recovers the diffuse there, beyond what imin (or no declipping) does
    d = _scene()
    h, w = d.shape[:2]
    spec = 0.9 * _bump(h, w, 16, 12, 2.5)
    st = np.minimum(_stack(d, spec, (1, 1, 1), rho_s=1.0, phi_s=0.3), 1.0)
    part = (st >= 1.0).any(axis=(0, 3)) & ~(st >= 1.0).all(axis=0).any(axis=-1)
    assert part.sum() >= 8
    err = lambda x: float(np.abs(x - d)[part].mean())  # noqa: E731
    ours = polcam.separate(st, method="polarized-residual", **_STEPS).diffuse
    off = polcam.separate(st, method="polarized-residual", **_STEPS, declip=False).diffuse
    imin = polcam.separate(st, method="imin").diffuse
    assert err(ours) < 0.5 * err(off)
    assert err(ours) < 0.5 * err(imin)
    assert np.all(ours <= st.mean(axis=0) + 1e-6)


def test_mono_clipped_strongly_polarized_highlight():
    # the same on a mono stack: a fully polarized highlight that clips one or two angles (AoLP 34 deg;
    # near 22.5 deg the two unclipped samples would sit symmetric about the minimum, unsolvable)
    d = _scene().mean(axis=-1)
    h, w = d.shape
    spec = 0.8 * _bump(h, w, 36, 32, 3)
    st = np.minimum(synthesize(spec, spec, np.full((h, w), 0.6)) + d, 1.0)
    part = (st >= 1.0).any(axis=0) & ((st >= 1.0).sum(axis=0) <= 2)
    assert part.sum() >= 8
    err = lambda x: float(np.abs(x - d)[part].mean())  # noqa: E731
    ours = polcam.separate(st, method="polarized-residual", unpolarized="measured").diffuse
    off = polcam.separate(st, method="polarized-residual", unpolarized="measured", declip=False).diffuse
    assert err(ours) < 0.5 * err(off)


def test_overexposed_white_surface_under_a_tinted_light_stays_diffuse():
    # WhiteGrey's white and grey checker under a green-heavy light (0.55, 1, 0.7), bright enough that
    # the green channel of the white squares is clipped at all four angles away from any highlight:
    # their colour is not measured, so the colour prior must not take them for a paler shade of a
    # coloured material (a prior blind to clipping removed up to 38 % of such a pixel's light;
    # docs/methods/polarized-residual.md)
    import dataclasses

    from polcam.synth.render import render
    from polcam.synth.scenes import scene

    r = render(dataclasses.replace(scene("WhiteGrey"), light_color=(0.55, 1.0, 0.7), light_intensity=1.6),
               size=64, seed=0)
    st = np.asarray(r.stack, np.float32)
    measured = st.mean(axis=0)
    wall = (measured.max(axis=-1) >= 0.98) & ((measured - r.diffuse).sum(axis=-1) < 0.02) & r.mask
    assert wall.sum() >= 50                                # clipped, with (nearly) no specular light
    d = polcam.separate(st, method="polarized-residual").diffuse
    kept = d[wall].sum(axis=-1) / measured[wall].sum(axis=-1)
    assert kept.min() > 0.97


@pytest.mark.parametrize("opt", [{"context": 0}, {"hue_bins": 2}, {"max_ratio": -1}, {"noise": "median"}, {"declip": "yes"},
                                 {"illuminant": (1, 0, 1)}, {"polarized_threshold": 2}, {"edge_fit": 3},
                                 {"edge_fit": True}, {"unpolarized": "all"}, {"evidence_window": 0}, {"one_colour": 1},
                                 {"aliasing": "yes"}])
def test_bad_options(opt):
    st = np.zeros((4, 8, 8, 3))
    with pytest.raises(MethodError):
        polcam.separate(st, method="polarized-residual", **opt)


@pytest.mark.parametrize("name, corner", [("astronaut", (80, 120)), ("coffee", (100, 100))])
def test_demosaicing_aliasing_is_not_taken_for_polarized_light(name, corner):
    # an unpolarized photograph through the mosaic: its only polarization is the demosaicing's, and
    # it sits at edges; counting the aliasing as noise (the default) keeps more of the edges' light
    y, x = corner
    rgb = load_photo(name)[y:y + 128, x:x + 128] * 0.8
    zero = np.zeros_like(rgb)
    raw = mosaic_stack(np.clip(synthesize(rgb, zero, zero), 0.0, 1.0), layout="imx250myr")
    cam = np.clip(polcam.demosaic(raw, layout="imx250myr"), 0.0, 1.0).astype(np.float32)
    measured = cam.mean(axis=0)
    edges = np.asarray(aliasing_deviation(measured)).sum(axis=-1) > ALIASING * 0.6 * measured.sum(axis=-1)
    kept = {}
    for aliasing in (True, False):
        d = polcam.separate(cam, method="polarized-residual", unpolarized="none", aliasing=aliasing).diffuse
        assert np.all(d <= measured + 1e-6)
        kept[aliasing] = float(d[edges].sum() / measured[edges].sum())
    assert kept[True] > kept[False] + 0.002, kept


def test_mono_stack_gives_a_mono_layer():
    res = polcam.separate(np.full((4, 8, 8), 0.2), method="polarized-residual")
    assert res.diffuse.shape == (8, 8)
    np.testing.assert_allclose(res.diffuse, 0.2, atol=1e-6)



def _noisy_mono_highlight(spec_scale, rho, seed=0):
    """A grey ramp with a partly polarized highlight, 0.3 % noise: (4, 64, 64) in [0, 1]."""
    h, w = 64, 64
    d = 0.2 + 0.3 * np.mgrid[:h, :w][1] / w
    spec = spec_scale * _bump(h, w, 30, 34, 5)
    st = synthesize(spec, rho * spec, np.full((h, w), 0.6)) + d
    rng = np.random.default_rng(seed)
    return np.clip(st + rng.normal(0, 0.003, st.shape), 0, 1)


def test_mono_stack_is_the_colour_path_on_a_grey_stack():
    # a mono sensor is a colour sensor whose channels see the same light: up to the learned stage the
    # mono layer is the colour path's on the stack repeated over three channels under a white illuminant
    st = _noisy_mono_highlight(0.3, 0.5)
    assert st.max() < 0.95
    before = polcam.separate(st, method="polarized-residual", unpolarized="none")
    grey = polcam.separate(np.repeat(st[..., None], 3, axis=-1), method="polarized-residual", illuminant=(1, 1, 1),
                           unpolarized="none")
    np.testing.assert_allclose(before.diffuse, grey.diffuse.mean(axis=-1), atol=1e-6)
    # the stage runs with the mono weights (and the mono bound: the polarized light seen at the pixel)
    mono = polcam.separate(st, method="polarized-residual")
    inputs = pres.learned_inputs(st)
    np.testing.assert_allclose(mono.diffuse, pres.learned_layer(inputs, load_weights(mono=True)).mean(axis=-1),
                               atol=1e-6)
    # it removes light from the highlight (the whole stage runs), and a mono camera has no colour to report
    assert mono.info["learned_specular"] > 0 and np.all(mono.diffuse <= st.mean(axis=0) + 1e-6)
    assert not {"illuminant", "illuminant_source", "efficiency"} & set(mono.info)
    layers = pres.stages(st)
    assert set(layers) == {"imin", "diffuse_polarization", "evidence_bounded", "diffuse"}
    assert all(v.shape == st.shape[1:] for v in layers.values())
    np.testing.assert_allclose(layers["diffuse"], mono.diffuse, atol=1e-6)


def test_mono_clipped_region_is_left_as_measured():
    # without colour the border cannot show that one material lies under a clipped region, so a mono
    # stack's clipped highlight is left as measured and counted; the same stack as a grey colour
    # stack (whose one-material test the grey border passes) is filled
    from polcam.separation import SATURATED

    st = _noisy_mono_highlight(3.0, 0.3)
    clipped = st.mean(axis=0) >= SATURATED
    assert clipped.sum() > 50
    mono = polcam.separate(st, method="polarized-residual")
    np.testing.assert_allclose(mono.diffuse[clipped], st.mean(axis=0)[clipped], atol=1e-6)
    assert mono.info["clipped_filled"] == 0 and mono.info["clipped_as_measured"] == clipped.sum()
    grey = polcam.separate(np.repeat(st[..., None], 3, axis=-1), method="polarized-residual", illuminant=(1, 1, 1))
    assert grey.info["clipped_filled"] == clipped.sum()


def _mono_scene(rho):
    h, w = 64, 64
    yy, xx = np.mgrid[:h, :w]
    d = 0.2 + 0.3 * xx / w                         # smooth diffuse shading
    spec = 0.3 * _bump(h, w, 30, 34, 4)
    st = synthesize(spec, rho * spec, np.full((h, w), 0.6)) + d
    return st, d


@pytest.mark.parametrize("rho", [0.4, 0.5, 1.0])
def test_mono_residual_follows_the_polarized_highlight(rho):
    # unpolarized="measured" on a mono stack: k from the gradients of Imin and the polarized light
    st, d = _mono_scene(rho)
    res = polcam.separate(st, method="polarized-residual", unpolarized="measured")
    imin = polcam.separate(st, method="imin").diffuse
    assert res.diffuse.shape == d.shape
    # the unpolarized share (1 - rho) of the highlight is found: k = (1 - rho) / rho
    assert res.info["residual_ratio"] == pytest.approx((1 - rho) / rho, rel=0.05, abs=0.02)
    err = np.abs(res.diffuse - d).max()
    if rho < 1:   # at least 90 % of the unpolarized specular light that imin leaves is removed
        assert err < 0.1 * np.abs(imin - d).max()
    else:         # a fully polarized highlight: nothing beyond the polarized light is removed
        assert err < 1e-3


def test_mono_unpolarized_white_kept():
    h, w = 32, 32
    d = np.full((h, w), 0.3)
    d[8:24, 8:24] = 0.9                            # a bright unpolarized object
    st = np.repeat(d[None], 4, axis=0)
    res = polcam.separate(st, method="polarized-residual")
    np.testing.assert_allclose(res.diffuse, d, atol=1e-6)


@pytest.mark.parametrize("opts", [{"evidence": True}, {}])
def test_polarized_diffuse_without_specular_is_kept(opts):
    # coloured surfaces whose diffuse light is partly polarized (DoLP 0.15, as near an occluding
    # contour) and no specular light at all: nothing is removed from the coloured patches (by
    # default because the removal's colour is the body's: step 4's two-colour fit sets it apart)
    d = _scene()
    st = _stack(d, np.zeros(d.shape[:2]), (1, 1, 1), rho_s=0.0, phi_s=0.3, rho_d=0.15)
    res = polcam.separate(st, method="polarized-residual", illuminant=(1, 1, 1), **opts)
    patches = np.zeros(d.shape[:2], bool)
    patches[9:23, 5:19] = patches[9:23, 25:39] = patches[9:23, 45:59] = True   # inside the red, green, blue
    np.testing.assert_allclose(res.diffuse[patches], d[patches], atol=2e-3)
    # imin removes the polarized diffuse light
    assert np.max(np.abs(polcam.separate(st, method="imin").diffuse[patches] - d[patches])) > 0.02


def test_saturated_highlight_is_filled_from_its_neighbours():
    # a strong highlight clips the red channel at all four angles: its polarization there is not
    # measured, and the diffuse of the clipped pixels comes from their neighbours
    h, w = 48, 64
    d = np.broadcast_to(np.array([0.6, 0.3, 0.2]), (h, w, 3)).copy()
    spec = 0.8 * _bump(h, w, 24, 32, 4)
    st = np.clip(_stack(d, spec, (1, 1, 1), rho_s=0.3, phi_s=0.5), 0.0, 1.0)
    clipped = st.mean(axis=0).max(axis=-1) >= 0.98
    assert 10 < clipped.sum() < 200
    res = polcam.separate(st, method="polarized-residual", **_STEPS, illuminant=(1, 1, 1))
    err = np.abs(res.diffuse - d)[clipped]
    assert err.mean() < 0.12
    # k = (1 - rho) / rho is measured on unclipped pixels only (a clipped red channel makes a pixel look
    # paler, more specular: with them, k came out 13 % high)
    assert abs(res.info["residual_ratio"] - 0.7 / 0.3) < 0.1 * 0.7 / 0.3
    # the polarization minimum keeps the highlight's unpolarized and unmeasured light
    err_imin = np.abs(polcam.separate(st, method="imin").diffuse - d)[clipped]
    assert err_imin.mean() > 3 * err.mean() and err_imin.max() > 3 * err.max()


def test_overexposed_diffuse_surface_is_left_as_measured():
    # a bright matte patch clipped in red, no polarized light around it: not a highlight, not filled
    d = _scene()
    d[30:42, 22:42] = (1.3, 0.8, 0.5)
    st = np.clip(_stack(d, np.zeros(d.shape[:2]), (1, 1, 1), rho_s=0.0, phi_s=0.0), 0.0, 1.0)
    res = polcam.separate(st, method="polarized-residual", illuminant=(1, 1, 1))
    np.testing.assert_allclose(res.diffuse[30:42, 22:42], st.mean(axis=0)[30:42, 22:42], atol=1e-6)


@pytest.mark.parametrize("opts", [{"evidence": True}, {}])
def test_polarized_diffuse_on_a_thin_contour_keeps_its_own_colour(opts):
    # diffuse light polarized only along one-pixel contours (DoLP 0.3, as at an occluding contour)
    # between patches of different colours: the decomposition uses each pixel's own amplitudes, so
    # the smoothing of the polarization axis does not mix the neighbours' colours into it; and
    # where the highlight's coherent polarization reaches them, step 4 reads the body-coloured
    # removal as diffuse (its projection on G is capped at the two-colour fit's specular part)
    d = _scene()
    h, w = d.shape[:2]
    rho = np.zeros((h, w))
    rho[8:24, 19] = rho[8:24, 24] = rho[8:24, 39] = rho[8:24, 44] = 0.3
    st = synthesize(d, rho[..., None] * d, np.full(d.shape, 0.3 + np.pi / 2))
    spec = 0.3 * _bump(h, w, 36, 32, 4)
    st = st + synthesize(spec[..., None] * np.ones(3), spec[..., None] * np.ones(3), np.full(d.shape, 0.3))
    res = polcam.separate(st, method="polarized-residual", illuminant=(1, 1, 1), **opts)
    rim = rho > 0
    err = np.abs(res.diffuse - d)[rim]
    assert err.max() < 0.01
    # imin takes the contours' polarized light out
    assert np.abs(polcam.separate(st, method="imin").diffuse - d)[rim].max() > 0.05


def test_no_diffuse_polarization_beyond_the_physical_bound_near_brewster(monkeypatch):
    # near Brewster's angle the highlights are strongly polarized and partly clipped: their amplitudes
    # then fit alpha G + beta e with large alpha and beta of opposite signs, a "diffuse" DoLP well
    # above what diffuse light can have; the bound (_MAX_DIFFUSE_DOLP) removes that light as specular
    import polcam.separation._residual as pr
    from polcam.bench.quality import score
    from polcam.synth.render import render
    from polcam.synth.scenes import scene

    r = render(scene("Brewster"), size=64, seed=0)
    bounded = score(polcam.separate(r.stack, method="polarized-residual", **_STEPS).diffuse, r.diffuse, r.mask)[2]
    monkeypatch.setattr(pr, "_MAX_DIFFUSE_DOLP", 1e9)
    unbounded = score(polcam.separate(r.stack, method="polarized-residual", **_STEPS).diffuse, r.diffuse, r.mask)[2]
    assert bounded > unbounded + 0.2


def test_weakly_polarized_diffuse_beside_a_highlight_is_kept():
    # an orange surface with a partly polarized white highlight on one side and, apart from it, a band
    # whose diffuse light is weakly polarized (DoLP 0.03, perpendicular to the specular's): the band's
    # polarized light has the surface's colour, so it stays in the diffuse (a
    # misfit bound of 3 % of the intensity would lose the band's polarized light)
    h, w = 48, 64
    d = np.broadcast_to(np.array([0.5, 0.25, 0.15]), (h, w, 3)).copy()
    spec = 0.3 * _bump(h, w, 24, 16, 4)
    band = np.zeros((h, w), bool)
    band[:, 44:56] = True
    st = _stack(d, spec, (1, 1, 1), rho_s=0.3, phi_s=0.4)
    st = st + synthesize(np.zeros_like(d), np.where(band, 0.03, 0.0)[..., None] * d,
                         np.full(d.shape, 0.4 + np.pi / 2))
    res = polcam.separate(st, method="polarized-residual", **_STEPS, illuminant=(1, 1, 1))
    amplitude = 0.03 * d[band]
    inner = np.zeros((h, w), bool)
    inner[:, 46:54] = True                     # away from the band's edges, where the smoothed axis mixes
    assert np.abs(res.diffuse[inner] - d[inner]).max() < 1e-3
    # imin removes it all
    err_imin = np.abs(polcam.separate(st, method="imin").diffuse[band] - d[band])
    assert err_imin.mean() > 0.9 * amplitude.mean()
    # and the highlight's unpolarized specular light is still removed
    hl = spec > 0.05
    assert (np.abs(res.diffuse[hl] - d[hl]).mean()
            < 0.4 * np.abs(polcam.separate(st, method="imin").diffuse[hl] - d[hl]).mean())


@pytest.mark.parametrize("channel", [1, 2])
def test_polarization_off_the_body_colour_is_not_kept(channel):
    # one channel's polarization (green or blue) on the red patch: neither the illuminant's colour nor
    # the surface's, as demosaicing's false polarization at a colour edge; it is not kept as a polarized
    # diffuse part, so the diffuse stays under Imin there
    d = _scene()
    st = _stack(d, np.zeros(d.shape[:2]), (1, 1, 1), rho_s=0.0, phi_s=0.3)
    pol = np.zeros_like(d)
    pol[8:24, 4:20, channel] = 0.03
    st = st + synthesize(np.zeros_like(d), pol, np.full(d.shape, 0.3))
    ic = st.mean(axis=0)
    imin = ic - np.hypot(0.5 * (st[0] - st[2]), 0.5 * (st[1] - st[3]))
    res = polcam.separate(st, method="polarized-residual", **_STEPS, illuminant=(1, 1, 1))
    assert float((res.diffuse - imin)[8:24, 4:20].max()) < 1e-4


@pytest.mark.parametrize("rho", [0.2, 0.3, 0.5])
def test_residual_ratio_on_a_wide_highlight_needs_a_context_beyond_it(rho):
    # a uniform orange surface (smooth shading) with one wide white highlight of specular DoLP rho:
    # the unpolarized / polarized ratio k = (1 - rho) / rho is measured against the body colour, which
    # only a neighbourhood wider than the highlight sees (the default context is 0.12 of the image side;
    # at 0.08 a highlight of Gaussian radius 12 px on 128 px gives k half the truth)
    h = w = 128
    d = np.array([0.5, 0.3, 0.2]) * (0.6 + 0.4 * _bump(h, w, 64, 64, 60))[..., None]
    spec = 0.35 * _bump(h, w, 64, 64, 12)
    st = _stack(d, spec, (1, 1, 1), rho_s=rho, phi_s=0.4)
    k_true = (1 - rho) / rho
    hl = spec > 0.1
    err_imin = np.abs(polcam.separate(st, method="imin").diffuse - d)[hl].mean()
    wide = polcam.separate(st, method="polarized-residual", **_STEPS, illuminant=(1, 1, 1), context=0.3)
    assert abs(wide.info["residual_ratio"] - k_true) < 0.05 * k_true
    assert np.abs(wide.diffuse - d)[hl].mean() < 0.03 * err_imin
    narrow = polcam.separate(st, method="polarized-residual", **_STEPS, illuminant=(1, 1, 1), context=0.05)
    assert narrow.info["residual_ratio"] < 0.8 * k_true


def test_stages_show_each_step():
    from polcam.separation.polarized_residual import separate_polarized_residual, stages

    d = _scene()
    h, w = d.shape[:2]
    spec = 0.35 * _bump(h, w, 16, 12, 3)            # highlight on the red patch, DoLP 0.5
    st = _stack(d, spec, (1, 1, 1), rho_s=0.5, phi_s=1.0)
    out = stages(st, **_STEPS)
    assert set(out) == {"imin", "polarized_removed", "ratio_removed", "prior_removed", "evidence_bounded", "diffuse"}
    final, _ = separate_polarized_residual(st, **_STEPS)
    np.testing.assert_array_equal(out["diffuse"], final)
    for a, b in [("polarized_removed", "ratio_removed"), ("ratio_removed", "prior_removed")]:
        assert np.all(out[b] <= out[a] + 1e-6), (a, b)
    # the evidence bound only gives light back, never below the pixel's surroundings' floor
    assert np.all(out["evidence_bounded"] >= out["prior_removed"] - 1e-6)
    # step 2 removes the polarized half of the highlight exactly; step 5 then most of the other half
    hl = spec > 0.1
    unpol = d + 0.5 * spec[..., None]
    assert np.max(np.abs(out["polarized_removed"][hl] - unpol[hl])) < 2e-3
    assert np.abs(out["ratio_removed"] - d)[hl].mean() < 0.3 * np.abs(out["polarized_removed"] - d)[hl].mean()
    # noise-free: imin is Ic less the polarized amplitude, here d plus the unpolarized half
    np.testing.assert_allclose(out["imin"], unpol, atol=1e-5)
    mono = stages(st.mean(axis=-1), unpolarized="measured")
    assert set(mono) == {"imin", "diffuse"}
    np.testing.assert_allclose(mono["imin"], unpol.mean(axis=-1), atol=1e-5)


def _two_cluster_ramp():
    """Four matte patches above a ramp of one material drifting from blue to cyan, no specular light.

    With these patches `shen13`'s clustering puts the ramp into two clusters whose intensity
    ratios differ (1.52 and 1.59), so its removal jumps where the cluster changes.
    """
    img = np.zeros((64, 128, 3))
    for k, c in enumerate([(0.32, 0.29, 0.33), (0.48, 0.29, 0.08), (0.23, 0.57, 0.29), (0.35, 0.28, 0.14)]):
        img[:32, 32 * k:32 * (k + 1)] = c
    t = np.linspace(0, 1, 128)[:, None]
    img[32:] = (np.array([0.25, 0.32, 0.81]) * (1 - t) + np.array([0.29, 0.8, 0.73]) * t)[None]
    return img


def test_colour_prior_has_no_jump_at_a_cluster_boundary():
    from polcam.separation._residual import _specular_free
    from polcam.separation.shen13 import cluster_ratios, ratio_specular

    img = _two_cluster_ramp()
    q, _ = cluster_ratios(img)
    assert len(np.unique(q[40])) == 2                      # the ramp is split: the case this guards
    hard = ratio_specular(img, q)[32:]
    soft = (img - _specular_free(img, 9)).max(axis=-1)[32:]
    jump_hard = np.abs(np.diff(hard, axis=1)).max()
    assert jump_hard > 0.01
    assert np.abs(np.diff(soft, axis=1)).max() < 0.2 * jump_hard


def test_colour_prior_on_one_material_is_shen13s():
    # one material (a shaded red disc with a white highlight) has one ratio: smoothing changes nothing
    from polcam.separation._residual import _specular_free
    from polcam.separation.shen13 import separate_shen13

    h, w = 48, 64
    yy, xx = np.mgrid[:h, :w]
    disc = ((yy - 24) ** 2 + (xx - 32) ** 2) < 20 ** 2
    shade = np.clip(1.0 - ((yy - 18) ** 2 + (xx - 26) ** 2) / 900.0, 0.3, 1.0)
    img = np.where(disc[..., None], shade[..., None] * np.array([0.7, 0.2, 0.15]), 0.0)
    img = np.clip(img + 0.25 * _bump(h, w, 20, 28, 3)[..., None] * disc[..., None], 0.0, 1.0)
    ref = separate_shen13(img)[0]
    np.testing.assert_allclose(_specular_free(img, 9), ref, atol=1e-5)
    assert np.abs(img - ref).max() > 0.1                   # and shen13 does remove the highlight here


# ---------------------------------------------------------------------------
# the same method on PyTorch tensors (one implementation over polcam._xp and polcam._imageops)
# ---------------------------------------------------------------------------

def _torch_cases():
    """Stacks that take every branch: the colour prior, diffuse polarization, the clipped fill, mono."""
    from polcam.synth.render import render
    from polcam.synth.scenes import scene

    d = _scene()
    h, w = d.shape[:2]
    spec = 0.35 * (_bump(h, w, 16, 12, 3) + _bump(h, w, 36, 32, 4))
    rng = np.random.default_rng(7)
    noisy = np.clip(_stack(d, spec, (1.0, 0.9, 0.8), rho_s=0.4, phi_s=0.3, rho_d=0.05)
                    + rng.normal(0, 2e-3, (4, h, w, 3)), 0, 1)
    d2 = np.broadcast_to(np.array([0.6, 0.3, 0.2]), (h, w, 3)).copy()
    clipped = np.clip(_stack(d2, 0.8 * _bump(h, w, 24, 32, 4), (1, 1, 1), rho_s=0.3, phi_s=0.5), 0, 1)
    bunny = np.asarray(render(scene("Bunny5"), size=64, seed=1).stack)
    return {"noisy tinted": (noisy, {}), "clipped": (clipped, {"illuminant": (1, 1, 1)}),
            "Bunny5": (bunny, {}), "Bunny5 mono": (bunny.mean(axis=-1), {}),
            "options": (noisy, {"efficiency": (1.0, 0.9, 0.8), "noise": "rice", "residual_model": "hue"}),
            "measured steps": (noisy, {"unpolarized": "measured"}),
            "measured clipped": (clipped, {"illuminant": (1, 1, 1), "unpolarized": "measured"}),
            "learned": (bunny, {"unpolarized": "learned"}), "learned noisy": (noisy, {"unpolarized": "learned"})}


@pytest.fixture(scope="module")
def torch_cases():
    return _torch_cases()


def test_torch_matches_numpy(torch_cases, dev):
    torch = pytest.importorskip("torch")
    from polcam.separation.polarized_residual import separate_polarized_residual, stages

    for name, (st, opts) in torch_cases.items():
        want, want_info = separate_polarized_residual(st, **opts)
        got, got_info = separate_polarized_residual(torch.as_tensor(st, device=dev), **opts)
        # a tensor in, a float32 tensor out on its device
        assert isinstance(got, torch.Tensor) and got.device.type == dev.split(":")[0], name
        assert got.dtype == torch.float32 and tuple(got.shape) == want.shape, name
        assert got_info.keys() == want_info.keys(), name
        assert got_info.get("illuminant_source") == want_info.get("illuminant_source"), name
        assert got_info.get("residual_ratio_source") == want_info.get("residual_ratio_source"), name
        assert got_info["residual_ratio"] == pytest.approx(want_info["residual_ratio"], rel=1e-4, abs=1e-6), name
        # float32 sums in another order: equal to a few units of the last place
        np.testing.assert_allclose(got.cpu().numpy(), want, rtol=0, atol=2e-5, err_msg=name)
        assert np.abs(want - st.mean(axis=0)).max() > 0.01, name        # something was removed
    # the step layers too, and device= on a numpy stack gives numpy back
    st, _ = torch_cases["noisy tinted"]
    want = stages(st)
    got = stages(st, device=dev)
    assert got.keys() == want.keys()
    for k in want:
        assert isinstance(got[k], np.ndarray), k
        np.testing.assert_allclose(got[k], want[k], rtol=0, atol=2e-5, err_msg=k)


def test_device_option_through_separate(dev):
    pytest.importorskip("torch")
    st, _ = _torch_cases()["noisy tinted"]
    want = polcam.separate(st, method="polarized-residual")
    got = polcam.separate(st, method="polarized-residual", device=dev)
    assert isinstance(got.diffuse, np.ndarray)
    np.testing.assert_allclose(got.diffuse, want.diffuse, rtol=0, atol=2e-5)
    np.testing.assert_allclose(got.diffuse + got.specular, st.mean(axis=0), atol=1e-6)


def test_bad_device_is_refused():
    st = _stack(_scene(), np.zeros((48, 64)), (1, 1, 1), rho_s=0.0, phi_s=0.0)
    with pytest.raises(MethodError, match="device=3"):
        polcam.separate(st, method="polarized-residual", device=3)
    try:
        import torch
    except ImportError:
        with pytest.raises(MethodError, match="needs PyTorch"):
            polcam.separate(st, method="polarized-residual", device="cpu")
        return
    with pytest.raises(MethodError, match="not a torch device name"):
        polcam.separate(st, method="polarized-residual", device="no-such-device")
    if not torch.cuda.is_available():
        with pytest.raises(MethodError, match="no CUDA GPU"):
            polcam.separate(st, method="polarized-residual", device="cuda")


def test_a_tiny_change_of_the_input_gives_a_tiny_change_of_the_layer():
    # every unclipped sample of a rendered scene scaled by 1 + N(0, 3e-7), far below any camera's
    # noise: the diffuse layer moves by less than 0.01 anywhere. Unlit pixels (their residual ~1e-11,
    # their hue that of rounding noise) must not lend their neighbours' saturation to a random hue:
    # when they did, Armadillo's layer moved by up to 0.28 at 64 px
    from polcam.separation.polarized_residual import separate_polarized_residual
    from polcam.synth.render import render
    from polcam.synth.scenes import scene

    st = np.asarray(render(scene("Armadillo"), size=64, seed=0).stack, np.float32)
    d0, _ = separate_polarized_residual(st)
    assert np.abs(d0 - st.mean(axis=0)).max() > 0.1        # it removes highlights
    for seed in range(3):
        noise = np.random.default_rng(seed).normal(0, 3e-7, st.shape)
        p = np.where(st >= 0.98, st, st * (1 + noise)).astype(np.float32)
        d1, _ = separate_polarized_residual(p)
        assert np.abs(d1 - d0).max() < 0.01, seed


def test_torch_path_copies_to_the_host_only_where_documented(torch_cases, monkeypatch):
    # on a GPU an implicit numpy conversion of a tensor fails, and a hidden copy costs time: make
    # every implicit one raise, and record who asks for the explicit ones (docs/methods/polarized-residual.md,
    # "Backends": the noise estimate's bins, the white test's block sums, the highlights' colour
    # sum, and the clipped fill)
    import inspect

    torch = pytest.importorskip("torch")
    from polcam import _xp
    from polcam.separation.polarized_residual import separate_polarized_residual

    def refuse(self, *args, **kwargs):
        raise AssertionError("implicit host copy of a tensor")

    callers = set()
    real = _xp.TorchXP.to_numpy

    def spy(a):
        callers.add(inspect.stack()[1].function)
        return real(a)

    monkeypatch.setattr(torch.Tensor, "__array__", refuse)
    monkeypatch.setattr(_xp.TorchXP, "to_numpy", staticmethod(spy))
    for name, (st, opts) in torch_cases.items():
        separate_polarized_residual(torch.as_tensor(st), **opts)
    assert callers <= {"_binned_spread", "_white_distance", "_total_chromaticity", "_highlight_colour",
                       "fill_clipped_highlights"}, callers
    assert "fill_clipped_highlights" in callers                   # the clipped case took that path
