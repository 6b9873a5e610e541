"""The tensor methods' options: checks, defaults, the tile plan."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation.tensor.options import (
    AUTO_TILE,
    AUTO_UNTILED_PIXELS,
    DEFAULTS,
    EXACT_TOL,
    FAST_TOL,
    default_lam,
    resolve,
    tile_plan,
)
from polcam.separation.tensor.tiling import tile_spans


def test_tile_plan_keeps_the_exact_solver_whole_and_tiles_large_fast_runs():
    big = int(np.sqrt(AUTO_UNTILED_PIXELS)) + 1
    assert tile_plan(big, big, None, 4, "exact") == ((big, big), 0)
    (th, tw), ov = tile_plan(big, big, None, 4, "fast")
    assert ov == 4 and th <= AUTO_TILE[0] and tw <= AUTO_TILE[1]
    # the automatic tile is the smallest that needs no more tiles than AUTO_TILE does
    for got, most in ((th, AUTO_TILE[0]), (tw, AUTO_TILE[1])):
        assert len(tile_spans(big, got, 4)) == len(tile_spans(big, most, 4))
        assert len(tile_spans(big, got - 1, 4)) > len(tile_spans(big, most, 4))
    assert tile_plan(big - 1, big - 1, None, 4, "fast") == ((big - 1, big - 1), 0)
    assert tile_plan(big, big, 32, 4, "exact") == ((32, 32), 4)     # asked for: tiles
    assert tile_plan(big, big, (48, 16), 4, "fast") == ((48, 16), 4)
    assert tile_plan(20, big, (48, 16), 4, "fast") == ((20, 16), 4)  # one tile along the short side
    assert tile_plan(20, 30, (48, 32), 4, "fast") == ((20, 30), 0)   # the whole image
    for bad in [(48,), (48, 4), (48, 16, 2), "48", True, (48.0, 16)]:
        with pytest.raises(MethodError, match="tile"):
            tile_plan(big, big, bad, 4, "fast")
    with pytest.raises(MethodError, match="overlap"):
        tile_plan(big, big, (48, 16), 8, "fast")                     # half the narrow side


def test_resolve_fills_the_defaults_per_variant_and_solver():
    p = resolve((4, 40, 30, 3), "tensor", {})
    assert p.opt == DEFAULTS and p.tol == FAST_TOL and p.gamma == DEFAULTS["gamma"] and p.use_tau
    assert p.shared and p.one_tile and p.shape == (40, 30) and p.workers >= 1
    p = resolve((4, 40, 30, 3), "tensor-tau", {"solver": "exact"})
    assert p.tol == EXACT_TOL and p.gamma == 0.0 and p.use_tau and not p.shared
    p = resolve((4, 40, 30, 3), "tensor-plain", {"tile": 16, "overlap": 4, "workers": 3, "tol": 1e-3})
    assert not p.use_tau and p.gamma == 0.0 and p.tile == (16, 16) and p.overlap == 4 and not p.one_tile
    assert p.workers == 3 and p.tol == 1e-3


@pytest.mark.parametrize("bad,match", [({"solver": "magic"}, "solver"), ({"tile": 4}, "tile"),
                                       ({"tile": 16, "overlap": 8}, "overlap"),
                                       ({"workers": 0}, "workers"), ({"workers": True}, "workers"),
                                       ({"precision": "half"}, "precision"),
                                       ({"device": 3}, "device"),
                                       ({"device": "cpu", "solver": "exact"}, "fast solver"),
                                       ({"n5": 3}, "unknown option")])
def test_options_are_checked(bad, match):
    if "device" in bad and isinstance(bad["device"], str):
        pytest.importorskip("torch")
    with pytest.raises(MethodError, match=match):
        resolve((4, 8, 8, 3), "tensor", bad)


def test_default_lambda_is_trpcas():
    assert default_lam(None, 40, 30, 4) == pytest.approx(1 / np.sqrt(160))
    assert default_lam(0.2, 40, 30, 4) == 0.2
