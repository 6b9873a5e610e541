"""Tests of the photograph-like scenes: licensed photographs only, disjoint training and
validation photographs, seeded stacks in range, and the polarization the docs describe."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.polarimetry import aolp, dolp
from polcam.synth.photos import TRAINING_PHOTOS, VALIDATION_PHOTOS, load_photo, photo_stack, polarize


def test_training_and_validation_photos_are_disjoint() -> None:
    assert TRAINING_PHOTOS and VALIDATION_PHOTOS
    assert not set(TRAINING_PHOTOS) & set(VALIDATION_PHOTOS)


@pytest.mark.parametrize("name", TRAINING_PHOTOS + VALIDATION_PHOTOS)
def test_photos_load_as_rgb_in_range(name: str) -> None:
    img = load_photo(name)
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32
    assert 0.0 <= float(img.min()) and float(img.max()) <= 1.0 and float(img.std()) > 0.02


def test_unknown_photo_is_refused() -> None:
    with pytest.raises(MethodError, match="camera"):
        load_photo("camera")


def test_photo_stacks_are_seeded_and_in_range() -> None:
    a = photo_stack(np.random.default_rng(3), 64)
    np.testing.assert_array_equal(a, photo_stack(np.random.default_rng(3), 64))
    assert a.shape == (4, 64, 64, 3) and a.dtype == np.float32
    assert 0.0 <= float(a.min()) and float(a.max()) <= 1.0
    b = photo_stack(np.random.default_rng(4), 64, photos=VALIDATION_PHOTOS)
    assert not np.allclose(a, b)


def test_polarization_is_physical_and_colour_dependent() -> None:
    """I0 + I90 = I45 + I135 (a valid linear-polarization stack); DoLP spans weak and strong values
    and differs between the colours of one pixel; strong DoLP sits on bright unsaturated pixels or
    added highlights."""
    rgb = load_photo("coffee")[::2, ::2][:160, :160]
    d_all, spread_all = [], []
    for seed in range(4):
        st = polarize(np.ascontiguousarray(rgb), np.random.default_rng(seed))
        inside = (st.max(axis=0) < 0.999)  # not clipped
        np.testing.assert_allclose((st[0] + st[2])[inside], (st[1] + st[3])[inside], atol=1e-5)
        d = dolp(st)
        d_all.append(d.reshape(-1))
        spread_all.append((d.max(axis=2) - d.min(axis=2)).reshape(-1))
        assert np.isfinite(aolp(st)).all()
    d = np.concatenate(d_all)
    spread = np.concatenate(spread_all)
    assert float(np.mean(d < 0.1)) > 0.3 and float(np.mean(d > 0.3)) > 0.005
    assert float(np.mean(spread > 0.01)) > 0.2
