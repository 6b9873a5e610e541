"""Tests of polcam.synth.patterns: the synthetic scenes and their ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.polarimetry import aolp, dolp, stokes
from polcam.synth.patterns import SCENES, make_scene, stack_from_stokes, uniform_scene

N = 96


@pytest.fixture(scope="module")
def scenes() -> dict[tuple[str, bool], object]:
    return {(name, color): make_scene(name, height=N, width=N + 8, seed=4, color=color)
            for name in SCENES for color in (False, True)}


def test_malus_law_closed_form() -> None:
    st = stack_from_stokes(np.array([[0.8]]), np.array([[0.5]]), np.array([[np.deg2rad(30.0)]]))
    t = np.deg2rad([0.0, 45.0, 90.0, 135.0])
    want = 0.4 * (1 + 0.5 * np.cos(2 * t - np.deg2rad(60.0)))
    np.testing.assert_allclose(st[:, 0, 0], want, rtol=1e-6)


def test_stack_from_stokes_round_trip() -> None:
    rng = np.random.default_rng(0)
    s0 = rng.uniform(0.05, 1.0, size=(20, 30))
    d = rng.uniform(0.0, 1.0, size=(20, 30))
    a = rng.uniform(0.0, np.pi, size=(20, 30))
    st = stack_from_stokes(s0, d, a)
    np.testing.assert_allclose(stokes(st).s0, s0, rtol=1e-5)
    np.testing.assert_allclose(dolp(st), d, atol=1e-5)
    diff = np.mod(aolp(st) - a, np.pi)
    assert np.minimum(diff, np.pi - diff)[d > 0.01].max() < 1e-3


@pytest.mark.parametrize("color", [False, True])
@pytest.mark.parametrize("name", SCENES)
def test_scene_shapes_ranges_and_ground_truth(scenes, name: str, color: bool) -> None:
    sc = scenes[(name, color)]
    shape = (4, N, N + 8, 3) if color else (4, N, N + 8)
    assert sc.stack.shape == shape and sc.stack.dtype == np.float32
    assert sc.is_color == color and sc.shape == (N, N + 8) and sc.name == name and sc.seed == 4
    assert sc.stack.min() >= 0 and sc.stack.max() <= 1
    st = sc.stack.astype(np.float64)
    # ideal polarizers: I0 + I90 = I45 + I135 = S0
    np.testing.assert_allclose(st[0] + st[2], st[1] + st[3], atol=2e-6)
    np.testing.assert_allclose(sc.s0, st[0] + st[2], atol=2e-6)
    assert sc.s0.shape == sc.dolp.shape == sc.aolp.shape == shape[1:]
    np.testing.assert_allclose(sc.dolp, dolp(sc.stack), atol=1e-4)
    diff = np.mod(sc.aolp - aolp(sc.stack), np.pi)
    assert np.minimum(diff, np.pi - diff)[sc.dolp > 0.05].max() < 1e-3
    assert sc.aolp.min() >= 0 and sc.aolp.max() < np.pi


@pytest.mark.parametrize("name", SCENES)
def test_scenes_are_deterministic(name: str) -> None:
    a = make_scene(name, height=32, width=40, seed=11, color=True)
    b = make_scene(name, height=32, width=40, seed=11, color=True)
    c = make_scene(name, height=32, width=40, seed=12, color=True)
    np.testing.assert_array_equal(a.stack, b.stack)
    assert not np.array_equal(a.stack, c.stack)


def test_polarization_ranges_are_covered(scenes) -> None:
    for name in ("smooth", "textured", "sweep"):
        sc = scenes[(name, False)]
        assert sc.dolp.min() < 0.02 and sc.dolp.max() > 0.98, name
        counts, _ = np.histogram(sc.aolp, bins=6, range=(0, np.pi))
        assert (counts > 0).all(), (name, counts)
    edges = scenes[("edges", False)]
    assert edges.dolp.max() - edges.dolp.min() > 0.5


def test_sweep_ramps() -> None:
    sc = make_scene("sweep", height=64, width=64, seed=0)
    np.testing.assert_allclose(sc.dolp[:, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(sc.dolp[:, -1], 1.0, atol=1e-5)
    assert np.all(np.diff(sc.dolp.mean(axis=0)) > 0)
    a = sc.aolp[:, 10]
    np.testing.assert_allclose(np.diff(a), np.pi / 64, atol=1e-4)


def _high_frequency_fraction(img: np.ndarray) -> float:
    """Share of the spectral energy above 0.2 cycles per pixel (Hann window: no edge leakage)."""
    win = np.outer(np.hanning(img.shape[0]), np.hanning(img.shape[1]))
    f = np.abs(np.fft.fft2((img - img.mean()) * win)) ** 2
    fy = np.fft.fftfreq(img.shape[0])[:, None]
    fx = np.fft.fftfreq(img.shape[1])[None, :]
    return float(f[np.hypot(fy, fx) > 0.2].sum() / f.sum())


def test_textured_has_fine_detail_and_smooth_has_none(scenes) -> None:
    assert _high_frequency_fraction(scenes[("textured", False)].s0) > 0.05
    assert _high_frequency_fraction(scenes[("smooth", False)].s0) < 1e-6


def test_edges_are_sharp(scenes) -> None:
    sc = scenes[("edges", False)]
    jump_d = np.abs(np.diff(sc.dolp, axis=1))
    jump_s0 = np.abs(np.diff(sc.s0, axis=1))
    # a step across one pixel: large jumps exist, but most neighbours are equal
    assert jump_d.max() > 0.3 and jump_s0.max() > 0.2
    assert np.mean(jump_s0 < 1e-6) > 0.5


def test_colour_channels_differ_but_correlate(scenes) -> None:
    for name in ("smooth", "textured", "edges"):
        s0 = scenes[(name, True)].s0
        r, g, b = (s0[..., c].ravel() for c in range(3))
        assert not np.allclose(r, g) and not np.allclose(g, b)
    tex = scenes[("textured", True)].s0
    assert np.corrcoef(tex[..., 0].ravel(), tex[..., 1].ravel())[0, 1] > 0.5


def test_uniform_scene() -> None:
    sc = uniform_scene(10, 12, s0=(0.2, 0.4, 0.6), dolp=0.3, aolp=2.0)
    assert sc.stack.shape == (4, 10, 12, 3)
    np.testing.assert_allclose(sc.s0[3, 4], (0.2, 0.4, 0.6), atol=1e-6)
    np.testing.assert_allclose(sc.dolp, 0.3, atol=1e-5)
    np.testing.assert_allclose(sc.aolp, 2.0, atol=1e-4)
    mono = uniform_scene(8, 8, s0=0.5, dolp=0.0, aolp=0.0)
    assert mono.stack.shape == (4, 8, 8)
    np.testing.assert_allclose(mono.stack, 0.25, atol=1e-7)


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(MethodError, match="'checkerboard'"):
        make_scene("checkerboard")
    with pytest.raises(MethodError, match="at least 8"):
        make_scene("smooth", height=4, width=32)
    with pytest.raises(MethodError, match="triple"):
        uniform_scene(8, 8, s0=(0.1, 0.2))
    with pytest.raises(MethodError, match=r"\[0, 1\]"):
        uniform_scene(8, 8, dolp=1.5)
    with pytest.raises(MethodError, match="dolp"):
        stack_from_stokes(np.ones((2, 2)), np.full((2, 2), -0.1), np.zeros((2, 2)))
