"""polcam.separation._polarization_noise: the garrotes that shrink what noise and aliasing explain, the axis that spares a coherent amplitude, and the aliasing of the default demosaicing."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import polcam
from polcam.demosaicing import mosaic_stack
from polcam.polarimetry import synthesize
from polcam.separation._polarization_noise import (
    _KSIG,
    ALIASING,
    ALIASING_WINDOW,
    _debias,
    aliasing_deviation,
    axis_debias,
    noise_reduction,
    prior_removal,
)
from polcam.synth.photos import load_photo


def test_colour_prior_removal_is_shrunk_by_the_noise():
    # the colour prior's removal is a garrote at _KSIG deviations of Ic's noise: a removal at the
    # noise's level is (almost) undone, one far above it is kept
    h, w = 4, 5
    sig = np.full((h, w, 3), 0.01, np.float32)            # deviation of q and u
    sd_ic = float(np.sqrt(0.5 * 3) * 0.01)                # of Ic, over the three channels
    diffuse = np.full((h, w, 3), 0.5, np.float32)
    for size, lo, hi in ((0.5 * _KSIG * sd_ic, 0.0, 1e-6), (10 * _KSIG * sd_ic, 0.98, 0.995)):
        t = size / np.sqrt(3.0)                           # a removal of norm `size` along white
        sf = diffuse - t
        kept = prior_removal(diffuse, sf, sig).sum(axis=-1) / (3 * t)
        assert np.all((kept >= lo) & (kept <= hi))
    # never more than the prior asked for, never negative (sf above the diffuse removes nothing)
    rng = np.random.default_rng(0)
    sf = diffuse + rng.normal(0, 0.05, diffuse.shape).astype(np.float32)
    out = prior_removal(diffuse, sf, sig)
    assert np.all(out >= 0) and np.all(out <= diffuse - np.minimum(sf, diffuse) + 1e-7)


def _noisy_stokes(amplitude: float, sigma: float, shape=(200, 200, 3), seed: int = 0):
    """q, u of a coherent polarization (AoLP 30 degrees) of ``amplitude`` with Gaussian noise."""
    rng = np.random.default_rng(seed)
    two_phi = np.deg2rad(60.0)
    q = (amplitude * np.cos(two_phi) + rng.normal(0, sigma, shape)).astype(np.float32)
    u = (amplitude * np.sin(two_phi) + rng.normal(0, sigma, shape)).astype(np.float32)
    return q, u


def _smoothed_axis(q, u, k=3):
    qs, us = cv2.GaussianBlur(q, (k, k), 0), cv2.GaussianBlur(u, (k, k), 0)
    qq, uu = qs.sum(axis=-1), us.sum(axis=-1)
    nn = np.hypot(qq, uu)
    c2, s2 = (qq / nn)[..., None], (uu / nn)[..., None]
    return c2, s2, qs * c2 + us * s2, noise_reduction(k)


def test_axis_debias_keeps_a_coherent_amplitude_unbiased():
    # a coherent polarization of five noise deviations: along the known axis the amplitude has
    # zero-mean noise, so its mean is the planted one; the plain garrote shrinks it by ~_KSIG^2/5
    sigma, amp = 0.002, 0.010
    q, u = _noisy_stokes(amp, sigma)
    sig = np.full(q.shape, sigma, np.float32)
    c2, s2, smoothed, red = _smoothed_axis(q, u)
    est = axis_debias(q, u, c2, s2, smoothed, sig, red, "shrink")
    assert abs(float(est.mean()) / amp - 1.0) < 0.03
    shrunk = _debias(np.hypot(q, u), sig, "shrink")
    assert float(shrunk.mean()) / amp < 0.9                 # what the axis saves


def test_axis_debias_leaves_noise_shrunk():
    # no polarization at all: the axis is noise, and the amplitude is debiased as before (mostly 0),
    # far below the noise's own mean amplitude sigma sqrt(pi / 2)
    sigma = 0.002
    q, u = _noisy_stokes(0.0, sigma, seed=1)
    sig = np.full(q.shape, sigma, np.float32)
    c2, s2, smoothed, red = _smoothed_axis(q, u)
    est = axis_debias(q, u, c2, s2, smoothed, sig, red, "shrink")
    raw = np.hypot(q, u)
    assert float(est.mean()) < 0.25 * float(raw.mean())
    assert np.all(est >= 0) and np.all(est <= raw + 1e-7)
    # and where the axis is known the orthogonal part, noise, is debiased as one component
    rice = axis_debias(q, u, c2, s2, np.full_like(q, 1.0), sig, red, "rice")
    par = q * c2 + u * s2
    assert np.allclose(rice, np.hypot(par, np.sqrt(np.maximum((u * c2 - q * s2) ** 2 - sigma**2, 0))), atol=1e-7)


def test_reduction_is_the_blurs_noise_factor():
    rng = np.random.default_rng(2)
    x = rng.normal(0, 1, (400, 400)).astype(np.float32)
    for k in (3, 5):
        got = float(cv2.GaussianBlur(x, (k, k), 0)[10:-10, 10:-10].std())
        assert abs(got / noise_reduction(k) - 1) < 0.03


def test_coherent_prior_removal_is_kept_whole():
    # a removal of five of Ic's deviations over a smooth patch: the garrote alone keeps ~3/4 of it,
    # with the coherence check it is kept whole; a removal of pure noise is still shrunk
    rng = np.random.default_rng(4)
    h, w = 64, 64
    sig = np.full((h, w, 3), 0.004, np.float32)
    sd_ic = float(np.sqrt(0.5 * 3) * 0.004)
    diffuse = np.full((h, w, 3), 0.5, np.float32)
    t = 5 * sd_ic / np.sqrt(3.0)
    sf = (diffuse - t + rng.normal(0, 0.3 * sd_ic, diffuse.shape)).astype(np.float32)
    want = diffuse - np.minimum(sf, diffuse)
    plain = prior_removal(diffuse, sf, sig)
    kept = prior_removal(diffuse, sf, sig, smooth=3)
    assert float(plain.mean()) < 0.85 * float(want.mean())
    np.testing.assert_allclose(kept, want, atol=1e-7)
    noise = (diffuse + rng.normal(0, sd_ic / np.sqrt(3.0), diffuse.shape)).astype(np.float32)
    both = prior_removal(diffuse, noise, sig, smooth=3)
    assert float(both.mean()) <= float(prior_removal(diffuse, noise, sig).mean()) * 1.05 + 1e-9
    assert float(both.mean()) < 0.2 * float((diffuse - np.minimum(noise, diffuse)).mean())


def test_axis_and_coherence_switches_are_continuous():
    # a smoothed amplitude swept through the axis test's threshold (COHERENT_KSIG deviations): the
    # estimate moves from the garrote's to the axis-known one gradually, never by a step (a hard
    # switch jumped by the whole difference, 0.02 of Imin on a rendered scene, under a 1e-7 change)
    from polcam.separation._polarization_noise import COHERENT_KSIG

    sigma, red = 0.01, 0.3
    n = 2001
    q = np.full((1, n, 1), 0.012, np.float32)
    u = np.full((1, n, 1), 0.009, np.float32)
    sig = np.full((1, n, 1), sigma, np.float32)
    c2, s2 = np.ones((1, n, 1), np.float32), np.zeros((1, n, 1), np.float32)
    dev = np.linspace(COHERENT_KSIG - 1.5, COHERENT_KSIG + 1.5, n, dtype=np.float32)
    smoothed = (dev * red * sigma).reshape(1, n, 1)
    est = axis_debias(q, u, c2, s2, smoothed, sig, red, "shrink").ravel()
    garrote = float(_debias(np.hypot(q, u), sig, "shrink").ravel()[0])
    known = float(np.hypot(q[0, 0, 0], _debias(np.abs(u), sig, "shrink", components=1).ravel()[0]))
    assert abs(known - garrote) > 0.005                     # the two estimates differ: a step would show
    assert est[0] == pytest.approx(garrote, abs=1e-7) and est[-1] == pytest.approx(known, abs=1e-7)
    assert np.abs(np.diff(est)).max() < 4.0 / n * abs(known - garrote)     # a ramp over a third of the sweep
    # the colour prior's coherent-removal check, swept the same way
    h = 9
    var_sig = np.full((h, h, 3), 0.004, np.float32)
    sd = float(np.sqrt(0.5 * 3 * 0.004**2) * noise_reduction(3))
    outs = []
    for k in np.linspace(COHERENT_KSIG - 1.5, COHERENT_KSIG + 1.5, 301):
        diffuse = np.full((h, h, 3), 0.5, np.float32)
        sf = diffuse - np.float32(k * sd / np.sqrt(3.0))
        outs.append(float(prior_removal(diffuse, sf, var_sig, smooth=3)[4, 4, 0]) / (k * sd / np.sqrt(3.0)))
    outs = np.array(outs)
    assert outs[0] < 0.8 and outs[-1] == pytest.approx(1.0, abs=1e-5)
    assert np.abs(np.diff(outs)).max() < 0.05


def _unpolarized_camera(rgb: np.ndarray) -> np.ndarray:
    """Unpolarized light ``rgb`` through the IMX250MYR mosaic and the default demosaicing, without noise."""
    zero = np.zeros_like(rgb)
    raw = mosaic_stack(np.clip(synthesize(rgb, zero, zero), 0.0, 1.0), layout="imx250myr")
    return np.clip(polcam.demosaic(raw, layout="imx250myr"), 0.0, 1.0).astype(np.float32)


def test_aliasing_is_the_default_demosaicings():
    # an unpolarized photograph has q = u = 0: what the camera gives is the mosaic's aliasing, and its
    # RMS over C Ic (C the local log contrast) is the constant the deviation is built on; 0.061 when
    # measured over 12 crops of the four training photographs (docs/methods/polarized-residual.md)
    ratios = []
    for name, (y, x) in (("astronaut", (80, 120)), ("rocket", (150, 200)), ("astronaut", (300, 250))):
        rgb = load_photo(name)[y:y + 160, x:x + 160] * 0.8
        cam = _unpolarized_camera(rgb)
        ic = cam.mean(axis=0)
        dev = np.asarray(aliasing_deviation(ic))
        q, u = 0.5 * (cam[0] - cam[2]), 0.5 * (cam[1] - cam[3])
        inner = (slice(8, -8), slice(8, -8))
        keep = (dev[inner] > 0.1 * ALIASING * ic[inner]) & (ic[inner] > 0.03)   # C > 0.1, lit
        d = dev[inner][keep] / ALIASING                     # C Ic
        ratios += [q[inner][keep] / d, u[inner][keep] / d]
    rms = float(np.sqrt(np.mean(np.concatenate(ratios) ** 2)))
    assert 0.8 * ALIASING <= rms <= 1.25 * ALIASING, rms


def test_aliasing_deviation_is_zero_on_flat_light_and_grows_with_the_edge():
    ic = np.full((40, 40, 3), 0.3, np.float32)
    assert np.all(np.asarray(aliasing_deviation(ic)) == 0)
    for ratio in (2.0, 8.0):
        step = ic.copy()
        step[:, 20:] *= ratio
        dev = np.asarray(aliasing_deviation(step))
        # the pixel beside the step, and the pixels beyond the window on either side
        assert dev[10, 20, 0] == pytest.approx(ALIASING * np.log(ratio) * step[10, 20, 0], rel=1e-5)
        assert np.all(dev[:, :20 - ALIASING_WINDOW // 2 - 1] == 0) and np.all(dev[:, 21 + ALIASING_WINDOW // 2:] == 0)


def test_aliasing_shrinks_what_is_not_coherent_and_spares_a_coherent_amplitude():
    # where the axis is known (a coherent amplitude far above the noise) the parallel part is kept
    # whatever the aliasing; where it is not (noise-like polarization), the aliasing's deviation
    # shrinks the amplitude further
    sig = 0.002
    q, u = _noisy_stokes(0.2, sig)
    c2, s2, amp, red = _smoothed_axis(q, u)
    alias = np.full(q.shape, 0.05, np.float32)
    coherent = axis_debias(q, u, c2, s2, amp, np.full(q.shape, sig, np.float32), red, "shrink", alias)
    assert abs(float(np.mean(coherent)) - 0.2) < 0.01
    q, u = _noisy_stokes(0.0, 0.03, seed=1)
    c2, s2, amp, red = _smoothed_axis(q, u)
    plain = axis_debias(q, u, c2, s2, amp, np.full(q.shape, 0.03, np.float32), red, "shrink")
    with_alias = axis_debias(q, u, c2, s2, amp, np.full(q.shape, 0.03, np.float32), red, "shrink", alias)
    assert float(np.mean(with_alias)) < 0.5 * float(np.mean(plain))
