"""Training of polarized-residual's learned stage: its samples, the fit, the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from polcam.bench.residual_training import fit, scene_samples
from polcam.cli import main
from polcam.errors import PolcamError
from polcam.separation import _learned_residual as lr
from polcam.synth.family import TEST_SEED_MIN, TRAINING_SEED_MIN, split_seeds, training_seeds


def test_training_seeds_are_disjoint_from_both_splits() -> None:
    seeds = training_seeds(50, start=10)
    assert seeds[0] == TRAINING_SEED_MIN + 10 and len(set(seeds)) == 50
    assert max(split_seeds("validation", 40)[0]) < min(seeds) and max(seeds) < TEST_SEED_MIN
    with pytest.raises(PolcamError, match="training scenes"):
        training_seeds(0)
    with pytest.raises(PolcamError, match="1..500000"):
        split_seeds("validation", TRAINING_SEED_MIN + 1)


def test_scene_samples_targets_lie_between_zero_and_the_bound() -> None:
    s = scene_samples(training_seeds(1)[0], size=64)
    n = len(s["target"])
    assert n > 0 and s["x"].shape == (n, len(lr.FEATURES)) and np.isfinite(s["x"]).all()
    assert (s["target"] >= 0).all() and (s["target"] <= s["bound"] + 1e-9).all() and (s["weight"] > 0).all()


def test_fit_recovers_a_planted_share() -> None:
    """Targets made by a known rule of two features: the fit predicts them far better than no removal."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4000, len(lr.FEATURES))).astype(np.float32)
    bound = rng.uniform(0.2, 1.0, 4000)
    target = bound * np.clip(0.5 + 0.4 * np.tanh(x[:, 0]) - 0.3 * x[:, 3], 0, 1)
    w = fit({"x": x, "target": target, "bound": bound, "weight": np.ones(4000)}, hidden=(8,), iterations=300, l2=0)
    pred = bound * np.clip(lr.forward(x, {k: np.asarray(v, np.float32) for k, v in w.items()}), 0, 1)
    assert np.mean((pred - target) ** 2) < 0.02 * np.mean(target ** 2)


@pytest.mark.slow
def test_command_writes_weights_the_method_loads(tmp_path) -> None:
    out = tmp_path / "w.npz"
    assert main(["bench", "train-residual", "--scenes", "2", "--size", "64", "--samples", "3000",
                 "--iterations", "5", "--out", str(out)]) == 0
    w = lr.load_weights(out)
    assert int(w["layers"]) == 3
    with np.load(out) as z:
        assert "--scenes 2 --size 64" in json.loads(str(z["info"]))["command"]


def test_command_refuses_bad_numbers(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "train-residual", "--scenes", "0"])
    assert "--scenes 0" in capsys.readouterr().err
