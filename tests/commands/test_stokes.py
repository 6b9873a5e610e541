"""``polcam stokes`` (and the demo, which runs it) reports the DoLP of the lit pixels only."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from polcam.cli import main
from polcam.commands.stokes import LIT_DOLP_BIAS, dolp_of_lit, lit_floor
from polcam.io import read_image

REPO = Path(__file__).resolve().parents[2]


def test_lit_floor_is_the_noise_bias_bound():
    # unpolarized light plus noise of one quantisation step per angle image, at the floor:
    # the DoLP read is LIT_DOLP_BIAS on average (Monte Carlo against the closed form)
    white = 4095.0
    floor = lit_floor(0.0, white)
    assert floor == pytest.approx(math.sqrt(math.pi) / LIT_DOLP_BIAS / white)
    rng = np.random.default_rng(0)
    sigma = 1.0 / white
    i = floor / 2 + rng.normal(0, sigma, (4, 200_000))              # S0 = (I0 + I45 + I90 + I135) / 2
    s0 = i.sum(axis=0) / 2
    dolp = np.hypot(i[0] - i[2], i[1] - i[3]) / s0
    assert dolp.mean() == pytest.approx(LIT_DOLP_BIAS, rel=0.02)
    assert lit_floor(0, 255) == pytest.approx(35.449 / 255, rel=1e-4)


def test_dolp_of_lit_counts_only_lit_pixels():
    s0 = np.array([[0.5, 0.001], [0.2, 0.0]])
    dolp = np.array([[0.1, 0.9], [0.3, 1.0]])
    got = dolp_of_lit(s0, dolp, 0.01)
    assert got["lit_share"] == 0.5 and got["mean"] == pytest.approx(0.2) and got["median"] == pytest.approx(0.2)
    none = dolp_of_lit(s0, dolp, 5.0)
    assert none["lit_share"] == 0 and math.isnan(none["mean"])


def test_the_bunny_reports_its_object_not_the_dark_background(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["stokes", str(REPO / "fixtures" / "raw" / "synthetic_bunny5.png"), "-o", str(out),
                 "--format", "tiff"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    got = re.search(r"DoLP over the lit pixels \(S0 >= ([\d.]+), (\d+)% of the pixels\): "
                    r"mean ([\d.]+), median ([\d.]+)", line)
    assert got, line
    # independently: the maps written, read back, and the floor of a 12-bit frame
    s0, _ = read_image(out / "synthetic_bunny5" / "s0.tif")
    dolp, _ = read_image(out / "synthetic_bunny5" / "dolp.tif")
    lit = s0 >= math.sqrt(math.pi) / 0.05 / 4095
    assert float(got.group(1)) == pytest.approx(math.sqrt(math.pi) / 0.05 / 4095, rel=1e-2)
    assert int(got.group(2)) == round(100 * lit.mean())
    assert float(got.group(3)) == pytest.approx(float(dolp[lit].mean()), abs=1e-3)
    assert float(got.group(4)) == pytest.approx(float(np.median(dolp[lit])), abs=1e-3)
    # the dark background's noise is what the plain mean reported
    assert float(dolp.mean()) > 0.4 and float(got.group(3)) < 0.1
    meta = json.loads((out / "synthetic_bunny5" / "meta.json").read_text())
    assert meta["dolp_lit"]["mean"] == pytest.approx(float(got.group(3)), abs=1e-3)
