"""Per-frame peak memory and the worker count the machine's memory allows."""

from __future__ import annotations

import json
import shutil

import pytest

from polcam import _memory
from polcam.cli import main

_PEAK = """
import numpy as np
from polcam import _memory
_memory.reset_peak()
before = _memory.peak_rss_mb()
big = np.ones(200 * 2**20 // 8)  # 200 MB, every page touched
during = _memory.peak_rss_mb()
del big
print(before, during, _memory.reset_peak(), _memory.peak_rss_mb())
"""


def test_peak_follows_an_allocation_and_resets():
    # in a fresh interpreter: this one's allocator may hold freed memory (a command run in-process
    # calls polcam.parallel.hold_freed_memory), and a new array would then not raise the peak
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _PEAK], capture_output=True, text=True, timeout=60,
                         check=True).stdout.split()
    before, during, reset, after = float(out[0]), float(out[1]), out[2] == "True", float(out[3])
    assert during - before > 180
    if not reset:
        pytest.skip("this kernel does not let a process reset its peak RSS")
    assert after < during - 150  # the released array is no longer in the peak


@pytest.mark.parametrize("available,per,cores,want", [
    (10000.0, 1000.0, 2, 2),    # plenty of memory: the cores
    (2000.0, 1000.0, 8, 1),     # 80 % of 2000 MB holds one 1000 MB worker
    (4000.0, 1000.0, 8, 3),     # ... and three of them in 4000 MB
    (100.0, 1000.0, 8, 1),      # never fewer than one
])
def test_workers_for_memory(available, per, cores, want):
    assert _memory.workers_for_memory(per, cores, available=available) == want


def test_available_memory_is_read():
    avail = _memory.available_mb()
    assert avail is None or avail > 0


def test_auto_workers_scale_with_the_method_and_resolution(monkeypatch):
    monkeypatch.setitem(_memory.METHOD_PEAK_MB, "imin", 500.0)
    assert _memory.auto_workers("imin", "cell", 16, available=2000.0) == 3    # 1600 / 500
    assert _memory.auto_workers("imin", "full", 16, available=2000.0) == 1    # 4x the pixels
    assert _memory.worker_peak_mb("imin", 2448 * 2048 // 4) == 500.0          # never below the 5 MP figure


def test_process_reports_each_frames_peak_and_the_max(tmp_path, fixtures_dir):
    raw = tmp_path / "raw"
    raw.mkdir()
    for stem in ("fruits_crop", "synthetic_bunny5"):
        for ext in (".png", ".json"):
            shutil.copy(fixtures_dir / "raw" / f"{stem}{ext}", raw / f"{stem}{ext}")
    out = tmp_path / "out"
    assert main(["process", str(raw), "-o", str(out), "--quiet", "--workers", "1", "--method", "imin"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    peaks = [r["peak_rss_mb"] for r in summary["results"]]
    assert len(peaks) == 2 and all(p > 50 for p in peaks)   # an interpreter with numpy is tens of MB
    assert summary["peak_rss_mb"] == max(peaks)
