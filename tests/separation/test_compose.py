"""The public calls compose: ``polcam.separate(polcam.demosaic(polcam.read_frame(path)))``.

Demosaicing overshoots [0, 1] near edges and is not clipped; ``separate`` clips its input itself
(docs/decisions/input-range.md) and says how much in ``info``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import polcam

FRAMES = sorted((Path(__file__).resolve().parents[2] / "fixtures" / "raw").glob("*.png"))


def test_there_are_fixture_frames_of_both_kinds():
    kinds = {polcam.read_frame(p).layout.is_color for p in FRAMES}
    assert kinds == {True, False}


def _check(res, stack):
    mean = np.clip(stack, 0, 1).mean(axis=0)
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-5)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    lo, hi = res.info["input_range"]
    assert lo == pytest.approx(float(stack.min())) and hi == pytest.approx(float(stack.max()))
    outside = np.count_nonzero((stack < 0) | (stack > 1)) / stack.size
    assert res.info["input_clipped"] == pytest.approx(outside)


@pytest.mark.parametrize("path", FRAMES, ids=lambda p: p.stem)
def test_default_demosaic_then_default_separation(path):
    frame = polcam.read_frame(path)
    stack = polcam.demosaic(frame)
    res = polcam.separate(stack)
    _check(res, stack)


@pytest.mark.parametrize("path", FRAMES, ids=lambda p: p.stem)
@pytest.mark.parametrize("demosaic", polcam.DEMOSAIC_METHODS)
def test_every_demosaic_method_composes(path, demosaic):
    stack = polcam.demosaic(polcam.read_frame(path), method=demosaic)
    res = polcam.separate(stack, method="imin")
    _check(res, stack)


def test_an_overshooting_stack_is_clipped_and_said():
    """eari overshoots on the colour fixture: the case the composition has to survive."""
    colour = next(p for p in FRAMES if polcam.read_frame(p).layout.is_color)
    stack = polcam.demosaic(polcam.read_frame(colour), method="eari")
    assert stack.min() < 0 and stack.max() > 1
    res = polcam.separate(stack, method="imin")
    _check(res, stack)
    assert res.info["input_clipped"] > 0
    # the same answer as clipping first
    np.testing.assert_array_equal(res.diffuse, polcam.separate(np.clip(stack, 0, 1), method="imin").diffuse)
