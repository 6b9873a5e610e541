"""The separation contract, checked for EVERY registered method: the list comes from the registry.

A method registered in polcam.separation (any module of the package registers itself on import) is
collected here without being named, so none escapes the checks: the result's shapes and dtype,
the scale (diffuse + specular == the mean over the angles), 0 <= diffuse <= that mean, and the
info keys (method, seconds; iterations with converged).  Colour methods refuse a mono stack with
a MethodError; mono methods run on one.  Method-specific behaviour is tested in each method's file.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation import method_spec, methods, separate
from polcam.synth.dichromatic import banded_scene, polarization_stack

#: Options that keep the iterative stack methods quick on the small scene (the contract holds
#: at any iteration count: the diffuse is clipped to [0, mean] and specular = mean - diffuse).
QUICK = {"tensor": {"max_iter": 5}, "tensor-tau": {"max_iter": 5}, "tensor-plain": {"max_iter": 5},
         "wen21": {"max_iter": 5}}


def _quick(method: str) -> dict:
    spec = method_spec(method)
    accepted = spec.options
    if accepted is None:
        import inspect

        accepted = tuple(inspect.signature(spec.fn).parameters)
    return {k: v for k, v in QUICK.get(method, {}).items() if k in accepted}


@pytest.fixture(scope="module")
def colour_stack() -> np.ndarray:
    image, diffuse = banded_scene(32, 48, peak=0.3)
    return polarization_stack(image, diffuse)


def check(res, stack: np.ndarray, method: str) -> None:
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == mean.shape and res.specular.shape == mean.shape
    assert res.diffuse.dtype == np.float32 and res.specular.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-5)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-5)
    assert res.info["method"] == method and res.info["seconds"] >= 0
    if "iterations" in res.info:
        assert "converged" in res.info


def test_the_registry_lists_the_methods_polcam_ships():
    assert {"tensor", "imin", "yang10"} <= set(methods())


@pytest.mark.parametrize("method", methods())
def test_contract_on_a_colour_stack(method, colour_stack):
    check(separate(colour_stack, method=method, **_quick(method)), colour_stack, method)


@pytest.mark.parametrize("method", methods())
def test_mono_stack_runs_or_is_refused_clearly(method, colour_stack):
    mono = np.ascontiguousarray(colour_stack.mean(axis=-1))
    if method_spec(method).mono:
        check(separate(mono, method=method, **_quick(method)), mono, method)
    else:
        with pytest.raises(MethodError, match=method):
            separate(mono, method=method, **_quick(method))
