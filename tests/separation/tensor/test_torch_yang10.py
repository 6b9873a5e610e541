"""Yang'10 and the joint bilateral filter on a torch device against the numpy functions they mirror.

Run on the CPU build of PyTorch where it is installed (skipped otherwise) and,
where a CUDA GPU is present, on it too (``POLCAM_TEST_DEVICES`` overrides the
list, e.g. ``cpu,cuda``).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from polcam.filters import JointBilateral  # noqa: E402
from polcam.separation.tensor import torch_yang10 as P  # noqa: E402
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
