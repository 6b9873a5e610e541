"""polcam bench real --relit: the matte mask, the invented-structure measure, a small run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from polcam.bench.relit import VARIANTS, brightest_composition, invented_structure, matte_mask, run, summary
from polcam.cli import main


def _grey_stack(img: np.ndarray) -> np.ndarray:
    """(H, W) unpolarized grey scene -> (4, H, W, 3) stack."""
    return np.repeat(np.repeat(img[None, ..., None], 4, axis=0), 3, axis=-1).astype(np.float64)


def test_matte_mask_leaves_out_clipped_and_locally_bright_pixels():
    img = np.full((80, 80), 0.5)
    img[10:20, 10:20] = 1.0            # clipped patch
    img[50:53, 50:53] = 0.62           # a local highlight, 24 % over its surroundings
    img[60:63, 20:23] = 0.55           # 10 % over: matte sheen the mask keeps
    stack = _grey_stack(img)
    ach = np.ones((80, 80), bool)
    m = matte_mask(ach, stack)
    assert not m[10:20, 10:20].any()
    assert not m[8, 8] and not m[21, 15] and m[23, 15]      # grown by 2 pixels, not more
    assert not m[50:53, 50:53].any() and m[60:63, 20:23].all()
    assert m[30:45, 30:45].all()
    assert not matte_mask(np.zeros((80, 80), bool), stack).any()


def _polarized_stack(ic: np.ndarray, p: np.ndarray, phi: float = 0.3) -> np.ndarray:
    """(H, W) intensity and DoLP -> (4, H, W, 3) grey stack, I(t) = Ic (1 + p cos(2t - 2 phi)), clipped at 1."""
    t = np.deg2rad([0, 45, 90, 135])[:, None, None]
    return np.repeat(np.clip(ic * (1 + p * np.cos(2 * t - 2 * phi)), 0, 1)[..., None], 3, axis=-1)


def test_brightest_composition_tells_a_clipped_matte_wall_from_a_polarized_highlight():
    h = w = 96
    ic = np.full((h, w), 0.35)
    p = np.zeros((h, w))
    wall = ic.copy()
    wall[:, :12] = 1.2                                  # a matte white wall, clipped, 12.5 % of the frame
    comp = brightest_composition(_polarized_stack(wall, p), _polarized_stack(wall, p))
    assert comp["top_clipped"] == 1.0 and comp["top_unpolarized"] == 1.0
    assert comp["top_rising"] == 0.0 and comp["top_rising_polarized"] == 0.0
    yy, xx = np.mgrid[0:h, 0:w]
    lobe = np.exp(-((yy - 48) ** 2 + (xx - 48) ** 2) / (2 * 4.0 ** 2))
    glossy = ic + 0.5 * lobe                            # a highlight rising to 0.85, unclipped
    pol = np.where(lobe > 0.05, 0.3 * lobe / (1 + 0.5 * lobe / 0.35), 0.0)   # its polarized part over the total
    stack = _polarized_stack(glossy, pol)
    comp = brightest_composition(stack, stack)
    assert comp["top_clipped"] == 0.0 and comp["top_unpolarized"] == 0.0
    assert comp["top_rising"] == 1.0 and comp["top_rising_polarized"] == 1.0
    # the same rise with no polarization: rising, but not a highlight's signs
    comp = brightest_composition(_polarized_stack(glossy, p), _polarized_stack(glossy, p))
    assert comp["top_rising"] == 1.0 and comp["top_unpolarized"] == 1.0 and comp["top_rising_polarized"] == 0.0


def test_invented_structure_is_zero_for_membranes_and_positive_for_facets():
    h = w = 48
    img = np.full((h, w), 0.6)
    img[8:40, 8:40] = 1.0              # all 12 samples clipped
    given = _grey_stack(img)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    as_measured = given.mean(axis=0)
    ramp = np.repeat((0.5 + 0.008 * xx)[..., None], 3, axis=-1)
    saddle = np.repeat((0.7 + 2e-4 * ((xx - 24) ** 2 - (yy - 24) ** 2))[..., None], 3, axis=-1)  # harmonic
    pyramid = np.repeat((1.0 - 0.02 * np.maximum(np.abs(xx - 24), np.abs(yy - 24)))[..., None], 3, axis=-1)
    for d in (as_measured, ramp, saddle):
        inv, share = invented_structure(d, given)
        assert inv < 1e-9 and share == pytest.approx(32 * 32 / (h * w))
    inv, _ = invented_structure(np.minimum(pyramid, as_measured), given)
    assert inv > 0.02
    # nothing clipped: nothing to judge
    assert np.isnan(invented_structure(as_measured, _grey_stack(np.full((h, w), 0.5)))[0])


def _data() -> Path:
    import os

    root = Path(os.environ.get("POLCAM_SHARED_DATA", Path(__file__).resolve().parents[2].parent / "shared" / "data"))
    if not (root / "real-color-stacks" / "jcpd-15").is_dir():
        pytest.skip("real stacks not found (../shared/data)")
    return root


def test_small_relit_run_and_the_cli(tmp_path, capsys):
    data = _data()
    scores = run(data, methods=["imin"], scenes=["jcpd-15"], scale=0.25, progress=False)
    assert [s.variant for s in scores] == list(VARIANTS)
    for s in scores:
        assert 0.8 < s.matte_kept <= 1.0 + 1e-9 and s.error is None
    over = {s.variant: s for s in scores}
    assert over["overexposed"].clipped_share > over["recorded"].clipped_share
    summ = summary(scores)["imin"]
    assert summ["matte_kept_min"] <= summ["matte_kept_min_mean"] <= 1
    assert main(["bench", "real", "--relit", "--data", str(data), "--methods", "imin", "--scenes", "jcpd-15",
                 "--scale", "0.25", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "relit.json").read_text())
    assert len(doc["rows"]) == 4 and doc["summary"]["imin"]["matte_kept_min"] == pytest.approx(summ["matte_kept_min"])
    out = capsys.readouterr().out
    assert "| jcpd-15 | tinted+overexposed | imin |" in out
    # the shared stack's brightest 1 % is its clipped white base: every variant says so
    assert all(s.top_clipped > 0.9 and s.top_rising_polarized < 0.05 for s in scores)
    assert "What the brightest 1 % holds" in out and doc["rows"][0]["top_clipped"] == pytest.approx(scores[0].top_clipped)
    assert main(["bench", "real", "--relit", "--data", str(data), "--exposure", "2", "--out", str(tmp_path)]) == 2


def test_invented_structure_leaves_out_regions_too_small_to_judge():
    img = np.full((40, 40), 0.6)
    img[5:11, 5:11] = 1.0              # 6 x 6: a 4 x 4 interior, under MIN_REGION
    given = _grey_stack(img)
    d = given.mean(axis=0).copy()
    d[7:9, 7:9] = 0.3                  # a pit inside it
    assert np.isnan(invented_structure(d, given)[0])
    img[20:30, 20:30] = 1.0            # 10 x 10: an 8 x 8 interior, judged
    given = _grey_stack(img)
    d = given.mean(axis=0).copy()
    d[24:26, 24:26] = 0.3
    inv, _ = invented_structure(d, given)
    # the region's edge is white all round, so its membrane is 1: the pit's depth over the interior's light
    assert inv == pytest.approx(4 * 0.7 / 64, rel=1e-6)
