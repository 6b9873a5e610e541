"""Tests of the lmmse training script: its scenes, the constrained fit, the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from polcam.bench.lmmse_training import accumulate, fit_bank, gram_sums, pattern_stack, training_stack
from polcam.cli import main
from polcam.demosaicing import mosaic_stack
from polcam.demosaicing.lmmse import CANONICAL, apply_bank, lattice_of_taps, tap_offsets
from polcam.mosaic import parse_layout
from polcam.polarimetry import dolp


def test_scenes_are_seeded_in_range_and_colours_differ_in_polarization() -> None:
    a = training_stack(np.random.default_rng(5), 64)
    b = training_stack(np.random.default_rng(5), 64)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (4, 64, 64, 3) and a.dtype == np.float32
    assert 0.0 <= float(a.min()) and float(a.max()) <= 1.0
    # over a few scenes, DoLP differs between colour channels at many pixels, and both weakly
    # and strongly polarized pixels occur
    d = np.concatenate([dolp(training_stack(np.random.default_rng(s), 64)).reshape(-1, 3) for s in range(6)])
    spread = d.max(axis=1) - d.min(axis=1)
    assert float(np.mean(spread > 0.05)) > 0.1
    assert float(np.mean(d < 0.1)) > 0.2 and float(np.mean(d > 0.4)) > 0.01


@pytest.mark.parametrize("color", [False, True])
def test_fit_keeps_the_constraints_and_fits_its_data(color: bool) -> None:
    """The fitted bank meets the lattice-sum and moment constraints and predicts its training blocks."""
    lay = parse_layout(CANONICAL[(color, "diag")])
    rng = np.random.default_rng(0)
    stack = training_stack(rng, 64)
    truth = stack if color else stack[..., 1]
    raw = mosaic_stack(truth, layout=lay)
    gram, cross, n = accumulate([(raw, truth)], lay)
    assert n == 14 * 14 and gram.shape == (144, 144)
    w = fit_bank(gram, cross, lay, ridge=1e-6)
    channels = 3 if color else 1
    lat = lattice_of_taps(lay)
    off = tap_offsets()
    for o in range(0, 64 * channels, 7):
        k, rest = divmod(o, 16 * channels)
        u, rest = divmod(rest, 4 * channels)
        v, c = divmod(rest, channels)
        for lt in range(4 * channels):
            sel = lat == lt
            assert w[sel, o].sum() == pytest.approx(1.0 if lt == k * channels + c else 0.0, abs=1e-4)
            assert float(w[sel, o] @ (off[sel, 0] - u)) == pytest.approx(0.0, abs=1e-3)
    # the fit predicts the training targets far better than the constraint-only solution would
    # (a pure bilinear-like map): the residual is small compared with the targets' spread
    from polcam.demosaicing.lmmse import block_features, to_blocks

    x = block_features(to_blocks(raw), 0, 14).reshape(-1, 144)
    pred = x @ w
    tgt = truth.reshape(4, 16, 4, 16, 4, channels).transpose(1, 3, 0, 2, 4, 5)[1:-1, 1:-1].reshape(pred.shape)
    assert float(np.sqrt(np.mean((pred - tgt) ** 2))) < 0.5 * float(tgt.std())


@pytest.mark.parametrize("color", [False, True])
def test_second_moments_make_quadratic_images_exact(color: bool) -> None:
    """With ``moments=2`` every angle (and colour) image a different quadratic function of x and
    y comes back exactly; with ``moments=1`` it does not."""
    lay = parse_layout(CANONICAL[(color, "diag")])
    stack = training_stack(np.random.default_rng(1), 64)
    truth = stack if color else stack[..., 1]
    gram, cross, _ = accumulate([(mosaic_stack(truth, layout=lay), truth)], lay)
    h, w = 40, 48
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) / 40
    rng = np.random.default_rng(2)
    channels = 3 if color else 1
    quad = np.empty((4, h, w, channels), np.float32)
    for k in range(4):
        for c in range(channels):
            a = rng.uniform(-0.3, 0.3, 6)
            quad[k, ..., c] = 0.5 + a[0] * x + a[1] * y + a[2] * x * x + a[3] * x * y + a[4] * y * y
    q = quad if color else quad[..., 0]
    raw = mosaic_stack(q, layout=lay)
    errs = {}
    for order in (1, 2):
        wts = fit_bank(gram, cross, lay, ridge=1e-2, moments=order)
        est = apply_bank(raw, wts, (0, 0), channels)[:, 8:-8, 8:-8]
        errs[order] = float(np.abs(est - quad[:, 8:-8, 8:-8]).max())
    assert errs[2] < 1e-4 < errs[1], errs


def test_pattern_scenes_and_additive_sums() -> None:
    """Pattern scenes are seeded RGB stacks in [0, 1]; the normal equations of scenes and pattern
    scenes add, so the selection can fit every mix from two passes."""
    a = pattern_stack(np.random.default_rng(3), 32)
    np.testing.assert_array_equal(a, pattern_stack(np.random.default_rng(3), 32))
    assert a.shape == (4, 32, 32, 3) and 0 <= float(a.min()) and float(a.max()) <= 1
    both = gram_sums(scenes=1, size=32, seed=9, patterns=2)
    first = gram_sums(scenes=1, size=32, seed=9)
    second = gram_sums(scenes=0, size=32, seed=9, patterns=2)
    for key, (g, x, n) in both.items():
        np.testing.assert_allclose(g, first[key][0] + second[key][0])
        np.testing.assert_allclose(x, first[key][1] + second[key][1])
        assert n == first[key][2] + second[key][2]
    # photograph crops add the same way
    with_photos = gram_sums(scenes=1, size=32, seed=9, photos=1)
    photos = gram_sums(scenes=0, size=32, seed=9, photos=1)
    for key, (g, x, n) in with_photos.items():
        np.testing.assert_allclose(g, first[key][0] + photos[key][0])
        assert n == first[key][2] + photos[key][2]


def test_command_line_writes_weights(tmp_path: Path) -> None:
    out = tmp_path / "w.npz"
    assert main(["bench", "train-lmmse", "--scenes", "2", "--size", "32", "--photos", "0", "--out", str(out)]) == 0
    with np.load(out) as data:
        assert set(data.files) == {"info", "mono_diag", "mono_beside", "color_diag", "color_beside"}
        assert data["color_diag"].shape == (144, 192) and data["mono_diag"].shape == (144, 64)
        info = json.loads(str(data["info"]))
    assert info["scenes"] == 2 and "no third-party images" in info["data"]
    assert info["command"].startswith("polcam bench train-lmmse --scenes 2 --size 32 ")
    with pytest.raises(SystemExit):
        main(["bench", "train-lmmse", "--size", "30", "--out", str(out)])


def test_shipped_weights_say_how_they_were_made() -> None:
    from polcam.demosaicing.lmmse import WEIGHTS_FILE

    with np.load(WEIGHTS_FILE) as data:
        info = json.loads(str(data["info"]))
    assert info["scenes"] >= 100 and "polcam.demosaicing.training" in info["command"]  # the module that made them
    # the settings the validation set chose (docs/methods/demosaic-lmmse.md)
    assert info["moments"] == 2 and info["patterns"] == 50 and info["ridge"] == 0.003 and info["seed"] == 2024
    assert info["photos"] == 80 and "CC0" in info["data"]
