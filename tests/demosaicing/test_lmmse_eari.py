"""Tests of the lmmse/eari blend: the weight's closed forms, the blend's limits, and its claim on
pattern scenes (the contract tests run it through the shared checks)."""

from __future__ import annotations

import numpy as np
import pytest

import polcam.demosaicing.lmmse_eari as le
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.mosaic import Layout, parse_layout
from polcam.polarimetry import dolp
from polcam.synth.patterns import SCENES, make_scene

MYR = parse_layout("imx250myr")
MZR = parse_layout("imx250mzr")
B = 8


def test_weight_is_zero_where_the_methods_agree_and_one_where_they_differ_much() -> None:
    rng = np.random.default_rng(0)
    a = rng.uniform(0.2, 0.6, size=(4, 64, 80, 3)).astype(np.float32)
    e = a.copy()
    w = le.blend_weight(a, e, mean=0.4, tau=0.2, sigma=4.0, floor=0.03)
    assert w.shape == (64, 80) and w.dtype == np.float32
    np.testing.assert_array_equal(w, 0)
    e[:, :, 40:] += 0.3  # a large disagreement on the right half
    w = le.blend_weight(a, e, mean=0.4, tau=0.2, sigma=4.0, floor=0.03)
    assert float(w[:, 60:].min()) == 1.0 and float(w[:, :20].max()) < 1e-3
    assert float(w.min()) >= 0 and float(w.max()) <= 1


def test_weight_is_the_closed_form_on_a_uniform_disagreement() -> None:
    """Constant d and m: w = d / (tau (m^2 + (floor mean)^2)) exactly (the blurs change nothing)."""
    a = np.full((4, 32, 32, 3), 0.25, np.float32)  # S0 per colour 0.5: m = 0.5
    e = a - np.float32(0.01)  # d = 12 * 1e-4
    w = le.blend_weight(a, e, mean=0.25, tau=0.2, sigma=4.0, floor=0.03)
    expected = 12e-4 / (0.2 * (0.25 + (0.03 * 0.25) ** 2))
    np.testing.assert_allclose(w, expected, rtol=1e-4)
    # scaling the data (and its mean) leaves the weight unchanged
    w2 = le.blend_weight(4 * a, 4 * e, mean=1.0, tau=0.2, sigma=4.0, floor=0.03)
    np.testing.assert_allclose(w2, w, rtol=1e-4)


@pytest.mark.parametrize("lay", [MYR, MZR], ids=lambda x: x.name)
def test_blend_limits_are_eari_and_lmmse(lay: Layout, monkeypatch: pytest.MonkeyPatch) -> None:
    """tau huge: the weight is 0 and the result is eari's; tau tiny: lmmse's wherever they differ."""
    scene = make_scene("textured", height=48, width=64, seed=2, color=lay.is_color)
    raw = mosaic_stack(scene.stack, layout=lay)
    ref = {m: demosaic(raw, layout=lay, method=m) for m in ("eari", "lmmse")}
    monkeypatch.setitem(le.BLEND_PARAMS, "tau", 1e12)
    np.testing.assert_allclose(demosaic(raw, layout=lay, method="lmmse-eari"), ref["eari"], atol=1e-6)
    monkeypatch.setitem(le.BLEND_PARAMS, "tau", 1e-12)
    np.testing.assert_allclose(demosaic(raw, layout=lay, method="lmmse-eari"), ref["lmmse"], atol=1e-6)


def test_blend_recovers_what_lmmse_loses_on_pattern_scenes() -> None:
    """On the pattern scenes (seed 1, 128 pixels; lmmse loses most to eari on smooth and
    sweep), the blend's mean S0 and DoLP PSNR are each at least 0.3 dB above lmmse's (measured
    with the shipped lmmse and tau 0.02: +0.57 / +0.42 dB)."""
    psnr: dict[str, list[tuple[float, float]]] = {}
    for name in SCENES:
        truth = make_scene(name, height=128, width=128, seed=1, color=True).stack
        raw = (np.round(mosaic_stack(truth, layout=MYR) * 65535) / 65535).astype(np.float32)
        t = truth[:, B:-B, B:-B]
        for method in ("lmmse", "lmmse-eari"):
            est = demosaic(raw, layout=MYR, method=method)[:, B:-B, B:-B]
            s0 = float(np.mean((est.sum(0) / 2 - t.sum(0) / 2) ** 2, dtype=np.float64))
            dl = float(np.mean((dolp(est).astype(np.float64) - dolp(t)) ** 2))
            psnr.setdefault(method, []).append((10 * np.log10(4 / s0), 10 * np.log10(1 / dl)))
    lm_, bl = np.mean(psnr["lmmse"], axis=0), np.mean(psnr["lmmse-eari"], axis=0)
    assert bl[0] >= lm_[0] + 0.3 and bl[1] >= lm_[1] + 0.3, (lm_, bl)
