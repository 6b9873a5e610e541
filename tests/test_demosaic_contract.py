"""The demosaicing contract, checked for EVERY registered method (the list comes from the registry).

Shapes and dtype at both resolutions and both sensor kinds, and a uniform unpolarized scene
(every pixel the same count) demosaiced to that value everywhere: any interpolation of equal
samples gives the sample, so a method that shifts, scales or mixes angles fails here.
"""

from __future__ import annotations

import numpy as np
import pytest

import polcam


@pytest.mark.parametrize("method", polcam.DEMOSAIC_METHODS)
@pytest.mark.parametrize("layout, colour", [("imx250mzr", False), ("imx250myr", True)])
@pytest.mark.parametrize("resolution", ["full", "cell"])
def test_uniform_scene_and_shapes(method, layout, colour, resolution):
    h, w = 32, 48
    raw = np.full((h, w), 1234, dtype=np.uint16)
    stack = polcam.demosaic(raw, layout=layout, method=method, resolution=resolution)
    oh, ow = (h, w) if resolution == "full" else (h // 2, w // 2)
    assert stack.shape == ((4, oh, ow, 3) if colour else (4, oh, ow)) and stack.dtype == np.float32
    np.testing.assert_allclose(stack, 1234 / 65535, rtol=1e-5)
