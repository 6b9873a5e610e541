"""polcam bench stability: continuity and flicker, on real renders, with a method known to jump."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench.stability import format_markdown, perturbed, run
from polcam.errors import MethodError


def test_perturbation_leaves_clipped_samples_and_is_tiny():
    s = np.array([[0.2, 0.5], [0.98, 1.0]], np.float32)
    p = perturbed(np.broadcast_to(s, (4, 2, 2)), 3e-7, seed=0)
    assert p.dtype == np.float32 and p.shape == (4, 2, 2)
    np.testing.assert_array_equal(p[:, 1], np.broadcast_to(s[1], (4, 2)))   # the white level stays
    rel = np.abs(p[:, 0] / s[0] - 1)
    assert rel.max() < 3e-6 and rel.max() > 0


def test_a_method_without_switches_does_not_jump_and_one_with_a_switch_does():
    from polcam import separation

    @separation.register("test-rounding-switch", kind="single")
    def switch(image):
        # halves the pixels whose float32 value has an odd last bit: any change of the input flips it
        odd = (np.asarray(image, np.float32).view(np.int32) & 1).astype(bool)
        return np.where(odd, 0.5 * image, image)

    try:
        rows = run(scenes=["Bunny5"], methods=["imin", "test-rounding-switch"], size=32, frames=3)
    finally:
        separation.unregister("test-rounding-switch")
    imin, sw = rows
    assert (imin.scene, imin.method, sw.method) == ("Bunny5", "imin", "test-rounding-switch")
    assert imin.jump < 1e-5 and imin.jump_share == 0.0
    assert sw.jump > 0.05 and sw.jump_share > 0.1
    # noise differs between the frames: the layer varies, and imin's mean PSNR is a real score
    assert 0 < imin.flicker_p99 <= imin.flicker_max < 0.1 and 10 < imin.psnr < 60
    assert not imin.held and not sw.held
    md = format_markdown(rows)
    assert "| Bunny5 | imin |" in md and "| **mean** | test-rounding-switch |" in md


def test_held_illuminant_only_where_a_method_estimates_one():
    rows = run(scenes=["Tinted"], methods=["polarized-residual", "imin"], size=32, frames=2,
               hold_illuminant=True)
    pr, imin = rows
    assert pr.held and not imin.held
    per_frame = run(scenes=["Tinted"], methods=["polarized-residual"], size=32, frames=2)[0]
    assert not per_frame.held and per_frame.jump == pr.jump        # the continuity test is the same
    given = run(scenes=["Tinted"], methods=["polarized-residual"], size=32, frames=2, hold_illuminant=True,
                options={"polarized-residual": {"illuminant": [1.0, 0.75, 0.5]}})[0]
    assert not given.held


@pytest.mark.parametrize("kw, match", [({"frames": 1}, "frames=1"), ({"rel": 0.0}, "rel=0.0")])
def test_bad_settings(kw, match):
    with pytest.raises(MethodError, match=match):
        run(scenes=["Bunny5"], methods=["imin"], size=16, **kw)


def test_cli_writes_the_table(tmp_path, capsys):
    from polcam.cli import main

    out = tmp_path / "stab"
    assert main(["bench", "stability", "--scenes", "Bunny5", "--methods", "imin", "--size", "24", "--frames", "2",
                 "--mono", "--out", str(out)]) == 0
    assert "| Bunny5 | imin |" in capsys.readouterr().out
    assert (out / "table.md").read_text().startswith("| scene | method |")
    assert (out / "stability.csv").read_text().splitlines()[1].startswith("Bunny5,imin,")
