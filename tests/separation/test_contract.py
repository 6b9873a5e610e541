"""The contract every single-image separation method keeps, checked for each of them.

Registration, the dispatcher's scale contract on polarization stacks, determinism,
degenerate and thin inputs, saturated highlights, and (slow) fidelity on Shen & Zheng's
images.  The method-specific behaviour is tested in each method's own test file.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.separation import method_spec, separate
from polcam.separation.akashi16 import separate_akashi16
from polcam.separation.shen08 import separate_shen08
from polcam.separation.shen09 import separate_shen09
from polcam.separation.shen13 import separate_shen13
from polcam.separation.tan05 import separate_tan05
from polcam.separation.yamamoto19 import separate_yamamoto19
from polcam.separation.yang10 import separate_yang10
from polcam.separation.yoon06 import separate_yoon06
from polcam.synth.dichromatic import banded_scene, edge_cases, patch_scene, polarization_stack

FUNCTIONS = {
    "tan05": separate_tan05,
    "yoon06": separate_yoon06,
    "shen08": separate_shen08,
    "shen09": separate_shen09,
    "yang10": separate_yang10,
    "shen13": separate_shen13,
    "akashi16": separate_akashi16,
    "yamamoto19": separate_yamamoto19,
}
METHODS = tuple(FUNCTIONS)

#: Options the dispatcher checks pass (a fixed seed; a base other than the default).
DISPATCH_OPTIONS = {"akashi16": {"seed": 1}, "yamamoto19": {"base": "shen09"}}
#: Options of the direct calls (yamamoto19: every replacement pass, not only the first).
CALL_OPTIONS = {"yamamoto19": {"epsilon": 0.0}}
#: info keys each method reports besides method and seconds.
INFO_KEYS = {
    "tan05": {"iterations", "converged"},
    "yoon06": {"converged"},
    "shen08": {"iterations", "converged"},
    "shen09": {"k"},
    "yang10": {"iterations", "converged"},
    "shen13": {"clusters"},
    "akashi16": {"iterations", "converged", "seed"},
    "yamamoto19": {"base"},
}


def call(method: str, image: np.ndarray, **options) -> np.ndarray:
    out, _ = FUNCTIONS[method](image, **{**CALL_OPTIONS.get(method, {}), **options})
    return out


def check_dispatch(method: str, stack: np.ndarray):
    res = separate(stack, method=method, **DISPATCH_OPTIONS.get(method, {}))
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == mean.shape and res.diffuse.dtype == np.float32
    assert res.specular.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    assert res.specular.sum() > 0.01
    assert res.info["method"] == method and INFO_KEYS[method] <= res.info.keys()
    if method == "yoon06":
        assert res.info["converged"]  # the fixed point is exact
    if method == "yamamoto19":
        assert res.info["base"] == "shen09"
    return res


@pytest.mark.parametrize(
    "method, author, year",
    [("tan05", "Tan", "2005"), ("yoon06", "Yoon", "2006"), ("shen08", "Shen", "2008"),
     ("shen09", "Shen", "2009"), ("yang10", "Yang", "2010"), ("shen13", "Shen", "2013"),
     ("akashi16", "Akashi", "2016"), ("yamamoto19", "Yamamoto", "2019")],
)
def test_registered_as_single_image_method(method, author, year):
    spec = method_spec(method)
    assert spec.kind == "single" and not spec.mono and spec.fn is FUNCTIONS[method]
    assert author in spec.reference and year in spec.reference


@pytest.mark.parametrize("method", METHODS)
def test_scale_contract_on_a_polarization_stack(method):
    # the specular lobe varies with the angle, the diffuse layer does not
    image, diffuse = banded_scene(peak=0.3)
    res = check_dispatch(method, polarization_stack(image, diffuse))
    assert res.diffuse.shape == (64, 96, 3)
    if method == "shen13":
        assert res.info["clusters"] == 2  # one per band colour
    if method == "yang10":
        assert psnr(res.diffuse, diffuse) > 45


@pytest.mark.parametrize("method", METHODS)
def test_scale_contract_on_a_stack_of_gains(method):
    image, _ = patch_scene(h=24, w=32, margin=4)
    gains = np.random.default_rng(3).uniform(0.9, 1.1, (4, 1, 1, 1))
    res = check_dispatch(method, np.clip(image[None] * gains, 0, 1))
    assert res.diffuse.shape == (24, 32, 3)


@pytest.mark.parametrize("method", METHODS)
def test_deterministic(method):
    image, _ = banded_scene(h=32, w=40) if method == "yang10" else banded_scene()
    np.testing.assert_array_equal(call(method, image), call(method, image.copy()))


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name, image", edge_cases())
def test_edge_cases_are_finite_and_in_range(method, name, image):
    out = call(method, image)
    assert out.shape == image.shape and out.dtype == np.float64
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


THIN_CASES = [
    *[pytest.param(m, {}, id=m) for m in METHODS if m not in ("yoon06", "akashi16")],
    *[pytest.param("yoon06", {"direction": d}, id=f"yoon06-{d}") for d in ("vertical", "horizontal", "both")],
    pytest.param("akashi16", {"max_iter": 200}, id="akashi16"),
]


@pytest.mark.parametrize("method, options", THIN_CASES)
@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 9, 3), (9, 1, 3)])
def test_thin_images(method, options, shape):
    image = np.random.default_rng(4).uniform(0.1, 0.9, shape)
    out = call(method, image, **options)
    assert out.shape == shape and np.all(out >= 0) and np.all(out <= image)


@pytest.mark.parametrize("method", METHODS)
def test_saturated_pixels_stay_bounded(method):
    image, _ = patch_scene(h=24, w=32, margin=4, peak=1.5)
    image = np.clip(image, 0, 1)
    out = call(method, image)
    assert np.all(np.isfinite(out)) and np.all(out >= 0) and np.all(out <= image)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["shen13", "yang10"])
def test_speed_640x480(benchmark, method):
    """Timed by pytest-benchmark (`make test-all PYTEST_ARGS=--benchmark-enable`), never asserted."""
    rng = np.random.default_rng(0)
    image, _ = banded_scene(h=480, w=640, colours=tuple(rng.dirichlet([2, 2, 2], size=6)))
    out = benchmark(FUNCTIONS[method], image)
    d = out[0] if isinstance(out, tuple) else out
    assert d.shape == image.shape and np.all(np.isfinite(d))


@pytest.mark.slow
@pytest.mark.parametrize("method", [m for m in METHODS if m != "yamamoto19"])  # no reference row
def test_fidelity_on_shen2013(shared_data, method):
    from polcam.bench.sihr import run

    (row,) = run(shared_data / "shen2013", [method])
    assert row["deviation"] < 1.0
