"""polcam bench speed --maps: the routes it times compute the same maps (no timed assertions)."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.bench import maps
from polcam.demosaicing import mosaic_stack

pytest.importorskip("polanalyser")


@pytest.mark.parametrize("layout", ["imx250mzr", "imx250myr"])
def test_every_route_gives_the_planted_polarization(layout):
    # a uniform scene of DoLP 0.6, AoLP 30 degrees (colour: distinct R, G, B levels)
    t = np.deg2rad([0.0, 45.0, 90.0, 135.0])
    level = np.array([0.3, 0.5, 0.7]) if layout == "imx250myr" else np.array(0.5)
    ic = np.broadcast_to(level, (48, 64) + level.shape)
    stack = np.stack([ic * (1 + 0.6 * np.cos(2 * a - 2 * np.deg2rad(30.0))) for a in t])
    raw = np.round(mosaic_stack(stack, layout=layout) * 4095).astype(np.uint16)
    routes = maps.routes(layout)
    assert list(routes)[:2] == ["polanalyser", "polcam bilinear"] and len(routes) == 3
    inner = (slice(8, -8), slice(8, -8))
    for name, fn in routes.items():
        s0, dolp, aolp = (np.asarray(a, np.float64)[inner] for a in fn(raw))
        np.testing.assert_allclose(dolp, 0.6, atol=2e-3, err_msg=name)
        np.testing.assert_allclose(aolp, np.deg2rad(30.0), atol=2e-3, err_msg=name)
        scale = 1.0 if name == "polanalyser" else 65535.0  # polanalyser keeps counts ...
        if name == "polanalyser" and layout == "imx250myr":
            s0 = s0[..., ::-1]                              # ... in OpenCV's BGR order
        np.testing.assert_allclose(s0 * scale, 2 * ic[inner] * 4095, rtol=2e-3, err_msg=name)


def test_markdown_table_lists_every_row():
    rows = [maps.MapsRow("imx250mzr", "polanalyser", 1.0, 0.8, 1.0, 1.0),
            maps.MapsRow("imx250mzr", "polcam bilinear", 0.25, 0.3, 4.0, 8 / 3)]
    text = maps.format_markdown(rows)
    assert "| imx250mzr | polcam bilinear | 0.250 | 0.300 | 4.00 | 2.67 |" in text
    assert len(text.splitlines()) == 4
