"""The polcam command line, end to end on real files."""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from polcam import __version__
from polcam.cli import build_parser, main
from polcam.io import read_image

COMMANDS = ["process", "stokes", "capture", "calibrate", "demo", "devices", "formats", "render", "bench", "view"]


def test_every_command_has_help(capsys):
    for cmd in [None, *COMMANDS]:
        with pytest.raises(SystemExit) as exit_:
            main(["--help"] if cmd is None else [cmd, "--help"])
        assert exit_.value.code == 0
        out = capsys.readouterr().out
        assert "usage: polcam" in out
    subparsers = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    assert sorted(subparsers) == sorted(COMMANDS)


def test_version_and_module_entry_point():
    proc = subprocess.run([sys.executable, "-m", "polcam", "--version"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == f"polcam {__version__}"


def test_stokes_on_the_fixture_and_a_bad_file(tmp_path, fixtures_dir, capsys):
    src = tmp_path / "raw"
    src.mkdir()
    for f in ("fruits_crop.png", "fruits_crop.json"):
        shutil.copy(fixtures_dir / "raw" / f, src / f)
    (src / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    out = tmp_path / "out"
    code = main(["stokes", str(src), "-o", str(out), "--format", "tiff"])
    captured = capsys.readouterr()
    assert code == 1                                   # one file failed ...
    assert "broken.png" in captured.err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["done"] == 1 and summary["failed"][0]["input"].endswith("broken.png")
    d = out / "fruits_crop"                            # ... and the good one is complete
    for name in ("i000", "i045", "i090", "i135", "s0", "s1", "s2", "dolp", "aolp", "residual"):
        assert (d / f"{name}.tif").is_file(), name
    dolp, meta = read_image(d / "dolp.tif")
    aolp, _ = read_image(d / "aolp.tif")
    s0, _ = read_image(d / "s0.tif")
    assert dolp.shape[:2] == (512, 640)
    assert 0 <= dolp.min() and dolp.max() <= 1 and 0 <= aolp.min() and aolp.max() < np.pi
    assert meta["layout"] == "imx250mzr" and meta["product"] == "dolp"
    i = [read_image(d / f"i{a:03d}.tif")[0] for a in (0, 45, 90, 135)]
    np.testing.assert_allclose(s0, (i[0] + i[1] + i[2] + i[3]) / 2, atol=1e-5)
    from polcam.demosaicing import default_method

    assert json.loads((d / "meta.json").read_text())["demosaic"] == default_method("imx250mzr")


def test_stokes_tiff16_keeps_signed_maps_float(tmp_path, fixtures_dir):
    out = tmp_path / "o"
    assert main(["stokes", str(fixtures_dir / "raw" / "fruits_crop.png"), "-o", str(out),
                 "--format", "tiff16", "--resolution", "cell", "--quiet"]) == 0
    i0, _ = read_image(out / "fruits_crop" / "i000.tif")
    s1, _ = read_image(out / "fruits_crop" / "s1.tif")
    assert i0.shape[:2] == (256, 320)
    assert np.allclose(i0 * 65535, np.round(i0 * 65535), atol=1e-3)  # quantised to 16 bits
    assert s1.min() < 0                                               # signed map kept as float


def test_stokes_without_inputs(tmp_path, capsys):
    assert main(["stokes", str(tmp_path), "-o", str(tmp_path / "o")]) == 2
    assert "no raw frames" in capsys.readouterr().err


def test_missing_layout_is_reported(tmp_path, capsys):
    raw = tmp_path / "m.npy"
    np.save(raw, np.zeros((8, 8), np.uint16))
    assert main(["stokes", str(raw), "-o", str(tmp_path / "o")]) == 1
    assert "layout" in capsys.readouterr().err


def test_demo_runs_on_the_bundled_fixtures(tmp_path, capsys):
    # the tensor method on the colour fixture takes seconds: the test uses imin for both frames
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--separate", "imin"]) == 0
    assert "demo done: 2 frame(s)" in capsys.readouterr().out
    assert sorted(p.name for p in (out / "capture").glob("*.raw")) == ["frame_000000.raw", "frame_000001.raw"]
    for stem, shape in (("frame_000000", (256, 320)), ("frame_000001", (128, 128, 3))):
        assert (out / "stokes" / stem / "dolp.exr").is_file()
        d, meta = read_image(out / "layers" / stem / "diffuse.exr")
        s, _ = read_image(out / "layers" / stem / "specular.exr")
        assert d.shape[:2] == shape[:2] and meta["method"] == "imin"
        assert np.all(d >= 0) and np.all(s >= -1e-6)
    from rerun.chunk import RrdReader

    entities = {str(c.entity_path) for c in RrdReader(str(out / "demo.rrd")).stream().to_chunks()}
    assert {"/layers/diffuse", "/layers/specular", "/polarization/dolp"} <= entities


def test_formats_lists_vendor_formats(capsys):
    assert main(["formats", "--vendor", "The Imaging Source"]) == 0
    out = capsys.readouterr().out
    assert "PolarizedBayerBG8" in out and "BGGR" in out and "PolarizeMono8" not in out


def test_devices_fake_json(capsys):
    from polcam.camera import aravis_available

    if not aravis_available():
        pytest.skip("Aravis not installed")
    assert main(["devices", "--fake", "--json"]) == 0
    devices = json.loads(capsys.readouterr().out)
    assert any(d["id"] == "Fake_1" for d in devices)


def test_fixture_folder_exists():
    assert (Path(__file__).resolve().parents[1] / "fixtures" / "raw" / "fruits_crop.png").is_file()


@pytest.mark.parametrize("page", ["cli", "cli-bench"])
def test_docs_cli_md_is_up_to_date(page):
    """docs/reference/cli.md and cli-bench.md document every command and flag: the parsers' own help."""
    from polcam.cli import reference_markdown

    doc = Path(__file__).resolve().parents[1] / "docs" / "reference" / f"{page}.md"
    assert doc.read_text() == reference_markdown(page), \
        f"regenerate: python -m polcam.cli --markdown {page} > docs/reference/{page}.md"


def test_the_cli_pages_hold_every_command_once():
    """Every command's and sub-command's help is on exactly one reference page."""
    from polcam.cli import reference_markdown
    from polcam.commands import build_parser

    pages = "".join(reference_markdown(p) for p in ("cli", "cli-bench"))
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name in sub.choices:
        assert pages.count(f"\n## polcam {name}\n") == 1, name
    assert "\n### polcam bench speed\n" in reference_markdown("cli-bench")
    assert "polcam bench speed" not in reference_markdown("cli").split("cli-bench.md")[1]
    with pytest.raises(ValueError, match="cli-nothing"):
        reference_markdown("cli-nothing")
