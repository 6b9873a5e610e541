"""polcam process, items 8, 9 and 10: bad calibrations refused once before any work, a sidecar that
contradicts its image refused, symlink loops named, one-line errors for absurd headers, a memory
bound per frame, and an unreachable Dask scheduler refused within seconds."""

from __future__ import annotations

import json
import os
import shutil
import socket
import struct
import time
from pathlib import Path

import numpy as np

from tests.faults._process_helpers import check_accounted, check_consistent, make_frames, run, summary

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "raw"


def test_corrupt_or_wrong_size_calibration_is_refused_once_before_any_work(tmp_path):
    from polcam.calibration import calibrate_dark, save_calibration

    make_frames(tmp_path / "raw", 4)
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(os.urandom(2000))
    rng = np.random.default_rng(0)
    small = save_calibration(tmp_path / "dark32.npz",
                             calibrate_dark(rng.poisson(6.0, (4, 32, 32)).astype(np.uint16), layout="imx250myr"))
    for cal, want in ((corrupt, "not a NumPy .npz archive"), (small, "is for 32x32 frames")):
        out = tmp_path / f"out-{cal.stem}"
        code, ev, err = run(tmp_path / "raw", out, "--workers", "1", "--calibration", str(cal))
        assert code == 2, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and str(cal) in lines[0] and want in lines[0], err
        assert ev == [] and not out.exists()              # before any work: nothing created


def test_sidecar_that_contradicts_the_image_is_refused(tmp_path):
    """A 640x512 PNG whose sidecar says 2448x2048: that frame fails naming the file and both sizes;
    the others are processed and agree with their meta.json."""
    frames = make_frames(tmp_path / "raw", 2)
    shutil.copy(FIXTURES / "fruits_crop.png", tmp_path / "raw" / "wrong.png")
    (tmp_path / "raw" / "wrong.json").write_text(json.dumps({"layout": "imx250mzr", "width": 2448, "height": 2048}))
    out = tmp_path / "out"
    code, _, err = run(tmp_path / "raw", out, "--workers", "1", "--method", "imin")
    assert code == 1, err
    s = summary(out)
    by = check_accounted(out, [*frames, tmp_path / "raw" / "wrong.png"], s)
    assert by["failed"] == {"wrong.png"}
    msg = s["failed"][0]["error"]
    assert "wrong.png" in msg and "2448x2048" in msg and "640x512" in msg and "wrong.json" in msg
    assert sorted(check_consistent(out)) == ["f00", "f01"]


def _tiny_tiff(path: Path, w: int, h: int) -> int:
    """A 16-bit greyscale TIFF header declaring ``w`` x ``h`` with 4 bytes of pixel data."""
    entries = [(256, 4, w), (257, 4, h), (258, 3, 16), (259, 3, 1), (262, 3, 1), (273, 4, 138 - 4),
               (277, 3, 1), (278, 4, h), (279, 4, w * h * 2), (284, 3, 1)]
    ifd = struct.pack("<H", len(entries)) + b"".join(
        struct.pack("<HHII", tag, typ, 1, v) if typ == 4 else struct.pack("<HHIHH", tag, typ, 1, v, 0)
        for tag, typ, v in entries) + struct.pack("<I", 0)
    data = b"II*\x00" + struct.pack("<I", 8) + ifd + b"\x00" * 4
    path.write_bytes(data)
    return len(data)


def test_symlink_loop_absurd_header_and_memory_bound(tmp_path):
    raw = tmp_path / "raw"
    frames = make_frames(raw / "day1", 2, colour=False)
    os.symlink("..", raw / "day1" / "loop")                    # a loop under --recursive
    assert _tiny_tiff(raw / "tiny.tif", 11000, 11000) == 138
    out = tmp_path / "out"
    code, _, err = run(raw, out, "--recursive", "--workers", "1", "--method", "imin", "--layout", "imx250mzr",
                       "--max-memory", "0", child=True)
    assert code == 1, err
    assert f"note: {raw / 'day1' / 'loop'}: symbolic link loop: it leads back to {raw}; skipped" in err
    s = summary(out)
    by = check_accounted(out, [*frames, raw / "tiny.tif"], s)
    assert by["failed"] == {"tiny.tif"} and len(by["done"]) == 2
    msg = s["failed"][0]["error"]
    assert "\n" not in msg and len(msg) < 400 and "tiny.tif" in msg and "more lines like it" in msg
    assert sorted(check_consistent(out)) == ["day1/f00", "day1/f01"]

    # the same header under a memory bound: refused unread, with the limit and how to raise it
    pgm = tmp_path / "big" / "big.pgm"
    pgm.parent.mkdir()
    pgm.write_bytes(b"P5\n11000 11000\n255\n" + bytes(64))
    out2 = tmp_path / "out2"
    t0 = time.monotonic()
    code, _, err = run([pgm, *frames], out2, "--workers", "1", "--method", "imin", "--layout", "imx250mzr",
                       "--max-memory", "1G")
    assert code == 1 and time.monotonic() - t0 < 20, err
    s = summary(out2)
    check_accounted(out2, [pgm, *frames], s)
    msg = s["failed"][0]["error"]
    assert "big.pgm" in msg and "is 11000x11000" in msg and "limit of 1.0 GiB" in msg and "--max-memory" in msg


def test_unreachable_scheduler_fails_fast(tmp_path):
    make_frames(tmp_path / "raw", 1)
    with socket.socket() as s:                                 # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "out"
    t0 = time.monotonic()
    code, _, err = run(tmp_path / "raw", out, "--scheduler", f"tcp://127.0.0.1:{port}", "--scheduler-timeout", "1",
                       child=True)
    took = time.monotonic() - t0
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port} within 1 s" in lines[0]
    assert took < 15 and not out.exists()
