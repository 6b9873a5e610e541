"""shen09 (Shen & Cai, Applied Optics 2009) on synthetic dichromatic scenes with known diffuse.

The checks every single-image method shares (registration, scale contract, edge cases) are in
test_contract.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.quality import psnr
from polcam.errors import MethodError
from polcam.separation.shen09 import separate_shen09
from polcam.synth.dichromatic import banded_scene


def test_single_material():
    image, diffuse = banded_scene(colours=((0.6, 0.3, 0.1),))
    out, info = separate_shen09(image)
    assert not info["fallback"]
    assert psnr(image, diffuse) < 34
    assert psnr(out, diffuse) > 48  # measured 53.0 dB


def test_two_materials():
    image, diffuse = banded_scene()
    out, info = separate_shen09(image)
    assert psnr(out, diffuse) > psnr(image, diffuse) + 8  # measured 40.2 dB against 29.9


def test_threshold_and_pseudo_specular_closed_form():
    # with k = 1 the result is the MSF image: I - max(I_min - T, 0), T = mean + nu std of I_min
    image, _ = banded_scene()
    i_min = image.min(axis=-1)
    t = i_min.mean() + 0.5 * i_min.std()
    out, info = separate_shen09(image)
    assert info["threshold"] == pytest.approx(t, rel=1e-12)
    beta = np.maximum(i_min - t, 0)
    np.testing.assert_allclose(out, np.clip(image - info["k"] * beta[..., None], 0, image), atol=1e-12)
    # untouched below the threshold
    np.testing.assert_array_equal(out[i_min <= t], image[i_min <= t])


def test_scale_from_the_boundary():
    # a highlight whose pseudo specular term is a known fraction of the true one:
    # flat diffuse (I_min = T everywhere but the lobe), so beta = m_s / 3 exactly, k = 1
    h, w = 40, 50
    yy, xx = np.mgrid[0:h, 0:w]
    diffuse = np.broadcast_to(np.array([0.5, 0.3, 0.2]), (h, w, 3)).copy()
    ms = 0.6 * np.exp(-((yy - 20) ** 2 + (xx - 25) ** 2) / (2 * 4.0**2))
    image = diffuse + ms[..., None] / 3
    out, info = separate_shen09(image, nu=0.0)
    # T is the mean of I_min, slightly above the diffuse minimum 0.2: k compensates on the boundary
    assert not info["fallback"] and 0.5 < info["k"] < 1.5
    assert psnr(out, diffuse) > psnr(image, diffuse) + 10


def test_no_highlight_falls_back_and_keeps_the_image():
    flat = np.full((10, 12, 3), 0.4) * np.array([1.0, 0.5, 0.25])
    out, info = separate_shen09(flat)
    assert info["fallback"] and info["k"] == 1.0
    np.testing.assert_array_equal(out, flat)


def test_bad_input():
    with pytest.raises(MethodError, match=r"\(H, W, 3\)"):
        separate_shen09(np.zeros((3, 3)))
    with pytest.raises(MethodError, match="dtype"):
        separate_shen09(np.zeros((3, 3, 3), dtype=np.int32))
    with pytest.raises(MethodError, match="nu"):
        separate_shen09(np.full((3, 3, 3), 0.5), nu=-1)
    with pytest.raises(MethodError, match="region_threshold"):
        separate_shen09(np.full((3, 3, 3), 0.5), region_threshold=1.0)
    with pytest.raises(MethodError, match="ring"):
        separate_shen09(np.full((3, 3, 3), 0.5), ring=4)
