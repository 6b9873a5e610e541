"""imin: the polarization minimum against the closed form on synthetic scenes."""

from __future__ import annotations

import numpy as np

from polcam.polarimetry import synthesize
from polcam.separation import separate


def _scene(rng, shape):
    diffuse = rng.uniform(0.05, 0.5, shape)           # unpolarized
    spec = rng.uniform(0.0, 0.4, shape[:2])[..., None] * np.ones(shape)  # white specular
    phi = rng.uniform(0, np.pi, shape[:2])[..., None] * np.ones(shape)
    return diffuse, spec, phi


def test_fully_polarized_specular_is_removed_exactly():
    rng = np.random.default_rng(0)
    diffuse, spec, phi = _scene(rng, (16, 12, 3))
    # polarizer readings: unpolarized diffuse passes half... on the scale of one image:
    # I(t) = D + S (1 + cos(2t - 2phi)) / 2  -> Ic = D + S/2, Isv = S/2, Imin = D
    stack = synthesize(diffuse + spec / 2, spec / 2, phi)
    res = separate(stack, method="imin")
    np.testing.assert_allclose(res.diffuse, diffuse, atol=1e-6)
    np.testing.assert_allclose(res.specular, spec / 2, atol=1e-6)
    np.testing.assert_allclose(res.diffuse + res.specular, stack.mean(axis=0), atol=1e-6)


def test_partially_polarized_specular_leaves_the_unpolarized_part():
    rng = np.random.default_rng(1)
    diffuse, spec, phi = _scene(rng, (8, 8, 3))
    rho = 0.4
    stack = synthesize(diffuse + spec / 2, rho * spec / 2, phi)
    res = separate(stack, method="imin")
    np.testing.assert_allclose(res.diffuse, diffuse + (1 - rho) * spec / 2, atol=1e-6)


def test_mono_stack():
    rng = np.random.default_rng(2)
    d = rng.uniform(0.1, 0.5, (10, 10))
    s = rng.uniform(0, 0.3, (10, 10))
    stack = synthesize(d + s / 2, s / 2, rng.uniform(0, np.pi, (10, 10)))
    res = separate(stack, method="imin")
    assert res.diffuse.shape == (10, 10) and res.diffuse.dtype == np.float32
    np.testing.assert_allclose(res.diffuse, d, atol=1e-6)


def test_dark_input():
    res = separate(np.zeros((4, 5, 5, 3)), method="imin")
    assert np.all(res.diffuse == 0) and np.all(res.specular == 0)
