"""polcam bench real: the physics metrics on planted layers, and a small run on a real crop."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from polcam.bench.real import OVER_IMIN, achromatic_mask, find_scenes, metrics, prepare, relight, run, write_outputs
from polcam.cli import main
from polcam.errors import PolcamError
from polcam.polarimetry import synthesize

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
HAVE_DATA = bool(find_scenes(DATA)) if DATA.is_dir() else False


def _stack(ic, isv, phi):
    return np.clip(synthesize(ic, isv, phi), 0, 1)


def test_metrics_on_planted_layers():
    h, w = 20, 20
    ic = np.full((h, w, 3), 0.4)
    isv = np.zeros((h, w, 3))
    isv[:2, :] = 0.1                          # 10 % of the pixels carry white polarized light
    ic[:2, :] += 0.3                          # ... and are the brightest
    stack = _stack(ic, isv, np.zeros((h, w, 3)))
    imin = ic - isv
    # the exact answer: diffuse = Imin, specular = Isv
    m = metrics(imin, isv, stack, stack)
    assert m["over_input"] == 0 and m["over_true"] == 0
    assert m["spread"] == pytest.approx(0.0, abs=1e-12)       # white specular everywhere
    # brightest 1 %: among the polarized rows, Isv / Ic = 0.1 / 0.7 removed
    assert m["top_removed"] == pytest.approx(0.1 / 0.7)
    # unpolarized grey pixels (rows 2..) all kept
    assert m["achromatic_kept"] == pytest.approx(1.0)
    # a diffuse above Imin by 4/255 on a quarter of the pixels
    d = imin.copy()
    d[5:10] += 4 / 255
    m2 = metrics(d, ic - d, stack, stack)
    assert m2["over_input"] == pytest.approx(0.25)
    d[5:10] = imin[5:10] + 2 / 255            # under the threshold
    assert metrics(d, ic - d, stack, stack)["over_input"] == 0
    assert OVER_IMIN == pytest.approx(3 / 255)


def test_spread_of_two_specular_colours():
    s = np.zeros((2, 1, 3))
    s[0, 0] = (0.2, 0.0, 0.0)                 # pure red, magnitude 0.2
    s[1, 0] = (0.0, 0.0, 0.2)                 # pure blue, same magnitude
    ic = np.full((2, 1, 3), 0.5)
    stack = _stack(ic, np.zeros_like(ic), np.zeros_like(ic))
    m = metrics(ic - s, s, stack, stack)
    # mean chromaticity (0.5, 0, 0.5); each is sqrt(0.5) away
    assert m["spread"] == pytest.approx(np.sqrt(0.5))


def test_prepare_crops_scales_and_rounds_to_the_cell():
    st = np.random.default_rng(0).uniform(0, 1, (4, 50, 70, 3))
    out = prepare(st, crop=(2, 3, 30, 41))
    assert out.shape == (4, 28, 40, 3)
    assert np.array_equal(out, st[:, 2:30, 3:43])
    assert prepare(st, scale=0.5).shape == (4, 24, 32, 3)
    with pytest.raises(PolcamError, match="crop"):
        prepare(st, crop=(40, 0, 30, 10))
    with pytest.raises(PolcamError, match="scale"):
        prepare(st, scale=1.5)


def test_relight_scales_tints_and_clips():
    st = np.full((4, 2, 3, 3), 0.5)
    st[0, 0, 0] = (0.9, 0.2, 0.1)
    out = relight(st, exposure=1.5, light=(1.0, 0.5, 2.0))
    assert np.allclose(out[1, 1, 1], (0.75, 0.375, 1.0))      # 0.5 * 2 * 1.5 = 1.5 clips at 1
    assert np.allclose(out[0, 0, 0], (1.0, 0.15, 0.3))
    assert np.array_equal(relight(st), st)
    for bad in ({"exposure": 0}, {"exposure": float("nan")}, {"light": (1, 0, 1)}, {"light": (1, 1)}):
        with pytest.raises(PolcamError, match="exposure|light"):
            relight(st, **bad)


def test_achromatic_set_can_be_given():
    h, w = 10, 10
    ic = np.full((h, w, 3), 0.4)
    stack = _stack(ic, np.zeros_like(ic), np.zeros((h, w, 3)))
    assert achromatic_mask(stack).all()
    d = ic.copy()
    d[:5] = 0.0                                # half the grey pixels lost to the specular layer
    assert metrics(d, ic - d, stack, stack)["achromatic_kept"] == pytest.approx(0.5)
    only = np.zeros((h, w), bool)
    only[5:] = True                            # over the kept half alone
    assert metrics(d, ic - d, stack, stack, achromatic=only)["achromatic_kept"] == pytest.approx(1.0)


@pytest.mark.skipif(not HAVE_DATA, reason="../shared/data real colour stacks not present")
def test_relit_run_counts_the_recorded_white_surfaces(tmp_path):
    # under a green-heavy light the white wall is no longer grey in RGB, but it is the same wall:
    # imin keeps its unpolarized light whatever its colour, so the share kept must not change
    kw = {"methods": ["imin"], "scenes": ["jcpd-15"], "crop": (288, 0, 96, 160), "progress": False}
    plain, _ = run(DATA, **kw)
    tinted, _ = run(DATA, light=(0.55, 1.0, 0.7), **kw)
    assert np.isfinite(plain[0].achromatic_kept) and plain[0].achromatic_kept > 0.5
    assert tinted[0].achromatic_kept == pytest.approx(plain[0].achromatic_kept, abs=0.03)
    with pytest.raises(PolcamError, match="exposure"):
        run(DATA, exposure=-1, **kw)
    rc = main(["bench", "real", "--data", str(DATA), "--scenes", "jcpd-15", "--methods", "imin",
               "--exposure", "0", "--out", str(tmp_path / "o")])
    assert rc == 2 and not (tmp_path / "o").exists()


def test_no_data_is_a_clear_error(tmp_path):
    with pytest.raises(PolcamError, match="no real colour stack"):
        run(tmp_path)
    assert main(["bench", "real", "--data", str(tmp_path), "--out", str(tmp_path / "o")]) == 2


@pytest.mark.skipif(not HAVE_DATA, reason="../shared/data real colour stacks not present")
def test_bench_real_on_a_small_crop(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["bench", "real", "--data", str(DATA), "--scenes", "jcpd-15", "--crop", "200", "200", "64", "96",
               "--methods", "imin", "wen21", "--out", str(out)])
    assert rc == 0
    with open(out / "scores.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["scene"], r["method"]) for r in rows] == [("jcpd-15", "imin"), ("jcpd-15", "wen21")]
    for r in rows:
        # both methods are bounded by the Imin of the stack they were given
        assert float(r["over_input"]) == 0.0
        assert 0 <= float(r["top_removed"]) <= 1
    img = cv2.imread(str(out / "montage_jcpd-15.png"))
    assert img is not None and img.shape[0] > 2 * 100 and img.shape[1] == 3 * 360
    assert "| jcpd-15 | wen21 |" in (out / "table.md").read_text()
    assert "jcpd-15" in capsys.readouterr().out


def test_write_outputs_without_layers(tmp_path):
    from polcam.bench.real import RealScore

    paths = write_outputs([RealScore("a", "imin", 0, 0, 0, 0, 1, 0.1)], {}, tmp_path)
    assert [p.name for p in paths] == ["scores.csv", "table.md"]


@pytest.mark.skipif(not HAVE_DATA, reason="../shared/data real colour stacks not present")
def test_unknown_method_refused_before_work(tmp_path, capsys):
    assert main(["bench", "real", "--data", str(DATA), "--methods", "nope", "--out", str(tmp_path / "o")]) == 2
    assert "nope" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
