"""The separate() dispatcher: names, shapes, the scale contract, errors."""

from __future__ import annotations

import numpy as np
import pytest

import polcam
from polcam.errors import MethodError
from polcam.separation import METHODS, method_spec, register, separate, unregister


def test_methods_are_exported():
    assert polcam.METHODS == METHODS
    assert "imin" in METHODS
    assert method_spec("imin").kind == "stack"


def test_unknown_method_lists_the_known_ones():
    with pytest.raises(MethodError) as err:
        separate(np.zeros((4, 4, 4, 3)), method="nope")
    assert "nope" in str(err.value) and "imin" in str(err.value)


@pytest.mark.parametrize("shape", [(4, 4), (3, 4, 4, 3), (4, 4, 4, 2), (2, 4, 4, 3, 1)])
def test_wrong_shapes_are_refused(shape):
    with pytest.raises(MethodError, match="expected a \\(4, H, W, 3\\)"):
        separate(np.zeros(shape), method="imin")


def test_bad_values_are_refused():
    x = np.full((4, 4, 4, 3), 0.5)
    x[0, 0, 0, 0] = np.nan
    with pytest.raises(MethodError, match="NaN"):
        separate(x, method="imin")
    with pytest.raises(MethodError, match="integer"):
        separate(np.zeros((4, 4, 4, 3), np.uint8), method="imin")


def test_out_of_range_values_are_clipped_and_recorded():
    x = np.full((4, 4, 4, 3), 0.5)
    x[:, 0] = 3.0                       # one row of each angle image above 1
    x[:, 1] = -0.2                      # one below 0
    res = separate(x, method="imin")
    assert res.info["input_range"] == [-0.2, 3.0] and res.info["input_clipped"] == 0.5
    np.testing.assert_array_equal(res.diffuse + res.specular, np.clip(x, 0, 1).mean(axis=0).astype(np.float32))
    inside = separate(np.full((4, 4, 4, 3), 0.5), method="imin")
    assert inside.info["input_clipped"] == 0.0 and inside.info["input_range"] == [0.5, 0.5]


@pytest.fixture
def toy_methods():
    # a single-image method that returns out-of-range values, and a stack-only colour method
    register("_toy_single", kind="single")(lambda img, gain=2.0: (img * gain - 0.1, {"gain": gain}))
    register("_toy_stack", kind="stack")(lambda st: st.min(axis=0))
    yield
    unregister("_toy_single"), unregister("_toy_stack")


def test_scale_contract_and_info(toy_methods):
    rng = np.random.default_rng(0)
    stack = rng.uniform(0, 1, (4, 6, 5, 3))
    res = separate(stack, method="_toy_single", gain=3.0)
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (6, 5, 3) and res.diffuse.dtype == np.float32
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert res.info["method"] == "_toy_single" and res.info["gain"] == 3.0 and res.info["seconds"] >= 0
    # a single RGB image goes straight to a single-image method
    img = rng.uniform(0, 1, (6, 5, 3))
    res = separate(img, method="_toy_single")
    np.testing.assert_allclose(res.diffuse + res.specular, img, atol=1e-6)


def test_kind_checks(toy_methods):
    with pytest.raises(MethodError, match="needs a \\(4, H, W, 3\\) polarization stack"):
        separate(np.zeros((5, 5, 3)), method="_toy_stack")
    with pytest.raises(MethodError, match="needs colour"):
        separate(np.zeros((4, 5, 5)), method="_toy_stack")


def test_declared_options_of_a_kwargs_method_are_checked_before_it_runs():
    from polcam.separation import check_options

    calls = []

    def fn(stack, **options):
        calls.append(options)
        return stack.mean(axis=0)

    register("_toy_kwargs", kind="stack", options=("alpha", "beta"))(fn)
    register("_toy_open", kind="stack")(fn)
    try:
        check_options("_toy_kwargs", {"alpha": 1})
        with pytest.raises(MethodError, match="takes no option 'gamma'; its options: alpha, beta"):
            check_options("_toy_kwargs", {"gamma": 1})
        with pytest.raises(MethodError, match="takes no option 'gamma'"):
            separate(np.zeros((4, 4, 4, 3)), method="_toy_kwargs", gamma=1)
        assert calls == []                                  # refused before the call
        separate(np.zeros((4, 4, 4, 3)), method="_toy_open", gamma=1)   # undeclared: passed on
        assert calls == [{"gamma": 1}]
    finally:
        unregister("_toy_kwargs"), unregister("_toy_open")


def test_unknown_options_are_refused_by_name(toy_methods):
    with pytest.raises(MethodError, match="takes no option 'max_iter'; its options: none"):
        separate(np.zeros((4, 4, 4, 3)), method="imin", max_iter=5)
    with pytest.raises(MethodError, match="its options: gain"):
        separate(np.zeros((4, 4, 3)), method="_toy_single", gian=2.0)


def test_option_types_are_checked_before_the_method_runs():
    calls = []

    def fn(image, *, levels: int = 8, scale: float = 1.0, name: str | None = None):
        calls.append((levels, scale, name))
        return image

    register("_toy_typed", kind="single")(fn)
    register("_toy_declared", kind="stack", options={"max_iter": int})(lambda st, **o: st.mean(axis=0))
    try:
        img = np.full((4, 4, 3), 0.5)
        with pytest.raises(MethodError, match=r"option levels='abc' of method '_toy_typed': expected an integer"):
            separate(img, method="_toy_typed", levels="abc")
        with pytest.raises(MethodError, match=r"option scale=None of method '_toy_typed': expected a number"):
            separate(img, method="_toy_typed", scale=None)
        with pytest.raises(MethodError, match=r"option max_iter=2.5 of method '_toy_declared'"):
            separate(np.full((4, 4, 4, 3), 0.5), method="_toy_declared", max_iter=2.5)
        assert calls == []
        separate(img, method="_toy_typed", levels=3, scale=2, name=None)     # an int is a valid float
        assert calls == [(3, 2, None)]
    finally:
        unregister("_toy_typed"), unregister("_toy_declared")
    with pytest.raises(MethodError, match=r"option max_iter='abc' of method 'tensor': expected an integer"):
        separate(np.full((4, 8, 8, 3), 0.5), method="tensor", max_iter="abc")
