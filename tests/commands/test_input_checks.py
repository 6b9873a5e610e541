"""What a new user runs into, run as a user runs it (``python -m polcam ...`` in a subprocess).

Each test is one item of the new-user review: bad input is checked up front (exit 2, nothing
created), messages name the flag and the file, re-running the demo works, float TIFFs open
with tifffile as installed, and declared frame sizes are bounded before any allocation.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from polcam.separation import default_method

REPO = Path(__file__).resolve().parents[2]


def polcam(*args: str | Path, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "polcam", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def plain(tmp_path) -> Path:
    """Two plain 8-bit PNG mosaics without sidecars (a mono sensor's frames, layout unknown)."""
    import cv2

    d = tmp_path / "plain"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        cv2.imwrite(str(d / f"f{i}.png"), rng.integers(0, 256, (32, 48), dtype=np.uint8))
    return d


def test_demo_runs_twice_into_the_same_folder(tmp_path):
    out = tmp_path / "demo"
    first = polcam("demo", "--out", out)
    assert first.returncode == 0, first.stderr
    second = polcam("demo", "--out", out)
    assert second.returncode == 0, second.stderr
    assert "reusing the 2 frame(s)" in second.stdout
    assert "--append" not in second.stdout + second.stderr
    assert json.loads((out / "layers" / "summary.json").read_text())["skipped"] == 2   # up to date
    assert len(list((out / "capture").glob("frame_*.json"))) == 2                       # nothing added


def test_replay_capture_of_plain_frames(plain, tmp_path):
    # without a layout the frames are saved as sent (no live layers), saying how to get them
    r = polcam("capture", "--device", f"replay:{plain}", "--frames", "2", "--out", tmp_path / "c0")
    assert r.returncode == 0, r.stderr
    assert "layout unknown" in r.stderr and "--layout" in r.stderr and "None" not in r.stdout
    assert len(list((tmp_path / "c0").glob("frame_*.json"))) == 2
    summary = json.loads((tmp_path / "c0" / "summary.json").read_text())
    assert summary["frames_saved"] == 2 and summary["separation"] is None
    # a live view asked for explicitly needs the layout now: refused, nothing created
    r = polcam("capture", "--device", f"replay:{plain}", "--frames", "2", "--out", tmp_path / "c1",
               "--separate", "imin")
    assert r.returncode == 2 and "--layout" in r.stderr and "None" not in r.stdout
    assert not (tmp_path / "c1").exists()
    r = polcam("capture", "--device", f"replay:{plain}", "--frames", "2", "--out", tmp_path / "c2",
               "--layout", "imx250mzr")
    assert r.returncode == 0, r.stderr
    assert "layout imx250mzr" in r.stdout and "None" not in r.stdout
    assert len(list((tmp_path / "c2").glob("frame_*.json"))) == 2


def test_stokes_without_layout_names_the_file_and_the_flag(plain, tmp_path):
    r = polcam("stokes", plain, "-o", tmp_path / "s")
    assert r.returncode == 1
    assert f"{plain / 'f0.png'}: no layout" in r.stderr and "give --layout" in r.stderr
    assert "layout=" not in r.stderr
    p = polcam("process", plain, "-o", tmp_path / "p", "--quiet")
    assert p.returncode == 1 and f"{plain / 'f0.png'}: no layout" in p.stderr and "give --layout" in p.stderr


@pytest.mark.parametrize("command", ["stokes", "process"])
@pytest.mark.parametrize("flag, value", [("--layout", "imx999"), ("--demosaic", "nosuch"),
                                         ("--format", "png"), ("--resolution", "half")])
def test_bad_values_are_refused_up_front(plain, tmp_path, command, flag, value):
    out = tmp_path / "out"
    r = polcam(command, plain, "-o", out, flag, value)
    assert r.returncode == 2 and flag in r.stderr and value in r.stderr
    assert sum("error" in line for line in r.stderr.splitlines()) == 1   # once, not once per frame
    assert not out.exists()


@pytest.mark.parametrize("command", ["stokes", "process"])
def test_missing_input_is_exit_2_with_nothing_created(tmp_path, command):
    out = tmp_path / "out"
    r = polcam(command, tmp_path / "nowhere", "-o", out)
    assert r.returncode == 2 and "nowhere: no such file or folder" in r.stderr
    assert not out.exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    r = polcam(command, empty, "-o", out)
    assert r.returncode == 2 and "no raw frames found" in r.stderr and not out.exists()


def test_options_are_checked_against_the_methods_that_run(plain, tmp_path):
    out = tmp_path / "out"
    # mono frames run the mono default, which takes no max_iter: refused, not silently dropped
    mono = default_method("mono-stack")
    r = polcam("process", plain, "-o", out, "--layout", "imx250mzr", "--option", "max_iter=5")
    assert r.returncode == 2 and f"no method of this run ({mono} for mono frames) takes it" in r.stderr
    r = polcam("process", plain, "-o", out, "--layout", "imx250mzr", "--option", "bogus=1")
    assert r.returncode == 2 and f"'{mono}' takes no option 'bogus'" in r.stderr
    if default_method("stack") != mono:      # the colour default does not run on mono frames
        assert f"'{default_method('stack')}'" not in r.stderr
    assert not out.exists()


def test_colour_method_on_a_mono_layout_is_refused_up_front(plain, tmp_path):
    out = tmp_path / "out"
    r = polcam("process", plain, "-o", out, "--layout", "imx250mzr", "--method", "tensor")
    assert r.returncode == 2 and "needs colour frames" in r.stderr and "imin" in r.stderr
    assert not out.exists()


def test_unknown_vendor_is_named_with_the_known_ones():
    r = polcam("formats", "--vendor", "nosuchvendor")
    assert r.returncode == 2 and "nosuchvendor" in r.stderr and "FLIR" in r.stderr
    ok = polcam("formats", "--vendor", "flir")
    assert ok.returncode == 0 and "Polarized8" in ok.stdout


def test_float_tiffs_open_with_tifffile_as_installed(plain, tmp_path):
    import tifffile

    out = tmp_path / "s"
    r = polcam("stokes", plain, "-o", out, "--layout", "imx250mzr", "--format", "tiff")
    assert r.returncode == 0, r.stderr
    dolp = tifffile.imread(out / "f0" / "dolp.tif")
    s0 = tifffile.imread(out / "f0" / "s0.tif")
    assert dolp.dtype == np.float32 and dolp.shape == (32, 48)
    assert 0 <= dolp.min() and dolp.max() <= 1 and s0.max() > 0
    import cv2

    assert cv2.imread(str(out / "f0" / "dolp.tif"), cv2.IMREAD_UNCHANGED).dtype == np.float32


def _huge_tiff(path: Path, w: int, h: int) -> None:
    """A TIFF whose header declares w x h 16-bit pixels, holding 64 bytes of data."""
    entries = [(256, 4, w), (257, 4, h), (258, 3, 16), (259, 3, 1), (262, 3, 1), (273, 4, 0),
               (277, 3, 1), (278, 4, h), (279, 4, 64)]
    data_off = 8 + 2 + 12 * len(entries) + 4
    out = b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", len(entries))
    for tag, typ, val in entries:
        val = data_off if tag == 273 else val
        out += struct.pack("<HHIHH", tag, typ, 1, val, 0) if typ == 3 else struct.pack("<HHII", tag, typ, 1, val)
    path.write_bytes(out + struct.pack("<I", 0) + b"\0" * 64)


def test_declared_sizes_are_bounded_before_reading(plain, tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    _huge_tiff(bad / "huge.tif", 60000, 60000)
    (bad / "dump.raw").write_bytes(b"\0" * 64)
    (bad / "dump.json").write_text(json.dumps({"width": 200000, "height": 200000, "layout": "imx250mzr"}))
    r = polcam("stokes", bad, "-o", tmp_path / "s", "--layout", "imx250mzr")
    assert r.returncode == 1
    assert "huge.tif" in r.stderr and "dump.raw" in r.stderr
    assert "200000x200000" in r.stderr and "--max-pixels" in r.stderr
    # the limit is a flag: 32 x 48 frames refused under a limit of 1000 pixels, read under the default
    low = polcam("stokes", plain, "-o", tmp_path / "low", "--layout", "imx250mzr", "--max-pixels", "1000")
    assert low.returncode == 1 and "32 = 1536 pixels, more than the limit of 1000" in low.stderr
    ok = polcam("stokes", plain, "-o", tmp_path / "ok", "--layout", "imx250mzr", "--max-pixels", "2000")
    assert ok.returncode == 0, ok.stderr
