"""Training of polarized-residual's learned stage: its samples, the fit, the command line."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from polcam.bench import residual_training as rt
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
        info = json.loads(str(z["info"]))
    assert "--scenes 2 --size 64" in info["command"]
    assert set(info["harm_checks"]) == set(rt.HARM_FLOORS)       # measured and kept with the weights


def test_command_refuses_bad_numbers(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "train-residual", "--scenes", "0"])
    assert "--scenes 0" in capsys.readouterr().err


def _removes_its_whole_bound() -> dict[str, np.ndarray]:
    """The shipped model with its output pinned at 1: it removes all its bound allows, everywhere in its zone."""
    w = {k: v for k, v in lr.load_weights().items() if k not in ("info", "features")}
    last = int(w["layers"]) - 1
    w[f"w{last}"] = np.zeros_like(w[f"w{last}"])
    w[f"b{last}"] = np.full_like(w[f"b{last}"], 10.0)
    return w


def test_harm_checks_pass_the_shipped_weights_and_fail_a_greedy_model() -> None:
    shipped = rt.harm_checks(lr.load_weights())
    assert rt.failed_checks(shipped) == [] and shipped["checker16_kept"] < 1.0   # the stage does act there
    greedy = rt.harm_checks(_removes_its_whole_bound())
    # what the evidence bound would let through if the model took all of it: a share of the
    # 16-pixel squares' light (step 0's fit leaves little of the demosaicing's polarization at
    # their edges, so few of their pixels lie in the zone), and of the chart's greys
    assert greedy["checker16_kept"] < 0.95 and greedy["checker16_worst_square"] < 0.9
    assert greedy["chart_worst_grey"] < 0.96 and greedy["chart_frame_worst_grey"] < 0.96
    failed = rt.failed_checks(greedy)
    assert any(f.startswith("checker16_kept") for f in failed) and any(f.startswith("chart_worst_grey") for f in failed)


def test_weights_that_fail_the_checks_do_not_replace_the_shipped_ones(tmp_path, monkeypatch, capsys) -> None:
    from polcam.commands.bench import separation as cmd

    shipped = tmp_path / "residual_weights.npz"
    shipped.write_bytes(lr.WEIGHTS_FILE.read_bytes())
    monkeypatch.setattr(cmd, "RESIDUAL_WEIGHTS", shipped)         # the command's notion of "the shipped weights"
    monkeypatch.setattr(rt, "train", lambda *a, **k: {**_removes_its_whole_bound(), "loss": np.array(0.0)})
    assert main(["bench", "train-residual", "--out", str(shipped)]) == 1
    assert shipped.read_bytes() == lr.WEIGHTS_FILE.read_bytes()   # left as it was
    err = capsys.readouterr().err
    assert re.search(r"checker16_kept 0\.\d+ < 0\.98", err) and "is left as it was" in err
    rejected = tmp_path / "residual_weights.rejected.npz"           # nothing lost: the new weights are kept
    assert lr.load_weights(rejected)["b2"][0] == 10.0
    # elsewhere than the shipped file the weights are written, with a warning
    other = tmp_path / "try.npz"
    assert main(["bench", "train-residual", "--out", str(other)]) == 0
    assert other.exists() and "warning: these weights fail" in capsys.readouterr().err


def test_matte_scenes_hold_no_specular_light() -> None:
    from scipy import ndimage

    stack, truth, mask = rt.matte_scene(0, size=64)
    assert stack.shape == (4, 64, 64, 3) and stack.dtype == np.float32 and truth.shape == (64, 64, 3) and mask.all()
    again, _, _ = rt.matte_scene(0, size=64)
    assert np.array_equal(again, stack) and not np.array_equal(rt.matte_scene(1, size=64)[0], stack)
    saturated = 0
    for index in range(4):
        stack, truth, _ = rt.matte_scene(index)
        # nothing but the diffuse: the light is the truth's (noise and demosaicing average out)
        assert abs(stack.mean() / truth.mean() - 1.0) < 0.005
        # and unpolarized: away from the rectangles' edges, where the demosaicing draws its own
        # polarization, the image's S1 and S2 vanish against its S0 (noise alone)
        flat = np.all(ndimage.maximum_filter(truth, size=(13, 13, 1)) == ndimage.minimum_filter(truth, size=(13, 13, 1)),
                      axis=-1)
        s0 = float((stack[0] + stack[2])[flat].sum())
        assert flat.mean() > 0.2
        assert abs(float((stack[0] - stack[2])[flat].sum())) < 0.003 * s0
        assert abs(float((stack[1] - stack[3])[flat].sum())) < 0.003 * s0
        # some rectangles are of a saturated colour, not only grey or near grey
        saturated += int(((truth.max(-1) - truth.min(-1)) > 0.5 * truth.max(-1)).any())
    assert saturated >= 2


def test_training_samples_add_the_matte_scenes() -> None:
    family = rt.training_samples(1, size=64, max_samples=10**6, matte=0)
    both = rt.training_samples(1, size=64, max_samples=10**6, matte=2, matte_samples=10**6)
    added = len(both["target"]) - len(family["target"])
    assert added > 0 and np.array_equal(both["x"][:len(family["target"])], family["x"])
    # a matte scene's target is what its layer holds above the truth: little of the bound
    tail = slice(len(family["target"]), None)
    assert (both["target"][tail] >= 0).all() and both["target"][tail].sum() < 0.5 * both["bound"][tail].sum()
    assert len(rt.training_samples(1, size=64, max_samples=10**6, matte=2, matte_samples=50)["target"]) < \
        len(family["target"]) + 120



def test_mono_samples_read_what_the_mono_separation_runs() -> None:
    """A mono stack's inputs are those of polarized-residual's own mono run: the layer the stage makes
    from them with the shipped mono weights is the default mono layer, in each of three equal channels."""
    from polcam.separation.polarized_residual import learned_inputs, learned_layer, separate_polarized_residual
    from polcam.synth.family import render_family

    sc = render_family(training_seeds(1)[0], size=64)
    inputs = learned_inputs(sc.mono_stack)
    assert inputs["diffuse"].shape == (64, 64, 3) and inputs["zone"].any()
    layer = learned_layer(inputs, lr.load_weights(mono=True))
    assert np.array_equal(layer[..., 0], layer[..., 1]) and np.array_equal(layer[..., 0], layer[..., 2])
    mono, _ = separate_polarized_residual(sc.mono_stack)
    np.testing.assert_allclose(layer.mean(axis=-1), mono, atol=1e-6)
    assert not np.allclose(np.asarray(learned_layer(inputs, lr.load_weights())).mean(axis=-1), mono, atol=1e-4)
    # its samples are scored against the mono truth: the targets are what the layer holds above it
    s = scene_samples(training_seeds(1)[0], size=64, camera="mono")
    d = np.asarray(inputs["diffuse"], np.float64)[..., 0][inputs["zone"]]
    t = np.asarray(sc.diffuse_mono, np.float64)[inputs["zone"]]
    np.testing.assert_allclose(s["target"], np.clip(d - t, 0.0, s["bound"]), atol=1e-6)   # G = (1, 1, 1)
    assert np.array_equal(s["x"], inputs["x"])


def test_mono_matte_scenes_are_the_colour_ones_luminance() -> None:
    stack, truth, mask = rt.matte_scene(3, size=64, camera="mono")
    _, colour_truth, _ = rt.matte_scene(3, size=64)
    assert stack.shape == (4, 64, 64) and truth.shape == (64, 64) and mask.all()
    np.testing.assert_allclose(truth, colour_truth.mean(axis=-1))
    assert abs(stack.mean() / truth.mean() - 1.0) < 0.005                     # unpolarized, nothing added
    chart, patches = rt.colour_chart(camera="mono")
    assert chart.ndim == 3 and patches.shape[0] == 24                          # to a mono camera every patch is grey
    with pytest.raises(ValueError, match="camera='infrared'"):
        rt.matte_scene(0, camera="infrared")


def test_without_colour_the_bound_alone_keeps_the_matte_scenes() -> None:
    """In a mono stack the stage removes at most the polarized light it sees at the pixel: even a model
    that removes all of that keeps every matte scene of the checks above its floors, where on a colour
    stack it does not (test above); the shipped mono weights pass them too."""
    greedy = rt.harm_checks(_removes_its_whole_bound(), camera="mono")
    assert rt.failed_checks(greedy) == [] and greedy["checker16_kept"] < 1.0
    assert rt.failed_checks(rt.harm_checks(lr.load_weights(mono=True), camera="mono")) == []


def test_command_trains_for_the_camera_asked(tmp_path, capsys) -> None:
    out = tmp_path / "m.npz"
    assert main(["bench", "train-residual", "--camera", "mono", "--scenes", "1", "--size", "64", "--samples", "2000",
                 "--iterations", "3", "--matte-scenes", "1", "--out", str(out)]) == 0
    with np.load(out) as z:
        info = json.loads(str(z["info"]))
    assert info["camera"] == "mono" and info["command"].startswith("polcam bench train-residual --camera mono")
    with pytest.raises(SystemExit):
        main(["bench", "train-residual", "--camera", "infrared"])
    assert "invalid choice: 'infrared'" in capsys.readouterr().err
