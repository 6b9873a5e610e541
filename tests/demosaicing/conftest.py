"""Fixtures of the demosaicing tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from polcam.mosaic import Layout


def _affine_stack(lay: Layout, h: int, w: int) -> np.ndarray:
    """(4, h, w[, 3]) float32: every angle (and colour) image a different affine function of x and y."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    shape = (4, h, w, 3) if lay.is_color else (4, h, w)
    out = np.empty(shape, np.float32)
    rng = np.random.default_rng(3)
    for k in range(4):
        for c in range(3 if lay.is_color else 1):
            a, bx, by = rng.uniform(0.2, 0.4), rng.uniform(-4e-3, 4e-3), rng.uniform(-4e-3, 4e-3)
            img = a + bx * x + by * y
            if lay.is_color:
                out[k, ..., c] = img
            else:
                out[k] = img
    return out


@pytest.fixture
def affine_stack() -> Callable[[Layout, int, int], np.ndarray]:
    """A factory of stacks whose images are affine in x and y (exact for linear interpolation)."""
    return _affine_stack
