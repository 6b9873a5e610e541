"""The illuminant estimator: planted colours, efficiencies and the highlights check."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.polarimetry import synthesize
from polcam.separation._illuminant import estimate_illuminant, highlight_colour, polarized_colour


def _stack(gamma, *, diffuse=(0.3, 0.3, 0.3), rho=0.8, eff=(1.0, 1.0, 1.0)):
    h, w = 40, 40
    yy, xx = np.mgrid[:h, :w]
    s = 0.3 * np.exp(-((yy - 20) ** 2 + (xx - 20) ** 2) / 18.0)
    spec = s[..., None] * np.asarray(gamma)
    d = np.broadcast_to(np.asarray(diffuse, float), (h, w, 3))
    st = synthesize(spec, rho * spec, np.full((h, w, 3), 0.5)) + d
    mean = st.mean(axis=0)
    return mean + (st - mean) * np.asarray(eff)


def test_polarized_colour_is_the_planted_light():
    g = np.array([1.3, 1.0, 0.7])
    np.testing.assert_allclose(polarized_colour(_stack(g)), g / g.mean(), atol=1e-6)
    # nothing polarized: white
    np.testing.assert_allclose(polarized_colour(np.full((4, 8, 8, 3), 0.4)), 1.0)


def test_polarized_colour_is_not_biased_by_noise():
    # white light on a red matte surface, noisy: a sum of per-pixel amplitudes Isv over the most
    # polarized pixels takes the noise's positive bias, largest in the brightest (red) channel
    rng = np.random.default_rng(3)
    st = _stack((1, 1, 1), diffuse=(0.6, 0.15, 0.1), rho=0.1)     # a weakly polarized highlight
    noisy = np.clip(st + rng.normal(0.0, 0.01, st.shape) * np.sqrt(st / 0.5), 0.0, 1.0)   # shot noise
    got = polarized_colour(noisy)
    np.testing.assert_allclose(got, 1.0, atol=0.07)
    isv = 0.5 * np.hypot(noisy[0] - noisy[2], noisy[1] - noisy[3])
    tot = isv.sum(axis=-1)
    naive = isv[tot >= np.quantile(tot, 0.95)].sum(axis=0)
    assert np.max(np.abs(naive / naive.mean() - 1.0)) > 2 * np.max(np.abs(got - 1.0))


def test_efficiency_divides_the_polarized_amplitude():
    eff = np.array([0.5, 0.8, 1.0])
    st = _stack((1, 1, 1), eff=eff)
    np.testing.assert_allclose(polarized_colour(st), eff / eff.mean(), atol=1e-6)
    np.testing.assert_allclose(polarized_colour(st, efficiency=eff), 1.0, atol=1e-6)


def test_highlight_colour_of_a_white_highlight_on_grey():
    hc = highlight_colour(_stack((1, 1, 1)))
    np.testing.assert_allclose(hc, 1.0, atol=1e-6)
    assert np.all(np.isnan(highlight_colour(np.ones((4, 8, 8, 3)))))   # everything saturated


def test_highlight_colour_ignores_a_dark_noisy_background():
    # a tinted highlight on a bluish object (its colour near neutral under the tint) against a
    # black background whose noise has a large degree of polarization: the highlights are the
    # object's brightest polarized pixels, not the background's noise
    rng = np.random.default_rng(0)
    g = np.array([1.0, 0.75, 0.5])
    st = _stack(g, diffuse=(0.25, 0.225, 0.175), rho=0.5)
    yy, xx = np.mgrid[:40, :40]
    obj = ((yy - 20) ** 2 + (xx - 20) ** 2) < 14 ** 2
    st = np.where(obj[None, :, :, None], st, 0.0)
    noisy = np.clip(st + rng.normal(0.0, 2e-4, st.shape), 0.0, 1.0)
    hc = highlight_colour(noisy)
    want = np.asarray(st.mean(0)[20, 20], float)
    np.testing.assert_allclose(hc, want / want.mean(), atol=0.02)
    est = estimate_illuminant(noisy)
    assert est.source == "polarized"
    np.testing.assert_allclose(est.colour, g / g.mean(), atol=0.02)


def test_polarized_diffuse_light_does_not_tint_the_illuminant():
    # an orange object whose diffuse light is partially polarized everywhere (DoLP 0.1, AoLP
    # perpendicular to the specular's), with a white polarized highlight: the diffuse's polarized
    # light has the surface's own colour and is not taken for the illuminant's
    from polcam.separation._illuminant import projected_chromaticity

    h, w = 48, 48
    yy, xx = np.mgrid[:h, :w]
    shade = 0.2 + 0.4 * np.exp(-((yy - 24) ** 2 + (xx - 24) ** 2) / 500.0)
    d = shade[..., None] * np.array([0.9, 0.45, 0.3])
    spec = 0.25 * np.exp(-((yy - 20) ** 2 + (xx - 28) ** 2) / 12.0)[..., None] * np.ones(3)
    st = synthesize(spec, 0.9 * spec, np.full((h, w, 3), 0.3)) + synthesize(d, 0.1 * d, np.full((h, w, 3), 0.3 + np.pi / 2))
    plain = projected_chromaticity(st)
    weighted = projected_chromaticity(st, own_colour=0.1)
    err_plain = np.linalg.norm(plain - 1 / 3)
    err_weighted = np.linalg.norm(weighted - 1 / 3)
    assert plain[0] > plain[2] and err_plain > 0.1                # tinted towards orange without the weights
    # the weights take out the diffuse-only pixels; inside the highlight the perpendicular diffuse
    # part still subtracts a little orange, so the estimate errs slightly the other way
    assert err_weighted < 0.4 * err_plain
    np.testing.assert_allclose(polarized_colour(st) / 3, weighted, atol=1e-6)
    # a white scene: every polarized pixel has the surface's colour; the weights are dropped
    white = synthesize(np.full((h, w, 3), 0.3) + spec, 0.9 * spec, np.full((h, w, 3), 0.3))
    np.testing.assert_allclose(projected_chromaticity(white, own_colour=0.1), projected_chromaticity(white))


def test_estimate_sources():
    g = np.array([1.2, 1.0, 0.8])
    e = estimate_illuminant(_stack(g, diffuse=(0.2, 0.2, 0.2), rho=1.0))
    assert e.source == "polarized"
    np.testing.assert_allclose(e.colour, g / g.mean(), atol=1e-6)
    np.testing.assert_allclose(e.efficiency, 1.0)
    # white light seen through polarizers weaker in red and green: the highlights win
    eff = np.array([0.5, 0.7, 1.0])
    e2 = estimate_illuminant(_stack((1, 1, 1), eff=eff))
    assert e2.source == "highlights"
    np.testing.assert_allclose(e2.colour, 1.0, atol=1e-6)
    np.testing.assert_allclose(e2.efficiency, eff, atol=1e-6)
    e3 = estimate_illuminant(_stack((1, 1, 1), eff=eff), efficiency=eff)
    assert e3.source == "calibration"
    np.testing.assert_allclose(e3.colour, 1.0, atol=1e-6)


@pytest.mark.parametrize("bad", [(1, 1), (0.5, 1.2, 1), (0, 1, 1), (np.nan, 1, 1)])
def test_bad_efficiency(bad):
    with pytest.raises(MethodError, match="efficiency"):
        estimate_illuminant(_stack((1, 1, 1)), efficiency=bad)


def test_bad_stack():
    with pytest.raises(MethodError, match=r"\(4, H, W, 3\)"):
        estimate_illuminant(np.zeros((4, 8, 8)))


def _weak_highlights(gamma, seed, *, rho=0.08, sigma=0.004):
    """A red matte surface with weakly polarized highlights of colour ``gamma`` and Gaussian noise."""
    rng = np.random.default_rng(seed)
    h, w = 96, 96
    yy, xx = np.mgrid[:h, :w]
    s = sum(0.25 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 40.0) for cy, cx in ((30, 30), (60, 70), (25, 75)))
    spec = s[..., None] * np.asarray(gamma, float)
    st = synthesize(spec, rho * spec, np.full((h, w, 3), 0.7)) + np.array([0.4, 0.15, 0.1])
    return st + rng.normal(0.0, sigma, st.shape)


def test_white_distance_is_in_standard_errors():
    # under white light the polarized colour's distance from white, in its estimated standard
    # errors, is a chi with 2 degrees of freedom: E[z^2] = 2, P(z > 3) = 1.1 % (2 of these 40 seeds)
    from polcam.separation._illuminant import OWN_COLOUR, _parts, _projection_terms, _white_distance

    z = np.array([_white_distance(*_projection_terms(_parts(_weak_highlights((1, 1, 1), sd)), None, OWN_COLOUR))
                  for sd in range(40)])
    assert 1.4 < float(np.mean(z * z)) < 2.8
    assert int(np.sum(z > 3.0)) <= 3                            # 0.44 expected of 40
    # a tinted light with the same weak polarization is many standard errors from white
    zt = _white_distance(*_projection_terms(_parts(_weak_highlights((1.3, 1.0, 0.7), 0)), None, OWN_COLOUR))
    assert zt > 10


def test_weak_evidence_keeps_the_white_balance():
    # weakly polarized highlights under white light: the polarized colour alone errs by the noise,
    # and is not significantly off white, so the camera's white balance is kept exactly
    errs = []
    for sd in range(6):
        st = _weak_highlights((1, 1, 1), sd)
        est = estimate_illuminant(st)
        errs.append(float(np.abs(est.polarized - 1.0).max()))
        if est.source == "white balance":
            np.testing.assert_allclose(est.colour, 1.0)
    assert max(errs) > 0.01                                     # what the rule saves
    assert sum(estimate_illuminant(_weak_highlights((1, 1, 1), sd)).source == "white balance" for sd in range(6)) >= 5
    # the same scene under a tinted light: the evidence is strong, the light recovered
    g = np.array([1.3, 1.0, 0.7])
    est = estimate_illuminant(_weak_highlights(g, 0))
    assert est.source == "polarized"
    np.testing.assert_allclose(est.colour, g / g.mean(), atol=0.03)


def test_estimate_on_torch_is_the_same(dev):
    torch = pytest.importorskip("torch")
    eff = np.array([0.5, 0.7, 1.0])
    rng = np.random.default_rng(2)
    cases = [_stack(np.array([1.2, 1.0, 0.8]), diffuse=(0.2, 0.2, 0.2), rho=1.0), _stack((1, 1, 1), eff=eff),
             np.clip(_stack((1, 1, 1), rho=0.05) + rng.normal(0, 0.01, (4,) + _stack((1, 1, 1)).shape[1:]), 0, 1)]
    for st in cases:
        want = estimate_illuminant(st)
        got = estimate_illuminant(torch.as_tensor(st, device=dev))
        assert got.source == want.source
        for a, b in zip(got, want):
            if isinstance(a, np.ndarray):
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
        np.testing.assert_allclose(highlight_colour(torch.as_tensor(st, device=dev)), highlight_colour(st),
                                   rtol=0, atol=1e-6)
    assert {estimate_illuminant(st).source for st in cases} == {"polarized", "highlights", "white balance"}
