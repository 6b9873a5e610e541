"""Tiles and their blending."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.separation.tensor.operators import unfold
from polcam.separation.tensor.tiling import blend, ramps, seam_jumps, tile_batch, tile_spans, tile_windows, tiled


@pytest.mark.parametrize("n,tile,overlap", [(10, 16, 4), (16, 16, 4), (40, 16, 4), (37, 12, 5), (100, 30, 0)])
def test_tile_spans_cover_with_the_overlap(n, tile, overlap):
    spans = tile_spans(n, tile, overlap)
    assert spans[0][0] == 0 and spans[-1][1] == n
    assert all(b - a == min(tile, n) for a, b in spans)
    for (a0, b0), (a1, b1) in zip(spans, spans[1:]):
        assert a0 < a1 and b0 - a1 >= overlap          # consecutive tiles share >= overlap pixels


def test_ramps_rise_and_fall_over_the_shared_parts():
    spans = tile_spans(40, 16, 4)
    w = ramps(spans)
    assert np.all(w[0][:8] == 1) and w[0][-1] < 0.2            # the first tile: flat, then falls
    assert w[1][0] < 0.2 and w[1][-1] < 0.2 and w[1].max() == 1
    # along the axis the weights of the tiles covering a pixel are positive and sum to > 0
    total = np.zeros(40)
    for (a, b), wt in zip(spans, w):
        assert np.all(wt > 0)
        total[a:b] += wt
    assert total.min() > 0


def test_blending_reproduces_a_pixelwise_result_on_any_tiling():
    """A per-pixel 'solver' gives the same image whatever the tiles: the weights sum to one."""
    rng = np.random.default_rng(11)
    img = rng.uniform(0, 1, (37, 50, 3))

    def solve(rows, cols):
        return np.sqrt(img[rows, cols])

    for tile, overlap, workers in [(64, 0, 1), (16, 4, 1), (12, 5, 2), (9, 0, 1)]:
        np.testing.assert_allclose(tiled(img.shape[:2], tile, overlap, solve, workers=workers),
                                   np.sqrt(img), atol=1e-12)
    # blend takes results in tile_windows order
    windows = tile_windows(img.shape[:2], 16, 4)
    res = [np.full((r.stop - r.start, c.stop - c.start, 1), 2.0) for r, c in windows]
    np.testing.assert_allclose(blend(img.shape[:2], 16, 4, res), 2.0)
    with pytest.raises(ValueError, match="tile results"):
        blend(img.shape[:2], 16, 4, res[:-1])


def test_rectangular_tiles_cover_the_image_and_blend_constants_exactly():
    windows = tile_windows((50, 70), (24, 12), 4)
    cover = np.zeros((50, 70), int)
    for r, c in windows:
        assert (r.stop - r.start, c.stop - c.start) == (24, 12)
        cover[r, c] += 1
    assert cover.min() >= 1
    res = [np.full((24, 12, 3), 0.25) for _ in windows]
    np.testing.assert_allclose(blend((50, 70), (24, 12), 4, res), 0.25)
    np.testing.assert_allclose(blend((50, 70), (24, 12), 4, np.stack(res)), 0.25)


def test_tile_batch_is_the_unfolded_windows():
    rng = np.random.default_rng(4)
    d0 = rng.uniform(0, 1, (4, 4, 30, 41, 3)).astype(np.float32)
    ys, xs = tile_spans(30, 12, 2), tile_spans(41, 16, 3)
    got = tile_batch(d0, ys, xs)
    windows = [(slice(*y), slice(*x)) for y in ys for x in xs]
    assert got.shape[0] == len(windows) > 4
    for g, (r, c) in zip(got, windows):
        np.testing.assert_array_equal(g, unfold(d0[:, :, r, c]))


def test_torch_tiles_and_blend_match_numpy():
    torch = pytest.importorskip("torch")
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    rng = np.random.default_rng(4)
    d0 = rng.uniform(0, 1, (4, 4, 30, 41, 3)).astype(np.float32)
    ys, xs = tile_spans(30, 12, 2), tile_spans(41, 16, 3)
    res3 = rng.uniform(0, 1, (len(tile_spans(30, 12, 3)) * len(xs), 12, 16, 3))
    want = blend((30, 41), (12, 16), 3, list(res3))
    for dev in devices:
        got = tile_batch(torch.as_tensor(d0, device=dev), ys, xs).cpu().numpy()
        np.testing.assert_array_equal(got, tile_batch(d0, ys, xs))
        out = blend((30, 41), (12, 16), 3, torch.as_tensor(res3, device=dev))
        np.testing.assert_allclose(out.cpu().numpy(), want, atol=1e-12)


def test_seam_jumps_find_a_planted_seam_and_no_seam_in_a_smooth_image():
    yy, xx = np.mgrid[0:60, 0:90] / 90.0
    smooth = np.stack([0.3 + 0.2 * (xx + yy), 0.4 + 0.1 * (xx + yy), 0.5 - 0.1 * (xx + yy)], axis=-1)
    b, i = seam_jumps(smooth, tile=(24, 16), overlap=4)
    assert b / i == pytest.approx(1.0, abs=1e-6)                  # linear: every jump alike
    # a per-tile offset (what tiles solved apart and joined without blending leave): seams
    stepped = smooth.copy()
    for n, (r, c) in enumerate(tile_windows((60, 90), (24, 16), 0)):
        stepped[r, c] += 0.01 * (n % 3)
    b, i = seam_jumps(stepped, tile=(24, 16), overlap=0)
    assert b > 3 * i
    # against a reference: the share of the light kept; the reference's own edges do not count
    ref = smooth * np.where(xx > 0.5, 2.0, 1.0)[..., None]          # an edge in the input...
    b, i = seam_jumps(0.5 * ref, tile=(24, 16), overlap=4, reference=ref)   # ...kept in the layer
    assert b == pytest.approx(0.0, abs=1e-12) and i == pytest.approx(0.0, abs=1e-12)
