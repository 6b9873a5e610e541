"""polcam bench quality: metrics and a small end-to-end run."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from polcam.bench.quality import PAPER_TABLES, format_paper, psnr, run, ssim, write_outputs
from polcam.cli import main


def test_psnr_closed_form_and_mask():
    ref = np.zeros((4, 4, 3))
    x = ref.copy()
    x[0, 0] = 0.1                     # one pixel off by 0.1 in three channels
    assert np.isclose(psnr(x, ref), 10 * np.log10(1 / (3 * 0.01 / 48)))
    mask = np.zeros((4, 4), bool)
    mask[0, :2] = True
    assert np.isclose(psnr(x, ref, mask), 10 * np.log10(1 / (3 * 0.01 / 6)))
    assert psnr(ref, ref) == float("inf")


def test_ssim_mask_of_everything_is_the_whole_image():
    rng = np.random.default_rng(0)
    ref = rng.uniform(0, 1, (32, 32, 3))
    x = np.clip(ref + rng.normal(0, 0.05, ref.shape), 0, 1)
    assert np.isclose(ssim(x, ref), ssim(x, ref, np.ones((32, 32), bool)))
    assert ssim(ref, ref) == pytest.approx(1.0)
    assert ssim(x, ref) < 0.99


def test_paper_tables_are_complete():
    scenes = {f"Bunny{i}" for i in range(1, 8)} | {"Dragon1", "Dragon2", "Armadillo"}
    for method, table in PAPER_TABLES.items():
        assert set(table) == scenes, method
    # the paper's own claim: the tensor method is best on every scene
    for sc in scenes:
        assert max(PAPER_TABLES, key=lambda m: PAPER_TABLES[m][sc][1]) == "tensor"
    assert "Bunny4" in format_paper(["Bunny4"])


def test_small_run_scores_and_writes(tmp_path):
    scores, stats = run(scenes=["Bunny1", "Bunny6"], methods=["imin", "yang10"], size=32, progress=False)
    assert [(s.scene, s.method) for s in scores] == [
        ("Bunny1", "imin"), ("Bunny1", "yang10"), ("Bunny6", "imin"), ("Bunny6", "yang10")]
    assert all(np.isfinite(s.psnr) and 0 < s.ssim <= 1 for s in scores)
    assert stats["Bunny6"]["specular_ratio"] > stats["Bunny1"]["specular_ratio"]
    # every method improves on doing nothing on the strong-specular scene
    for s in scores:
        if s.scene == "Bunny6":
            assert s.psnr > stats["Bunny6"]["input_psnr"]
    files = write_outputs(scores, stats, tmp_path)
    with (tmp_path / "scores.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 and float(rows[0]["psnr"]) == pytest.approx(scores[0].psnr, abs=1e-3)
    assert "| imin |" in (tmp_path / "table.md").read_text()
    png = tmp_path / "psnr_vs_specular.png"
    assert png in files and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_failing_method_is_reported_not_fatal():
    scores, _ = run(scenes=["Bunny1"], methods=["imin", "no-such-method"], size=32, progress=False)
    assert scores[1].error and "no-such-method" in scores[1].error and np.isfinite(scores[0].psnr)


def test_cli_render(tmp_path, capsys):
    assert main(["render", str(tmp_path), "--scenes", "Bunny2", "--size", "32"]) == 0
    assert (tmp_path / "Bunny2" / "raw_imx250myr.png").is_file()
    assert main(["render", str(tmp_path), "--scenes", "Teapot", "--size", "32"]) == 2
    assert "Teapot" in capsys.readouterr().err


def test_scene_sets_and_a_mono_run(tmp_path):
    from polcam.bench.quality import format_object_psnr, scene_set
    from polcam.synth.scenes import SCENES, STRESS

    assert scene_set("paper") == list(SCENES)
    assert scene_set("all") == [*SCENES, *STRESS]
    with pytest.raises(ValueError, match="scene set"):
        scene_set("nope")
    scores, stats = run(scenes=["Brewster"], size=32, mono=True, progress=False)
    methods = [s.method for s in scores]
    assert "imin" in methods and "wen21" not in methods   # only methods that take mono stacks
    by = {s.method: s for s in scores}
    # near Brewster's angle the specular light is almost fully polarized: imin is close to the truth
    assert by["imin"].psnr_mask > 30
    table = format_object_psnr(scores)
    import polcam

    header = [c.strip() for c in table.splitlines()[0].strip("|").split("|")]
    assert header == ["scene", *[m for m in polcam.METHODS if m in methods]]   # columns in registry order
    assert "| Brewster |" in table and "| mean |" in table and "**" in table
    write_outputs(scores, stats, tmp_path)
    assert "Object PSNR" in (tmp_path / "table.md").read_text()


def test_family_run_scores_the_camera_stack_against_truth(capsys, tmp_path):
    from polcam.bench.quality import family_summary, run_family
    from polcam.synth.family import render_family

    scores, stats, seeds, master = run_family("validation", 2, size=32, methods=["imin"], progress=False)
    assert seeds == [0, 1] and master is None and [s.scene for s in scores] == ["rand-0", "rand-1"]
    sc = render_family(0, size=32)
    # imin of the camera stack, scored on the object: an independent computation of the same figure
    from polcam.polarimetry import imin
    ref = psnr(np.clip(imin(sc.stack.astype(np.float64)), 0, sc.stack.mean(0)), sc.diffuse, sc.mask)
    assert scores[0].psnr_mask == pytest.approx(ref, abs=0.05)
    mono, _, _, _ = run_family("validation", 1, size=32, methods=["imin"], mono=True, progress=False)
    ref_mono = psnr(np.clip(imin(sc.mono_stack.astype(np.float64)), 0, sc.mono_stack.mean(0))[..., None],
                    sc.diffuse_mono[..., None], sc.mask)
    assert mono[0].psnr_mask == pytest.approx(ref_mono, abs=0.05)
    assert "| imin |" in family_summary(scores) and "100%" in family_summary(scores)
    # the CLI prints the test split's master seed, and the seed reproduces the run's scenes
    assert main(["bench", "quality", "--set", "random", "--split", "test", "--n", "1", "--size", "32",
                 "--methods", "imin", "--seed", "7", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    from polcam.synth.family import split_seeds
    assert "master seed 7" in out and f"rand-{split_seeds('test', 1, seed=7)[0][0]}" in out
    assert main(["bench", "quality", "--set", "random", "--split", "validation", "--seed", "3", "--n", "1",
                 "--out", str(tmp_path)]) == 2


def test_the_analytic_family_runs_through_the_same_bench(capsys, tmp_path):
    from polcam.bench.quality import run_family
    from polcam.polarimetry import imin
    from polcam.synth.analytic import render_analytic

    scores, _, seeds, _ = run_family("validation", 2, size=32, methods=["imin"], progress=False, family="analytic")
    assert seeds == [0, 1] and [s.scene for s in scores] == ["ana-0", "ana-1"]
    sc = render_analytic(1, size=32)
    ref = psnr(np.clip(imin(sc.stack.astype(np.float64)), 0, sc.stack.mean(0)), sc.diffuse, sc.mask)
    assert scores[1].psnr_mask == pytest.approx(ref, abs=0.05)
    with pytest.raises(ValueError, match="scene family 'mesh'"):
        run_family("validation", 1, size=32, methods=["imin"], progress=False, family="mesh")
    assert main(["bench", "quality", "--set", "analytic", "--n", "1", "--size", "32", "--methods", "imin",
                 "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "scenes: ana-0" in out and "| imin |" in out
