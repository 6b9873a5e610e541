"""Tests of the lmmse model selection: its validation set is polcam's own and disjoint from the
training set, the score is what the docs say, and the selection runs end to end."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.demosaic_validation import (
    VALIDATION_SEED,
    evaluate,
    format_markdown,
    score,
    select,
    select_shared,
    stage_params,
    validation_scenes,
)
from polcam.bench.lmmse_training import training_stack
from polcam.cli import main
from polcam.demosaicing import demosaic, mosaic_stack
from polcam.errors import MethodError
from polcam.mosaic import parse_layout

SMALL = {"rendered": 2, "size": 48, "pattern_size": 48, "photos": 1}


@pytest.mark.parametrize("color", [True, False])
def test_validation_scenes_are_seeded_and_grouped(color: bool) -> None:
    a = validation_scenes(color=color, **SMALL)
    b = validation_scenes(color=color, **SMALL)
    assert [(g, n) for g, n, _, _ in a] == [("rendered", "rendered-0"), ("rendered", "rendered-1"),
                                            ("patterns", "smooth"), ("patterns", "textured"),
                                            ("patterns", "edges"), ("patterns", "sweep"),
                                            ("photos", "coffee-0"), ("photos", "chelsea-0")]
    lay = parse_layout("imx250myr" if color else "imx250mzr")
    for (_, _, ta, ra), (_, _, tb, rb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(ta, tb)
        np.testing.assert_array_equal(ra, rb)
        assert ta.shape == ((4, 48, 48, 3) if color else (4, 48, 48))
        # the raw is the truth's mosaic, up to the noise model / 16-bit quantisation
        assert float(np.abs(ra - mosaic_stack(ta, layout=lay)).mean()) < 0.02


def test_validation_scenes_are_not_training_scenes() -> None:
    """The rendered group comes from the validation seed, never the training seed's scenes."""
    assert VALIDATION_SEED != 2024
    val = validation_scenes(color=True, **SMALL)[0][2]
    train = training_stack(np.random.default_rng(2024), 48)
    assert not np.allclose(val, train)
    np.testing.assert_array_equal(val, training_stack(np.random.default_rng(VALIDATION_SEED), 48))


def test_score_is_the_mean_over_groups_of_s0_plus_dolp() -> None:
    res = {"a": {"psnr_s0": 40.0, "psnr_dolp": 30.0, "aolp_mae_deg": 1.0},
           "b": {"psnr_s0": 36.0, "psnr_dolp": 20.0, "aolp_mae_deg": 5.0}}
    assert score(res) == pytest.approx(63.0)


def test_evaluate_ranks_a_better_method_higher() -> None:
    """bilinear against a deliberately bad demosaicer (every angle the mosaic itself)."""
    lay = parse_layout("imx250mzr")
    val = validation_scenes(color=False, **SMALL)
    good = evaluate(lambda raw: demosaic(raw, layout=lay, method="bilinear"), val)
    bad = evaluate(lambda raw: np.stack([raw] * 4), val)
    assert set(good) == {"rendered", "patterns", "photos"}
    assert score(good) > score(bad) + 10


def test_select_runs_every_variant() -> None:
    rows = select(scenes=2, size=32, seed=5, ridges=(0.01, 0.1), moments=(1,), patterns=(0, 1), photos=(0, 1),
                  stages=(("ratio", 2.0), ("none", 2.0), ("ratio-tent", 1.0)), baselines=("bilinear",),
                  validation=SMALL)
    for kind in ("color", "mono"):
        sel = [r for r in rows if r["kind"] == kind]
        assert len(sel) == 1 + 2 * 2 * 2 * 3
        assert all(np.isfinite(r["score"]) for r in sel)
    text = format_markdown(rows)
    assert "best color: lmmse" in text and "best mono: lmmse" in text
    with pytest.raises(MethodError, match="patterns"):
        select(scenes=1, size=32, seed=5, patterns=(0, 1, 2), validation=SMALL)
    with pytest.raises(MethodError, match="photos"):
        select(scenes=1, size=32, seed=5, photos=(0, 1, 2), validation=SMALL)


def test_select_shared_runs_every_variant_and_matches_the_shipped_method() -> None:
    """One row per baseline, the per-colour ratio stage (tent) and every (common, offset, residual);
    the row with the shipped Gaussians scores exactly what the shipped ``lmmse`` scores."""
    from polcam.demosaicing.lmmse import LMMSE_PARAMS

    shipped = (LMMSE_PARAMS["common_sigma"], LMMSE_PARAMS["offset_sigma"], LMMSE_PARAMS["residual_sigma"])
    rows = select_shared(commons=(shipped[0], 2.0), offsets=(shipped[1],), residuals=(shipped[2], 6.0),
                         baselines=("bilinear", "lmmse"), validation=SMALL)
    assert len(rows) == 2 + 1 + 2 * 1 * 2
    assert all(r["kind"] == "color" and np.isfinite(r["score"]) for r in rows)
    lm_row = next(r for r in rows if r["variant"] == "lmmse")
    same = next(r for r in rows if (r["common"], r["offset"], r["residual"]) == shipped)
    assert same["score"] == pytest.approx(lm_row["score"], abs=1e-9)
    ratio = next(r for r in rows if r["variant"].startswith("lmmse, ratio stage"))
    assert ratio["score"] != pytest.approx(same["score"], abs=1e-6)
    assert "best color: lmmse, " in format_markdown(rows)


def test_stage_params_name_the_kernel() -> None:
    assert stage_params("ratio", 2.0)["kernel"] == "gauss"
    tent = stage_params("ratio-tent", 1.5)
    assert tent["kernel"] == "tent" and tent["tent_sigma"] == 1.5 and tent["color_stage"] == "ratio"
    with pytest.raises(MethodError, match="second stage"):
        stage_params("median", 1.0)


def test_photos_group_uses_validation_photographs_only() -> None:
    """The photos group is cut from the validation photographs, never the training ones, and
    the other groups do not depend on it."""
    from polcam.synth.photos import TRAINING_PHOTOS, VALIDATION_PHOTOS

    val = validation_scenes(color=True, **SMALL)
    names = [n.rsplit("-", 1)[0] for g, n, _, _ in val if g == "photos"]
    assert set(names) == set(VALIDATION_PHOTOS) and not set(names) & set(TRAINING_PHOTOS)
    without = validation_scenes(color=True, **{**SMALL, "photos": 0})
    assert len(without) == len(val) - len(VALIDATION_PHOTOS)
    for (_, _, ta, _), (_, _, tb, _) in zip(without, val, strict=False):
        np.testing.assert_array_equal(ta, tb)


def test_command_line_refuses_the_validation_seed_for_training() -> None:
    with pytest.raises(SystemExit):
        main(["bench", "demosaic-validation", "--seed", str(VALIDATION_SEED)])
