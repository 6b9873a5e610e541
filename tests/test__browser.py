"""The Rerun web viewer as a person sees it: headless Chromium opens `polcam view --web` and a live
`polcam capture --rerun serve`, and the screenshots must hold the planted test frame's colours."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from polcam._browser import (
    BrowserUnavailable,
    colour_fraction,
    open_page,
    planted_scene,
    shows_planted,
    viewer_screenshot,
)
from polcam.cli import main

pytestmark = pytest.mark.browser
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def browser() -> None:
    """Skips (saying why) where headless Chromium cannot start here."""
    try:
        with open_page("about:blank", width=320, height=200, start_timeout=30) as page:
            page.screenshot()
    except BrowserUnavailable as exc:
        pytest.skip(f"no headless browser: {exc}")


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _url(stream, proc: subprocess.Popen[str], timeout: float = 60.0) -> str:
    end = time.monotonic() + timeout
    seen = []
    while time.monotonic() < end:
        line = stream.readline()
        if not line:
            break
        seen.append(line)
        m = re.search(r"Rerun web viewer: open (http://\S+)", line)
        if m:
            return m.group(1)
    raise AssertionError(f"no URL printed (exit {proc.poll()}): {''.join(seen)[-2000:]}")


def _children(pid: int) -> list[int]:
    kids = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                if int(Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    kids.append(int(d))
            except OSError:
                pass
    return kids


def _check(shot: np.ndarray, ok: bool, colours: dict[str, tuple[int, int, int]], out: Path) -> None:
    import cv2

    cv2.imwrite(str(out), shot[:, :, ::-1])  # kept in the test's folder for a look when it fails
    fractions = {k: round(colour_fraction(shot, rgb), 4) for k, rgb in colours.items()}
    assert ok, f"the viewer did not show the planted colours in time: {fractions} (screenshot {out})"
    assert shot.std() > 20 and len(np.unique(shot.reshape(-1, 3), axis=0)) > 50  # not blank
    # each planted colour fills a good part of its panel(s), not a few stray pixels
    assert all(f >= 0.01 for f in fractions.values()), fractions


def test_view_web_shows_a_processed_folder(browser, tmp_path):
    colours = planted_scene(tmp_path / "raw")
    assert main(["process", str(tmp_path / "raw"), "-o", str(tmp_path / "out"), "--method", "imin",
                 "--workers", "1", "--quiet"]) == 0
    proc = subprocess.Popen([sys.executable, "-m", "polcam.cli", "view", str(tmp_path / "out"), "--web",
                             "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    try:
        url = _url(proc.stdout, proc)
        assert url.startswith("http://127.0.0.1:")
        shot, ok = viewer_screenshot(url, accept=lambda s: shows_planted(s, colours), timeout=60)
        _check(shot, ok, colours, tmp_path / "view.png")
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
        proc.stdout.close()
        proc.stderr.close()
    assert proc.returncode == 0


def test_capture_serve_shows_the_live_frames_to_a_late_viewer(browser, tmp_path):
    colours = planted_scene(tmp_path / "replay", count=3)
    proc = subprocess.Popen(
        [sys.executable, "-m", "polcam.cli", "capture", "--device", f"replay:{tmp_path / 'replay'}", "--loop",
         "--frame-rate", "5", "--duration", "120", "--no-save", "--separate", "imin", "--view-scale", "1",
         "--rerun", "serve", "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    try:
        url = _url(proc.stderr, proc)
        kids = _children(proc.pid)
        assert url.startswith("http://127.0.0.1:") and kids
        time.sleep(3)  # the viewer opens after the capture started: the server kept the recent frames
        shot, ok = viewer_screenshot(url, accept=lambda s: shows_planted(s, colours), timeout=60)
        _check(shot, ok, colours, tmp_path / "capture.png")
        assert proc.poll() is None  # still capturing: this was the live view
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        finally:
            proc.stdout.close()
            proc.stderr.close()
    assert proc.returncode == 0
    for k in kids:
        assert not Path(f"/proc/{k}").exists() or "Z" in Path(f"/proc/{k}/stat").read_text().rsplit(")", 1)[1][:3]
