"""Edge polarization: the share of the polarized light along the local edge normal."""

from __future__ import annotations

import numpy as np

from polcam.separation._diffuse_polarization import diffuse_like_share, edge_axis, radial_share, specular_part


def _disk(h=64, w=64, r=20):
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    dy, dx = yy - h / 2, xx - w / 2
    rad = np.hypot(dx, dy)
    lum = np.where(rad < r, 0.6, 0.05).astype(np.float32)
    # the outward normal's azimuth in the AoLP convention (counter-clockwise, y up)
    azimuth = np.arctan2(-dy, dx)
    return lum, azimuth, rad


def test_polarization_along_a_contours_normal_is_diffuse_and_across_it_is_not():
    lum, azimuth, rad = _disk()
    rim = np.abs(rad - 20) < 1.5
    for phi, want in ((azimuth, 1.0), (azimuth + np.pi / 2, 0.0)):
        amp = 0.05
        q = np.repeat((amp * np.cos(2 * phi))[..., None], 3, -1).astype(np.float32)
        u = np.repeat((amp * np.sin(2 * phi))[..., None], 3, -1).astype(np.float32)
        share = radial_share(q, u, edge_axis(lum, 5))
        assert share.shape == q.shape and share.min() >= 0 and share.max() <= 1
        assert abs(float(share[rim].mean()) - want) < 0.1


def test_no_share_where_the_gradient_has_no_direction():
    rng = np.random.default_rng(0)
    lum = np.full((40, 40), 0.5, np.float32)
    q = rng.normal(0, 0.01, (40, 40, 3)).astype(np.float32)
    u = rng.normal(0, 0.01, (40, 40, 3)).astype(np.float32)
    assert float(radial_share(q, u, edge_axis(lum, 5)).max()) == 0.0


def _disk_polarization(phi, lum):
    amp = 0.05 * (lum > 0.3)
    return (amp * np.cos(2 * phi)).astype(np.float32), (amp * np.sin(2 * phi)).astype(np.float32)


def test_diffuse_like_share_weighs_polarization_along_against_across_the_edges():
    lum, azimuth, _ = _disk()
    # along the contour's normal (diffuse light at an occluding contour): all diffuse-like
    q, u = _disk_polarization(azimuth, lum)
    assert diffuse_like_share(q, u, edge_axis(lum, 5)) > 0.95
    # across it (a specular highlight's polarization): none
    q, u = _disk_polarization(azimuth + np.pi / 2, lum)
    assert diffuse_like_share(q, u, edge_axis(lum, 5)) < 0.05
    # one fixed AoLP over the disk (a uniformly polarized surface): half its rim follows the
    # normal, half crosses it: no preference
    q, u = _disk_polarization(np.full_like(azimuth, 0.4), lum)
    assert abs(diffuse_like_share(q, u, edge_axis(lum, 5)) - 0.5) < 0.05


def test_diffuse_like_share_without_polarization_on_an_edge():
    lum, _, _ = _disk()
    zero = np.zeros(lum.shape, np.float32)
    assert diffuse_like_share(zero, zero, edge_axis(lum, 5)) == 1.0


def _planted(seed, n, g, beta_max):
    """Removals ``R = alpha G + beta M`` (specular of G's colour, diffuse polarization of the body's),
    their projection on G and whether the body's colour is told apart from G's (sine > 0.2)."""
    rng = np.random.default_rng(seed)
    body = rng.uniform(0.05, 0.9, (n, 3))
    alpha, beta = rng.uniform(0.0, 0.3, n), rng.uniform(0.0, beta_max, n)
    removed = alpha[:, None] * g + beta[:, None] * body
    a_g = (removed * g).sum(-1) / (g @ g)
    sine = np.sqrt(1 - ((body @ g) / np.linalg.norm(body, axis=-1) / np.linalg.norm(g)) ** 2)
    return body, alpha, beta, removed, a_g, sine > 0.2


def test_two_colour_fit_sets_the_body_coloured_polarized_light_apart():
    g = np.array([0.9, 1.0, 1.1])
    body, alpha, beta, removed, a_g, told = _planted(3, 50, g, 0.4)
    got = specular_part(removed, body, g, a_g)
    assert told.sum() > 30
    np.testing.assert_allclose(got[told], alpha[told], atol=1e-9)
    # the least multiple of G under every channel's removal takes part of the body's colour as specular
    assert np.all(((removed / g).min(-1) - alpha)[told] > 0)
    # a body of G's own colour: the two are not told apart, and the fit leaves the decision to the caller
    assert np.all(got[~told] >= 1e29)
    # a removal of G's colour alone on a coloured body is all specular
    red = np.array([[0.8, 0.1, 0.1]])
    np.testing.assert_allclose(specular_part(0.2 * g[None], red, g, np.array([0.2])), [0.2], atol=1e-9)


def test_two_colour_fit_says_where_the_body_coloured_part_dominates():
    # planted removals: the body-coloured term dominates exactly where |beta| |M| > |alpha| |G|
    g = np.array([1.1, 1.0, 0.9])
    body, alpha, beta, removed, a_g, told = _planted(4, 200, g, 0.3)
    spec, dominant = specular_part(removed, body, g, a_g, body_dominant=True)
    np.testing.assert_array_equal(spec, specular_part(removed, body, g, a_g))
    planted = told & (beta * np.linalg.norm(body, axis=-1) > alpha * np.linalg.norm(g))
    assert 20 < planted.sum() < told.sum() - 20
    np.testing.assert_array_equal(dominant, planted)
    # colours not told apart: never called dominant (the caller's own reading stands)
    assert not dominant[~told].any()


def test_an_isotropic_structure_tensor_has_no_axis(dev):
    # at the centre of a symmetric bump the gradients cancel: the tensor is isotropic but for
    # float32 rounding, whose direction each backend draws differently; there is no axis there,
    # while an edge's axis is kept
    import pytest

    torch = pytest.importorskip("torch")
    yy, xx = np.mgrid[:48, :64].astype(np.float64)
    lum = (0.3 + 0.5 * np.exp(-((yy - 24) ** 2 + (xx - 32) ** 2) / 32.0)).astype(np.float32)
    c2, s2, coh = edge_axis(lum, 7)
    assert coh[24, 32] < 1e-5 and c2[24, 32] == 0.0 and s2[24, 32] == 0.0
    assert np.hypot(c2[24, 40], s2[24, 40]) == pytest.approx(1.0, abs=1e-5)     # the bump's flank
    tc2, ts2, _ = edge_axis(torch.as_tensor(lum, device=dev), 7)
    # the same on the bump (its far tails' gradients are themselves at rounding level)
    bump = np.hypot(yy - 24, xx - 32) < 12
    np.testing.assert_allclose(tc2.cpu().numpy()[bump], c2[bump], atol=1e-4)
    np.testing.assert_allclose(ts2.cpu().numpy()[bump], s2[bump], atol=1e-4)
