"""The Rerun web viewer as a person sees it: headless Chromium opens `polcam view --web` and a live
`polcam capture --rerun serve`, and the screenshots must hold the planted test frame's colours."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from polcam._browser import (
    BrowserUnavailable,
    colour_fraction,
    open_page,
    planted_scene,
    process_gone,
    serve,
    shows_planted,
    viewer_screenshot,
)
from polcam.cli import main

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


def test_colour_fraction_and_planted_colours():
    shot = np.zeros((10, 10, 3), np.uint8)
    shot[:2] = (230, 13, 230)
    shot[2:3] = (235, 20, 225)   # within 10 of it
    shot[3:4] = (200, 13, 230)   # not
    assert colour_fraction(shot, (230, 13, 230)) == pytest.approx(0.3)
    assert shows_planted(shot, {"a": (230, 13, 230)}, least=0.3)
    assert not shows_planted(shot, {"a": (230, 13, 230), "b": (0, 255, 0)})


def test_the_planted_frame_holds_what_it_says(tmp_path):
    from polcam.io import read_frame
    from polcam.sinks.rerun import palettes

    colours = planted_scene(tmp_path, count=2)
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["planted_00.png", "planted_01.png"]
    frame = read_frame(tmp_path / "planted_00.png")
    assert str(frame.layout) == "imx250myr" and frame.bit_depth == 12
    import polcam
    from polcam import polarimetry as st

    s = st.stokes(polcam.demosaic(frame, resolution="cell"))
    top, bottom = (slice(4, 28), slice(4, -4)), (slice(36, 60), slice(4, -4))
    np.testing.assert_allclose(s.s0[top].mean(axis=(0, 1)) / 2, (0.9, 0.05, 0.9), atol=2e-3)
    assert abs(st.dolp(s)[bottom].mean() - 0.5) < 2e-3 and st.dolp(s)[top].max() < 2e-3
    assert abs(np.rad2deg(st.aolp(s)[bottom]).mean() - 60.0) < 0.1
    assert colours["s0"] == (230, 13, 230) and colours["aolp"] == (0, 255, 0)
    assert colours["dolp"] == dict((c, rgb) for c, _, rgb in palettes()["dolp"])[128]


def _check(shot: np.ndarray, ok: bool, colours: dict[str, tuple[int, int, int]], out: Path) -> None:
    import cv2

    cv2.imwrite(str(out), shot[:, :, ::-1])  # kept in the test's folder for a look when it fails
    fractions = {k: round(colour_fraction(shot, rgb), 4) for k, rgb in colours.items()}
    assert ok, f"the viewer did not show the planted colours in time: {fractions} (screenshot {out})"
    assert shot.std() > 20 and len(np.unique(shot.reshape(-1, 3), axis=0)) > 50  # not blank
    # each planted colour fills a good part of its panel(s), not a few stray pixels
    assert all(f >= 0.01 for f in fractions.values()), fractions


@pytest.mark.browser
def test_view_web_shows_a_processed_folder(browser, tmp_path):
    colours = planted_scene(tmp_path / "raw")
    assert main(["process", str(tmp_path / "raw"), "-o", str(tmp_path / "out"), "--method", "imin",
                 "--workers", "1", "--quiet"]) == 0
    with serve(["view", str(tmp_path / "out"), "--web", "--port", "0"], env=_env()) as served:
        assert served.url.startswith("http://127.0.0.1:") and served.server_pids
        shot, ok = viewer_screenshot(served.url, accept=lambda s: shows_planted(s, colours), timeout=60, width=1200, height=700)
        _check(shot, ok, colours, tmp_path / "view.png")
    assert served.returncode == 0 and all(process_gone(p) for p in served.server_pids)


@pytest.mark.browser
def test_capture_serve_shows_the_live_frames_to_a_late_viewer(browser, tmp_path):
    colours = planted_scene(tmp_path / "replay", count=3)
    with serve(["capture", "--device", f"replay:{tmp_path / 'replay'}", "--loop", "--frame-rate", "5",
                "--duration", "120", "--no-save", "--separate", "imin", "--view-scale", "1", "--rerun", "serve",
                "--port", "0"], stream="stderr", env=_env()) as served:
        assert served.url.startswith("http://127.0.0.1:") and served.server_pids
        time.sleep(3)  # the viewer opens after the capture started: the server kept the recent frames
        shot, ok = viewer_screenshot(served.url, accept=lambda s: shows_planted(s, colours), timeout=60, width=1200, height=700)
        _check(shot, ok, colours, tmp_path / "capture.png")
        assert served.proc.poll() is None  # still capturing: this was the live view
    assert served.returncode == 0 and all(process_gone(p) for p in served.server_pids)


def _other_address() -> str | None:
    """A non-loopback IPv4 address of this machine (``hostname -I``), or None."""
    import ipaddress
    import subprocess

    try:
        out = subprocess.run(["hostname", "-I"], capture_output=True, text=True, timeout=5).stdout.split()
    except (OSError, subprocess.TimeoutExpired):
        return None
    for a in out:
        try:
            ip = ipaddress.ip_address(a)
        except ValueError:
            continue
        if ip.version == 4 and not ip.is_loopback:
            return a
    return None


@pytest.mark.browser
def test_view_web_shows_an_rrd_recording_to_another_machine(browser, tmp_path):
    # the recording `polcam process --rerun` wrote, served from the file (with the blueprint in it)
    # on every interface and opened through this machine's network address, as a browser on another
    # machine would (the page's origin is then not localhost: the data server must allow it)
    colours = planted_scene(tmp_path / "raw")
    rrd = tmp_path / "run.rrd"
    assert main(["process", str(tmp_path / "raw"), "-o", str(tmp_path / "out"), "--method", "imin",
                 "--workers", "1", "--quiet", "--rerun", str(rrd)]) == 0
    import socket

    addr = _other_address()
    with serve(["view", str(rrd), "--web", "--port", "0", "--bind", "0.0.0.0"], env=_env()) as served:
        host = socket.gethostname()
        assert f"http://{host}:" in served.url
        url = served.url.replace(host, addr) if addr else served.url.replace(host, "127.0.0.1")
        shot, ok = viewer_screenshot(url, accept=lambda s: shows_planted(s, colours), timeout=60, width=1200, height=700)
        _check(shot, ok, colours, tmp_path / "rrd.png")
    assert served.returncode == 0 and all(process_gone(p) for p in served.server_pids)


@pytest.mark.browser
def test_view_web_shows_a_demo_output_folder(browser, tmp_path):
    # the first thing a user tries after `polcam demo`: `polcam view demo-output --web`
    import subprocess
    import sys

    colours = planted_scene(tmp_path / "raw")
    r = subprocess.run([sys.executable, "-m", "polcam", "demo", "--input", str(tmp_path / "raw"), "--out",
                        str(tmp_path / "demo-output"), "--separate", "imin"], capture_output=True, text=True,
                       env=_env(), timeout=300)
    assert r.returncode == 0, r.stderr
    with serve(["view", str(tmp_path / "demo-output"), "--web", "--port", "0"], env=_env()) as served:
        assert served.url.startswith("http://127.0.0.1:") and served.server_pids
        shot, ok = viewer_screenshot(served.url, accept=lambda s: shows_planted(s, colours), timeout=60, width=1200, height=700)
        _check(shot, ok, colours, tmp_path / "demo.png")
    assert served.returncode == 0 and all(process_gone(p) for p in served.server_pids)
