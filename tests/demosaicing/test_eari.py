"""Tests of EARI against the paper's own formulation, and its quality claim."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import polcam.demosaicing.eari as em
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.mosaic import Layout, parse_layout
from polcam.polarimetry import aolp, dolp, stokes
from polcam.synth.patterns import make_scene, uniform_scene

MZR = parse_layout("imx250mzr")
MYR = parse_layout("imx250myr")
GBRG = parse_layout("color:90,135,0,45:GBRG")
H, W = 32, 48
B = 8


def _interior(a: np.ndarray, b: int = B) -> np.ndarray:
    return a[b:a.shape[0] - b, b:a.shape[1] - b]


def _angle_diff(a: np.ndarray, b: float) -> np.ndarray:
    """|a - b| on the circle of period pi."""
    d = np.mod(np.asarray(a, np.float64) - b, np.pi)
    return np.minimum(d, np.pi - d)


def _scene(lay: Layout):
    s0 = (0.3, 0.6, 0.9) if lay.is_color else 0.7
    return uniform_scene(H, W, s0=s0, dolp=0.6, aolp=0.4)


# ---------------------------------------------------------------------------
# EARI internals against the paper's own formulation
# ---------------------------------------------------------------------------

def test_eari_guide_matches_the_papers_kernels_on_imx250() -> None:
    """Morimatsu et al.'s guide for the 90 45 / 135 0 cell, written with their 3x3
    directional kernels and one-sided 5x3 smoothing windows, equals the fast one inside."""
    rng = np.random.default_rng(5)
    img = rng.uniform(0.0, 1.0, size=(40, 56)).astype(np.float32)
    eps = 1e-3
    fn = np.array([[1, 2, 1], [1, 2, 1], [0, 0, 0]], np.float32) / 8
    hn = np.array([[-0.5, 1, -0.5], [0.5, -1, 0.5], [0, 0, 0]], np.float32)
    mn = np.zeros((5, 5), np.float32)
    mn[:3] = 1 / 15
    kernels = {
        "n": (fn, hn, mn),
        "s": (fn[::-1], hn[::-1], mn[::-1]),
        "w": (fn.T, hn.T, mn.T),
        "e": (fn[::-1].T, hn[::-1].T, mn[::-1].T),
    }
    num = np.zeros_like(img, np.float64)
    den = np.zeros_like(img, np.float64)
    for kx, kh, km in kernels.values():
        x = cv2.filter2D(img.astype(np.float64), cv2.CV_64F, kx)
        d = cv2.filter2D(np.abs(cv2.filter2D(img.astype(np.float64), cv2.CV_64F, kh)), cv2.CV_64F, km)
        wgt = 1.0 / (d + eps)
        num += wgt * x
        den += wgt
    ref = num / den
    got = em._eari_guide(img, MZR, eps)
    np.testing.assert_allclose(_interior(got, 6), _interior(ref, 6), rtol=1e-4, atol=1e-5)


def test_eari_strips_do_not_change_the_result(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(9)
    raw = rng.uniform(0.0, 1.0, size=(96, 64)).astype(np.float32)
    whole = demosaic(raw, layout=MZR, method="eari")
    monkeypatch.setattr(em, "_STRIP", 16)
    strips = demosaic(raw, layout=MZR, method="eari")
    np.testing.assert_allclose(strips, whole, atol=1e-5)


def test_eari_alternative_colour_stage(monkeypatch: pytest.MonkeyPatch) -> None:
    """The Malvar-He-Cutler colour stage kept as an option is exact on piecewise-constant
    colours (its kernels' weights per colour sum to 1 or 0) and keeps the samples."""
    monkeypatch.setitem(em.EARI_PARAMS, "color_stage", "mhc")
    for lay in (MYR, GBRG):
        scene = _scene(lay)
        est = demosaic(mosaic_stack(scene.stack, layout=lay), layout=lay, method="eari")
        np.testing.assert_allclose(_interior(dolp(est)), 0.6, atol=1e-4)
        assert float(_angle_diff(_interior(aolp(est)), 0.4).max()) < 1e-3
        raw = np.random.default_rng(4).uniform(0, 1, size=(H, W)).astype(np.float32)
        out = demosaic(raw, layout=lay, method="eari")
        np.testing.assert_allclose(mosaic_stack(out, layout=lay), raw, atol=1e-5)


# ---------------------------------------------------------------------------
# the quality claim, on data made independently of the method
# ---------------------------------------------------------------------------

def _psnr(est: np.ndarray, ref: np.ndarray, data_range: float) -> float:
    mse = float(np.mean((est.astype(np.float64) - ref) ** 2))
    return 10.0 * np.log10(data_range**2 / mse)


@pytest.mark.parametrize("lay", [MZR, MYR], ids=["mono", "colour"])
def test_eari_beats_bilinear_on_textured_scenes(lay: Layout) -> None:
    """Mean over three seeds of a 128x128 textured scene: EARI at least 1 dB above
    bilinear in PSNR of S0 and of DoLP."""
    gains = []
    for seed in range(3):
        truth = make_scene("textured", height=128, width=128, seed=seed, color=lay.is_color).stack
        raw = mosaic_stack(truth, layout=lay)
        t = truth[:, B:-B, B:-B]
        scores = {}
        for method in ("bilinear", "eari"):
            e = demosaic(raw, layout=lay, method=method)[:, B:-B, B:-B]
            scores[method] = (_psnr(stokes(e).s0, stokes(t).s0, 2.0), _psnr(dolp(e), dolp(t), 1.0))
        gains.append(np.subtract(scores["eari"], scores["bilinear"]))
    mean_gain = np.mean(gains, axis=0)
    assert mean_gain[0] >= 1.0, f"S0 gain {mean_gain[0]:.2f} dB"
    assert mean_gain[1] >= 1.0, f"DoLP gain {mean_gain[1]:.2f} dB"
