"""Adding a separation method, done once: a toy ``halve`` method (diffuse = I / 2).

Registered from a script (:func:`polcam.separation.register`), it runs through
:func:`polcam.separate` and through ``polcam process`` in the same process
(``polcam.commands.main``, one worker: a registration reaches only its own
process).  Installed as a plugin (a ``polcam.separation`` entry point, as a
distribution's ``pyproject.toml`` declares it), it runs through ``polcam process``
as a command, with worker processes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import polcam
from polcam.errors import MethodError
from polcam.separation import register, resolve_separation, unregister

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / "fixtures" / "raw"                 # a mono (fruits_crop) and a colour (synthetic_bunny5) frame
FRAMES = ("fruits_crop", "synthetic_bunny5")


def halve(image: np.ndarray) -> np.ndarray:
    """The toy method: half of each pixel is diffuse."""
    return image / 2


def _expected_diffuse(name: str) -> np.ndarray:
    """What ``halve`` must give for a fixture frame at cell resolution: half the mean over the angles
    of the default-demosaiced stack clipped to [0, 1]."""
    stack = polcam.demosaic(polcam.read_frame(RAW / f"{name}.png"), resolution="cell")
    return (np.clip(stack.astype(np.float64), 0, 1).mean(axis=0) / 2).astype(np.float32)


def _check_outputs(out: Path) -> None:
    for name in FRAMES:
        meta = json.loads((out / name / "meta.json").read_text())
        assert meta["method"] == "halve" and meta["method_options"] == {}
        diffuse, _ = polcam.read_image(out / name / "diffuse.exr")
        np.testing.assert_array_equal(diffuse, _expected_diffuse(name))


@pytest.fixture
def registered_halve():
    register("halve", kind="single", mono=True, reference="a test's toy method")(halve)
    try:
        yield
    finally:
        unregister("halve")
    assert "halve" not in polcam.METHODS


def test_a_registered_method_runs_through_separate(registered_halve):
    assert "halve" in polcam.METHODS
    rng = np.random.default_rng(1)
    stack = rng.uniform(-0.1, 1.1, (4, 6, 5, 3))
    res = polcam.separate(stack, method="halve")
    half = np.clip(stack, 0, 1).mean(axis=0) / 2
    np.testing.assert_array_equal(res.diffuse, half.astype(np.float32))
    np.testing.assert_array_equal(res.specular, res.diffuse)     # halving is exact
    assert res.info["method"] == "halve"
    resolved = resolve_separation("halve", "mono-stack")          # resolved once, then run as it is
    mono = rng.uniform(0, 1, (4, 6, 5))
    np.testing.assert_array_equal(polcam.separate(mono, method=resolved).diffuse,
                                  (mono.mean(axis=0) / 2).astype(np.float32))
    with pytest.raises(MethodError, match="takes no option 'gain'"):
        polcam.separate(stack, method="halve", gain=2)


def test_a_registered_method_runs_through_polcam_process_in_process(registered_halve, tmp_path, capsys):
    from polcam.commands import main

    out = tmp_path / "out"
    assert main(["process", str(RAW), "-o", str(out), "--method", "halve", "--workers", "1", "--quiet"]) == 0
    _check_outputs(out)
    unregister("halve")
    try:
        assert main(["process", str(RAW), "-o", str(tmp_path / "again"), "--method", "halve", "--quiet"]) == 2
        assert "separation method 'halve' is unknown" in capsys.readouterr().err
    finally:
        register("halve", kind="single", mono=True)(halve)


def _install_plugin(site: Path) -> None:
    """A distribution with a ``polcam.separation`` entry point, as pip installs it (module + dist-info)."""
    (site / "polcam_toy_halve.py").write_text(textwrap.dedent('''
        from polcam.separation import register


        @register("halve", kind="single", mono=True, reference="a plugin's toy method")
        def halve(image):
            return image / 2
    '''))
    info = site / "polcam_toy_halve-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: polcam-toy-halve\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[polcam.separation]\nhalve = polcam_toy_halve\n")


def test_an_installed_plugin_runs_through_the_polcam_process_command(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    _install_plugin(site)
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)])}
    r = subprocess.run([sys.executable, "-m", "polcam", "process", str(RAW), "-o", str(out),
                        "--method", "halve", "--workers", "2", "--quiet"],   # two worker processes
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    _check_outputs(out)
    # without the plugin on the path the name is unknown, and the run is refused before any work
    r = subprocess.run([sys.executable, "-m", "polcam", "process", str(RAW), "-o", str(tmp_path / "none"),
                        "--method", "halve"], env={**os.environ, "PYTHONPATH": str(REPO)},
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "separation method 'halve' is unknown" in r.stderr
    assert not (tmp_path / "none").exists()
