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
