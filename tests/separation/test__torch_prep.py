"""The device pipeline's steps against the numpy functions they mirror.

Run on the CPU build of PyTorch where it is installed (skipped otherwise) and,
where a CUDA GPU is present, on it too (``POLCAM_TEST_DEVICES`` overrides the
list, e.g. ``cpu,cuda``).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from polcam.bench.quality import psnr  # noqa: E402
from polcam.filters import JointBilateral  # noqa: E402
from polcam.separation import _torch_prep as P  # noqa: E402
from polcam.separation import separate  # noqa: E402
from polcam.separation import tensor as T  # noqa: E402
from polcam.separation.yang10 import separate_yang10  # noqa: E402
from polcam.synth.render import render  # noqa: E402
from polcam.synth.scenes import scene  # noqa: E402


def _devices() -> list[str]:
    env = os.environ.get("POLCAM_TEST_DEVICES")
    if env:
        return [d for d in env.split(",") if d]
    return ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


DEVICES = _devices()


@pytest.fixture(scope="module")
def stack() -> np.ndarray:
    return render(scene("Bunny6"), size=72, seed=3).stack


def _t(a: np.ndarray, dev: str):
    return torch.as_tensor(np.ascontiguousarray(a), device=dev)


@pytest.mark.parametrize("dev", DEVICES)
def test_illuminant_chromaticity_and_representations_match_numpy(stack, dev):
    gam = T.estimate_illuminant(stack)
    assert not np.allclose(gam, 1 / 3)            # the scene has a coloured illuminant estimate
    np.testing.assert_allclose(P.estimate_illuminant(_t(stack, dev).double()), gam, rtol=1e-10)
    # no polarization at all: white, as numpy says
    flat = np.repeat(stack.mean(axis=0, keepdims=True), 4, axis=0)
    np.testing.assert_allclose(P.estimate_illuminant(_t(flat, dev).double()), T.estimate_illuminant(flat))
    x = T.normalize_illuminant(stack, gam)
    chro = T.polarization_chromaticity(x)
    np.testing.assert_allclose(P.polarization_chromaticity(_t(x, dev)).cpu().numpy(), chro, atol=1e-12)
    o1, f1 = T.representations(chro, n4=4, block=3, threshold=0.03, rng=np.random.default_rng(5))
    o2, f2 = P.representations(_t(chro, dev), n4=4, block=3, threshold=0.03, rng=np.random.default_rng(5))
    assert 0.3 < f1 < 1 and f2 == pytest.approx(f1)
    np.testing.assert_array_equal(o2.cpu().numpy(), o1)
    np.testing.assert_array_equal(P.gather(_t(stack, dev), o2).cpu().numpy(), T.gather(stack, o1))


@pytest.mark.parametrize("dev", DEVICES)
@pytest.mark.parametrize("size,dark", [(40, 20 / 255), (72, 20 / 255), (72, 0.45)])
def test_yang10_matches_numpy(stack, dev, size, dark):
    # 40: the grid is the image (sigma 10 < 12 pixels); 72: cells of 3 x 3 pixels;
    # dark=0.45 leaves many pixels out (zero weight), so some grid components are empty
    img = np.clip(stack[1, :size, :size], 0, 1)
    want, _ = separate_yang10(img, dark=dark)
    got = P.yang10(_t(img, dev), dark=dark).cpu().numpy()
    assert np.abs(want - img).max() > 0.01         # Yang'10 removed something
    np.testing.assert_allclose(got, want, atol=1e-10)


@pytest.mark.parametrize("dev", DEVICES)
def test_joint_bilateral_with_empty_components_matches_numpy(dev):
    rng = np.random.default_rng(2)
    g = rng.uniform(0, 1, (50, 61))
    f = rng.uniform(0, 1, (50, 61))
    wts = (rng.uniform(0, 1, g.shape) > 0.7).astype(float)
    wts[:, :40] = 0                        # beyond the kernel's reach of the left columns: empty
    a = JointBilateral(g, sigma_spatial=4.0, sigma_range=0.05, weights=wts)
    b = P.JointBilateral(_t(g, dev), sigma_spatial=4.0, sigma_range=0.05, weights=_t(wts, dev))
    assert not a._den_ok.all() and not a._slice_ok.all()
    np.testing.assert_allclose(b(_t(f, dev)).cpu().numpy(), a(f), atol=1e-12)


@pytest.mark.parametrize("dev", DEVICES)
def test_tau_tiles_and_blend_match_numpy(dev):
    rng = np.random.default_rng(4)
    d0 = rng.uniform(0, 1, (4, 4, 30, 41, 3)).astype(np.float32)
    np.testing.assert_allclose(P.tau_weights(_t(d0[0], dev), alpha=2.0, beta=0.25, floor=1e-3).cpu().numpy(),
                               T.tau_weights(d0[0], alpha=2.0, beta=0.25, floor=1e-3), rtol=2e-6)
    ys, xs = T.tile_spans(30, 12, 2), T.tile_spans(41, 16, 3)
    got = P.tile_batch(_t(d0, dev), ys, xs).cpu().numpy()
    windows = [(slice(*y), slice(*x)) for y in ys for x in xs]
    assert got.shape[0] == len(windows) > 4
    for g, (r, c) in zip(got, windows):
        np.testing.assert_array_equal(g, T.unfold_slices(d0[:, :, r, c]))
    # blend's spans come from (tile, overlap): the same spans for the numpy reference
    ys3 = T.tile_spans(30, 12, 3)
    res3 = rng.uniform(0, 1, (len(ys3) * len(xs), 12, 16, 3))
    want = T.blend((30, 41), (12, 16), 3, list(res3))
    np.testing.assert_allclose(P.blend((30, 41), ys3, xs, _t(res3, dev)).cpu().numpy(), want, atol=1e-12)


@pytest.mark.parametrize("dev", DEVICES)
@pytest.mark.parametrize("variant", ["tensor", "tensor-plain"])
def test_device_pipeline_matches_numpy_tiled(stack, dev, variant):
    # tiled, so the blend and the per-tile batches are exercised end to end
    a = separate(stack, method=variant, tile=(40, 24), workers=1)
    b = separate(stack, method=variant, tile=(40, 24), device=dev)
    assert b.info["tiles"] == a.info["tiles"] > 1 and b.info["device"] == dev
    assert b.info["representations_filled"] == pytest.approx(a.info["representations_filled"])
    np.testing.assert_allclose(b.info["illuminant_chromaticity"], a.info["illuminant_chromaticity"], rtol=1e-9)
    assert psnr(b.diffuse, a.diffuse) > 70                   # float32 solvers, same problem
    assert set(b.info["timings"]) == {"illuminant", "representations", "init", "ialm"}


@pytest.mark.parametrize("dev", DEVICES)
@pytest.mark.parametrize("init,shared", [("shen09", False), ("shen09", True), ("yang10", False)])
def test_device_pipeline_other_init_and_unshared(stack, dev, init, shared):
    small = stack[:, :32, :32]
    a = separate(small, method="tensor", init=init, shared_init=shared, workers=1)
    b = separate(small, method="tensor", init=init, shared_init=shared, device=dev)
    assert psnr(b.diffuse, a.diffuse) > 70


@pytest.mark.parametrize("dev", DEVICES)
def test_device_pipeline_illuminant_options(stack, dev):
    from polcam.errors import MethodError

    small = stack[:, :24, :24]
    for ill in ("white", (0.5, 0.3, 0.2)):
        a = separate(small, method="tensor", illuminant=ill, workers=1)
        b = separate(small, method="tensor", illuminant=ill, device=dev)
        np.testing.assert_allclose(b.info["illuminant_chromaticity"], a.info["illuminant_chromaticity"])
        assert psnr(b.diffuse, a.diffuse) > 70
    with pytest.raises(MethodError, match="illuminant 'blue'"):
        separate(small, method="tensor", illuminant="blue", device=dev)
    with pytest.raises(MethodError, match="three positive values"):
        separate(small, method="tensor", illuminant=(0.5, 0.6, -0.1), device=dev)
