"""Tests of polcam.demosaicing._registry: the dispatcher's input checks, the forward model."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.demosaicing import DEMOSAIC_METHODS, default_method, demosaic, methods, mosaic_stack, to_float
from polcam.errors import FrameReadError, LayoutError, MethodError
from polcam.mosaic import parse_layout
from polcam.synth.patterns import stack_from_stokes

MZR = parse_layout("imx250mzr")
MYR = parse_layout("imx250myr")
H, W = 32, 48


@pytest.mark.parametrize("shape", [(31, 48), (32, 47), (31, 47)])
def test_odd_dimensions_are_refused(shape: tuple[int, int]) -> None:
    raw = np.zeros(shape, np.float32)
    for method in DEMOSAIC_METHODS:
        with pytest.raises(LayoutError, match="even dimensions"):
            demosaic(raw, layout=MZR, method=method)


def test_too_small_mosaics_are_refused() -> None:
    with pytest.raises(LayoutError, match="at least 8"):
        demosaic(np.zeros((6, 16), np.float32), layout=MYR)
    with pytest.raises(LayoutError, match="at least 4"):
        demosaic(np.zeros((2, 16), np.float32), layout=MZR)


def test_unknown_method_and_resolution_are_refused() -> None:
    raw = np.zeros((H, W), np.float32)
    with pytest.raises(MethodError, match="'newton'.*bilinear"):
        demosaic(raw, layout=MZR, method="newton")
    with pytest.raises(MethodError, match="'quarter'"):
        demosaic(raw, layout=MZR, resolution="quarter")
    with pytest.raises(MethodError):  # the method is checked whatever the resolution
        demosaic(raw, layout=MZR, method="newton", resolution="cell")


def test_bad_raw_arrays_are_refused() -> None:
    with pytest.raises(LayoutError, match="no layout"):
        demosaic(np.zeros((H, W), np.float32))
    with pytest.raises(FrameReadError, match="2-D"):
        demosaic(np.zeros((H, W, 3), np.float32), layout=MZR)
    bad = np.zeros((H, W), np.float32)
    bad[3, 4] = np.nan
    with pytest.raises(FrameReadError, match="NaN"):
        demosaic(bad, layout=MZR)
    with pytest.raises(FrameReadError, match="dtype"):
        demosaic(np.zeros((H, W), complex), layout=MZR)
    with pytest.raises(FrameReadError, match="white level"):
        to_float(np.zeros((H, W), np.uint8), black_level=10, white_level=10)


def test_mosaic_stack_samples_the_layout() -> None:
    stack = np.arange(4 * 4 * 4 * 3, dtype=np.float32).reshape(4, 4, 4, 3)
    raw = mosaic_stack(stack, layout=MYR)
    # IMX250MYR: R90 R45 G90 G45 / R135 R0 G135 G0 / G90 G45 B90 B45 / G135 G0 B135 B0
    assert raw[0, 0] == stack[2, 0, 0, 0] and raw[0, 1] == stack[1, 0, 1, 0]
    assert raw[0, 2] == stack[2, 0, 2, 1] and raw[1, 1] == stack[0, 1, 1, 0]
    assert raw[2, 2] == stack[2, 2, 2, 2] and raw[3, 3] == stack[0, 3, 3, 2]
    assert raw[3, 1] == stack[0, 3, 1, 1]
    with pytest.raises(MethodError, match=r"\(4, H, W, 3\)"):
        mosaic_stack(stack[..., 0], layout=MYR)
    with pytest.raises(MethodError, match=r"\(4, H, W\)"):
        mosaic_stack(stack, layout=MZR)


def test_stack_from_stokes_round_trip_through_bilinear_cells() -> None:
    """A sanity link between the synthetic model and demosaicking: cell-resolution
    stacks of a uniform scene are exactly the model's four intensities."""
    st = stack_from_stokes(np.full((H, W), 0.8), np.float64(0.5), np.float64(1.0))
    c = demosaic(mosaic_stack(st, layout=MZR), layout=MZR, resolution="cell")
    want = 0.4 * (1 + 0.5 * np.cos(2 * np.deg2rad([0, 45, 90, 135]) - 2.0))
    np.testing.assert_allclose(c[:, 3, 3], want, atol=1e-6)


def test_registry_lists_methods_and_defaults() -> None:
    import polcam
    import polcam.demosaicing as dm

    assert methods()[:3] == ("bilinear", "eari", "lmmse")
    assert DEMOSAIC_METHODS == methods()
    # the top-level name is the function, the package is reachable as polcam.demosaicing
    assert polcam.demosaic is dm.demosaic and callable(polcam.demosaic)
    for name in methods():
        spec = dm.method_spec(name)
        assert spec.name == name and spec.reference and (spec.mono or spec.color)
    for lay in (MZR, MYR):
        best = default_method(lay)
        assert best in methods()
        raw = np.random.default_rng(0).uniform(0, 1, size=(H, W)).astype(np.float32)
        np.testing.assert_array_equal(demosaic(raw, layout=lay), demosaic(raw, layout=lay, method=best))


def test_a_registered_method_is_listed_and_dispatched() -> None:
    """A method registered after import appears in DEMOSAIC_METHODS and is called; one that
    declares no colour support is refused on a colour layout with a clear error; unregistered,
    it is gone."""
    import polcam.demosaicing as dm

    calls = []

    def half(img, lay):
        calls.append(lay.name)
        return np.stack([img * 0.5] * 4)

    dm.register("half-test", color=False, reference="test")(half)
    try:
        assert "half-test" in dm.DEMOSAIC_METHODS
        raw = np.full((H, W), 0.5, np.float32)
        np.testing.assert_allclose(demosaic(raw, layout=MZR, method="half-test"), 0.25)
        assert calls == [MZR.name]
        with pytest.raises(MethodError, match="'half-test' does not take colour layouts"):
            demosaic(raw, layout=MYR, method="half-test")
        resolved = dm.resolve_demosaic("half-test", MZR)    # resolved once, then run as it is
        np.testing.assert_allclose(demosaic(raw, method=resolved), 0.25)
        assert calls == [MZR.name, MZR.name]
        with pytest.raises(MethodError, match="resolved for layout"):
            demosaic(raw, layout=MYR, method=resolved)
    finally:
        dm.unregister("half-test")
    assert "half-test" not in dm.DEMOSAIC_METHODS
    with pytest.raises(MethodError, match="'half-test' is unknown"):
        dm.method_spec("half-test")
