"""polcam.pipeline: the one per-frame pipeline (calibration, demosaicing, Stokes products, separation)."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.demosaicing import demosaic, mosaic_stack
from polcam.errors import LayoutError
from polcam.frame import Frame
from polcam.pipeline import PRODUCTS, live_maps, products, require_layout, run_frame, separate_layers, to_stack


def _stack(h: int = 16, w: int = 24, colour: bool = False) -> np.ndarray:
    """A stack with a known polarization: I(t) = a + b cos(2 t - 2 phi), phi = 0.3 rad."""
    rng = np.random.default_rng(0)
    a = rng.uniform(0.2, 0.4, (h, w) + ((3,) if colour else ()))
    b = 0.5 * a
    t = np.deg2rad([0, 45, 90, 135]).reshape((4,) + (1,) * a.ndim)
    return (a + b * np.cos(2 * t - 0.6)).astype(np.float32)


def test_products_match_the_closed_forms():
    stack = _stack()
    out = products(stack)
    assert set(out) == set(PRODUCTS)
    a = stack.mean(axis=0)
    np.testing.assert_allclose(out["s0"], 2 * a, rtol=1e-5)              # S0 = (I0+I45+I90+I135)/2
    np.testing.assert_allclose(out["dolp"], 0.5, atol=1e-5)               # b / a
    np.testing.assert_allclose(out["aolp"], 0.3, atol=1e-5)
    np.testing.assert_allclose(out["residual"], 0.0, atol=1e-6)
    np.testing.assert_array_equal(out["i045"], stack[1])
    with pytest.raises(ValueError, match="bogus"):
        products(stack, ["bogus"])


def test_run_frame_is_demosaic_then_products_then_separation():
    stack = _stack(colour=True)
    raw = mosaic_stack(np.repeat(np.repeat(stack, 2, axis=1), 2, axis=2), layout="imx250myr")
    frame = Frame(mosaic=(raw * 4095).round().astype(np.uint16), layout="imx250myr", bit_depth=12,
                  white_level=4095)
    res = run_frame(frame, demosaic="bilinear", resolution="cell", separate=True, method="imin")
    ref = demosaic(frame, method="bilinear", resolution="cell")
    np.testing.assert_array_equal(res.stack, ref)
    np.testing.assert_array_equal(res.products["s0"], products(ref, ["s0"])["s0"])
    mean = np.clip(ref, 0, 1).mean(axis=0)
    np.testing.assert_allclose(res.products["diffuse"] + res.products["specular"], mean, atol=1e-6)
    assert res.separation is not None and res.separation.info["method"] == "imin"
    assert {"calibrate", "demosaic", "stokes", "separate"} <= set(res.timings)
    assert to_stack(frame, demosaic="bilinear", resolution="cell").shape == ref.shape


def test_separate_layers_clips_the_stack_first():
    stack = _stack() * 3.0  # above 1: clipped to 1 before the separation
    res = separate_layers(stack, method="imin")
    np.testing.assert_allclose(res.diffuse + res.specular, np.clip(stack, 0, 1).mean(axis=0), atol=1e-6)


def test_live_route_agrees_with_the_full_route_on_mono():
    stack = _stack(32, 48)
    raw = mosaic_stack(np.repeat(np.repeat(stack, 2, axis=1), 2, axis=2), layout="imx250mzr")
    counts = (raw * 65535).round().astype(np.uint16)
    maps = live_maps(counts, require_layout(Frame(mosaic=counts, layout="imx250mzr")).layout)
    full = products(demosaic(counts, layout="imx250mzr", resolution="cell"), ["s0", "dolp", "aolp"])
    np.testing.assert_allclose(maps.ic, full["s0"] / 2, atol=1e-4)        # the live view shows S0 / 2
    np.testing.assert_allclose(maps.dolp, full["dolp"], atol=1e-4)
    # the same atan2 kernel: orientations agree to float32 rounding of the scaled Stokes values
    d = np.abs(maps.aolp.astype(np.float64) - full["aolp"])
    assert np.minimum(d, np.pi - d).max() < 1e-5


def test_a_frame_without_layout_is_refused_with_the_flag_to_give():
    with pytest.raises(LayoutError, match=r"f\.png: no layout.*--layout"):
        require_layout(Frame(mosaic=np.zeros((8, 8), np.uint8)), "f.png")


def test_run_frame_hands_wen21_the_fit_of_its_maps_pass(monkeypatch):
    """wen21 gets the sinusoid fit made with the products, and separates exactly as on its own."""
    import polcam
    import polcam.separation.wen21 as wen21_mod
    from polcam import pipeline
    from polcam.frame import Frame
    from polcam.synth.render import mosaic

    rng = np.random.default_rng(5)
    base = rng.uniform(0.05, 0.7, (24, 32, 3))
    t = np.deg2rad([0.0, 45.0, 90.0, 135.0])[:, None, None, None]
    stack = base[None] * (1 + 0.4 * np.cos(2 * t - 0.6))
    raw = np.round(np.clip(mosaic(stack, "imx250myr"), 0, 1) * 4095).astype(np.uint16)
    frame = Frame(mosaic=raw, layout="imx250myr", bit_depth=12)
    seen = []
    real = wen21_mod._fit
    monkeypatch.setattr(wen21_mod, "_fit", lambda arr: seen.append(arr.shape) or real(arr))
    from polcam.separation import resolve_separation

    assert resolve_separation("wen21", "stack").takes("fit") and not resolve_separation("imin", "stack").takes("fit")
    res = pipeline.run_frame(frame, resolution="cell", separate=True, method="wen21")
    assert seen == []  # the method did not fit the stack again
    alone = polcam.separate(np.clip(res.stack, 0, 1), method="wen21")
    np.testing.assert_array_equal(res.products["diffuse"], alone.diffuse)
    assert seen  # ... which it does when called on its own
    want = pipeline.products(res.stack, ("s0", "dolp", "aolp"))
    for k, v in want.items():
        np.testing.assert_array_equal(res.products[k], v)
