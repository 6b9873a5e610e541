"""Clipped samples: declipping by the polarizer identities, and the clipped highlights' fill."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from polcam.separation._clipping import _RING_RAMP, _RING_SHARE, declipped, fill_clipped_highlights, smooth_fill


def test_declipping_rebuilds_samples_exactly():
    # one pixel, three channels: a sinusoid per channel (common AoLP 35 deg), then clipped at 1
    t = np.deg2rad([0.0, 45.0, 90.0, 135.0])
    phi = np.deg2rad(35.0)
    ic = np.array([0.95, 0.78, 0.5])
    amp = np.array([0.3, 0.3, 0.2])
    true = (ic[None] + amp[None] * np.cos(2 * t[:, None] - 2 * phi)).reshape(4, 1, 1, 3).astype(np.float32)
    clipped = np.minimum(true, 1.0)
    assert (true >= 1.0).sum(axis=0).ravel().tolist() == [2, 1, 0]   # R two samples over, G one, B none
    assert np.all((clipped >= 1.0) | (clipped < 0.98))              # no sample just under the white level
    got = declipped(clipped)
    np.testing.assert_allclose(got, true, atol=1e-5)                 # G by the S0 identity, R by B's AoLP
    # a measurement that contradicts the model (the rebuilt value below the clipped one) is kept
    odd = clipped.copy()
    odd[:, 0, 0, 0] = [1.0, 0.5, 0.5, 0.5]
    np.testing.assert_array_equal(declipped(odd)[:, 0, 0, 0], odd[:, 0, 0, 0])
    # with the AoLP at 20 deg the two unclipped samples of R (90 and 135 deg) sit nearly symmetric
    # about the sinusoid's minimum: the 2 x 2 system is ill-conditioned (|det| 0.12) and R is left as is
    true20 = (ic[None] + amp[None] * np.cos(2 * t[:, None] - 2 * np.deg2rad(20.0))).reshape(4, 1, 1, 3)
    c20 = np.minimum(true20, 1.0).astype(np.float32)
    assert (c20[:, 0, 0, 0] >= 1.0).sum() == 2
    np.testing.assert_array_equal(declipped(c20)[:, 0, 0, 0], c20[:, 0, 0, 0])


def test_smooth_fill_fills_a_hole_from_a_smooth_surrounding():
    # a linear ramp in x with a 20 x 20 hole: the fill follows the ramp, smoothly, the rest is untouched
    h, w = 60, 90
    ramp = np.tile(np.linspace(0.2, 0.8, w, dtype=np.float32), (h, 1))
    img = np.stack([ramp, 0.5 * ramp, np.full((h, w), 0.3, np.float32)], axis=-1)
    mask = np.zeros((h, w), bool)
    mask[20:40, 35:55] = True
    holed = img.copy()
    holed[mask] = 1.0
    out = smooth_fill(holed, mask)
    assert out.shape == img.shape and out.dtype == np.float32
    np.testing.assert_array_equal(out[~mask], holed[~mask])
    # smooth: no step between neighbours inside the hole larger than the ramp's own over a few pixels
    assert np.abs(np.diff(out[20:40, 35:55, 0], axis=1)).max() < 0.03
    # against the best constant fill, the mean of the hole's one-pixel border: under half its error
    ring = np.zeros((h, w), bool)
    ring[19:41, 34:56] = True
    ring &= ~mask
    err = np.abs(out[mask] - img[mask]).mean()
    err_const = np.abs(img[ring].mean(axis=0) - img[mask]).mean()
    assert err < 0.5 * err_const


def test_clipped_region_fill_grows_with_its_polarized_border():
    # a clipped disk (white level) on a 0.5 grey surround; the share of its 2-pixel border marked as
    # coherent polarized specular light sweeps from 0 to 1. With none the region is an overexposed
    # surface, left as measured; with all of it a clipped highlight, filled from the surround. In
    # between the fill grows in steps as small as the share's (a hard switch at a share of 0.3 made a
    # clipped ear's diffuse jump by 0.5 between two noise draws)
    h, w = 40, 40
    yy, xx = np.mgrid[:h, :w]
    disk = (yy - 20) ** 2 + (xx - 20) ** 2 <= 36
    measured = np.where(disk[..., None], 1.0, 0.5).astype(np.float32) * np.array([1.0, 0.6, 0.4], np.float32)
    ring = (cv2.dilate(disk.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & ~disk
    ring_idx = np.flatnonzero(ring)
    g = np.ones(3, np.float32)
    centre = []
    shares = np.linspace(0.0, 1.0, 41)
    for share in shares:
        spec = np.zeros(h * w, bool)
        spec[ring_idx[: int(round(share * ring_idx.size))]] = True
        out, stats = fill_clipped_highlights(measured.copy(), measured, spec.reshape(h, w), g)
        assert np.array_equal(out[~disk], measured[~disk])
        assert stats["clipped_pixels"] == disk.sum()
        assert stats["clipped_filled"] + stats["clipped_as_measured"] + stats["clipped_seen"] == disk.sum()
        # only red is clipped there: not filled, the pixels keep the layer (here the measurement)
        assert stats["clipped_as_measured"] == 0 and stats["clipped_seen"] == disk.sum() - stats["clipped_filled"]
        centre.append(float(out[20, 20].mean()))
        if share == 1.0:
            # filled with the surround's own colour (an orange material), not grey
            np.testing.assert_allclose(out[20, 20] / out[20, 20].sum(), [0.5, 0.3, 0.2], atol=0.01)
    centre = np.array(centre)
    assert centre[0] == pytest.approx(measured[20, 20].mean()) and centre[-1] == pytest.approx(0.5 * 2 / 3, abs=0.02)
    assert np.all(np.diff(centre) <= 1e-6)                      # more border evidence, more fill
    assert np.abs(np.diff(centre)).max() < 0.1                  # no jump (a switch moves it by 0.5)
    lo = shares < _RING_SHARE - _RING_RAMP / 2
    assert np.all(centre[lo] == pytest.approx(measured[20, 20].mean()))   # weak evidence: left as measured


def test_clipped_region_between_two_materials_is_left_as_measured():
    # a clipped disk bordered half by red, half by green, all of its border polarized highlight:
    # the border does not say what is under it, so it is left as measured and counted so
    h, w = 40, 40
    yy, xx = np.mgrid[:h, :w]
    disk = (yy - 20) ** 2 + (xx - 20) ** 2 <= 36
    surround = np.where((xx < 20)[..., None], [0.6, 0.1, 0.1], [0.1, 0.6, 0.1]).astype(np.float32)
    measured = np.where(disk[..., None], 1.0, surround).astype(np.float32)
    out, stats = fill_clipped_highlights(measured.copy(), measured, np.ones((h, w), bool), np.ones(3, np.float32))
    np.testing.assert_array_equal(out, measured)
    assert stats["clipped_as_measured"] == disk.sum() and stats["clipped_filled"] == 0


def test_declipping_on_torch_is_the_same(dev):
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(5)
    t = np.deg2rad([0.0, 45.0, 90.0, 135.0])
    phi = rng.uniform(0, np.pi, (24, 20, 1))
    ic = rng.uniform(0.5, 0.95, (24, 20, 3))
    amp = rng.uniform(0.0, 0.4, (24, 20, 3))
    true = (ic[None] + amp[None] * np.cos(2 * t[:, None, None, None] - 2 * phi[None])).astype(np.float32)
    st = np.minimum(true, 1.0)
    counts = (st >= 0.98).sum(axis=0)
    assert (counts == 1).any() and (counts == 2).any()               # both rebuilding rules are used
    want = declipped(st)
    got = declipped(torch.as_tensor(st, device=dev))
    assert got.device.type == dev.split(":")[0]
    np.testing.assert_allclose(got.cpu().numpy(), want, rtol=0, atol=1e-6)
    assert np.abs(want - st).max() > 0.01


def test_declipping_is_continuous_in_the_conditioning():
    # red clipped at two angles, rebuilt from the AoLP of the unclipped channels: swept through the
    # AoLPs where the 2 x 2 system's |det| crosses the old cut (0.2), the rebuilt samples fade in
    # with |det| from 0.15 to 0.25 instead of appearing at once (a change of 1e-7 in the other
    # samples moved a rebuilt sample by 0.29 on a rendered scene)
    t = np.deg2rad([0.0, 45.0, 90.0, 135.0])
    ic = np.array([0.95, 0.6, 0.5])
    amp = np.array([0.3, 0.3, 0.2])
    angles = np.linspace(14.0, 30.0, 801)
    rebuilt = []
    for a in angles:
        true = (ic[None] + amp[None] * np.cos(2 * t[:, None] - 2 * np.deg2rad(a))).reshape(4, 1, 1, 3)
        st = np.minimum(true, 1.0).astype(np.float32)
        assert (st[:, 0, 0, 0] >= 0.98).sum() == 2 and (st[:, 0, 0, 1:] < 0.98).all()
        rebuilt.append(declipped(st)[:, 0, 0, 0].sum())
    rebuilt = np.array(rebuilt)
    span = rebuilt.max() - rebuilt.min()
    assert span > 0.1                                       # some AoLPs rebuild, some do not
    assert np.abs(np.diff(rebuilt)).max() < 0.02 * span
