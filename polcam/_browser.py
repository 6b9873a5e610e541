"""Headless Chromium driven over the DevTools protocol: open a page, wait, take a screenshot.

Used by the browser tests of the Rerun web viewer and by the screenshots in
``docs/img/`` (:func:`polcam.viewer.doc_screenshots`), so what the docs show is
what the tests check.  Needs Debian's ``chromium`` and the ``websocket-client``
package (the ``dev`` extra); :func:`find_chromium` says why when there is none.

The browser runs with a fresh profile in a temporary folder, no GPU (WebGL
through Chromium's software rasterizer, SwiftShader), no network services of
its own, and is killed with its process group when the page is done.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from polcam.frame import Frame
from polcam.io import write_frame
from polcam.mosaic import parse_layout
from polcam.sinks.rerun import dolp_ids, palettes
from polcam.synth.patterns import stack_from_stokes
from polcam.synth.render import mosaic

__all__ = ["PLANTED", "BrowserUnavailable", "Page", "Served", "child_pids", "colour_fraction", "doc_screenshots",
           "find_chromium", "open_page", "planted_scene", "process_gone", "serve", "shows_planted",
           "viewer_screenshot"]

_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class BrowserUnavailable(RuntimeError):
    """No headless Chromium can be started here (the message says why)."""


def find_chromium() -> str:
    """Path of a Chromium executable.

    Raises
    ------
    BrowserUnavailable
        None on the PATH (install Debian's ``chromium``), or no ``websocket-client``.
    """
    try:
        import websocket  # noqa: F401
    except ImportError:
        raise BrowserUnavailable("the websocket-client package is not installed (pip install 'polcam[dev]')") from None
    for name in _NAMES:
        path = shutil.which(name)
        if path:
            return path
    raise BrowserUnavailable("no chromium on the PATH (apt-get install chromium)")


class Page:
    """One browser tab, driven over its DevTools websocket.

    Use :func:`open_page`, which starts the browser and closes everything on exit.
    """

    def __init__(self, ws: Any) -> None:
        self._ws = ws
        self._next = 0

    def call(self, method: str, timeout: float = 30.0, **params: Any) -> dict[str, Any]:
        """Send one DevTools command and return its result (events in between are dropped)."""
        self._next += 1
        ident = self._next
        self._ws.settimeout(timeout)
        self._ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        while True:
            msg = json.loads(self._ws.recv())
            if msg.get("id") == ident:
                if "error" in msg:
                    raise RuntimeError(f"DevTools {method}: {msg['error']}")
                return msg.get("result", {})

    def screenshot(self) -> np.ndarray:
        """The page as it is now: uint8 RGB (H, W, 3)."""
        import cv2

        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        return np.ascontiguousarray(bgr[:, :, ::-1])

    def wait_for(self, accept: Callable[[np.ndarray], bool], *, timeout: float = 60.0,
                 every: float = 1.0) -> tuple[np.ndarray, bool]:
        """Take screenshots until ``accept(shot)`` or the timeout; (last shot, accepted)."""
        end = time.monotonic() + timeout
        while True:
            try:
                shot = self.screenshot()
            # RuntimeError: the page is still being swapped in by the first navigation; a timeout:
            # the renderer is too busy to answer in time (a loaded machine drawing in software)
            except (RuntimeError, TimeoutError, _ws_timeout()):
                if time.monotonic() > end:
                    raise
                time.sleep(every)
                continue
            if accept(shot):
                return shot, True
            if time.monotonic() > end:
                return shot, False
            time.sleep(every)


def _ws_timeout() -> type[Exception]:
    """websocket-client's timeout exception."""
    import websocket

    return websocket.WebSocketTimeoutException


class open_page:  # noqa: N801 - a context manager used like a function
    """Start headless Chromium on ``url``; ``with open_page(url) as page: ...``.

    Parameters
    ----------
    url
        The page to open.
    width, height
        Window size in CSS pixels (the screenshot's size).
    start_timeout
        Seconds to wait for the browser's DevTools endpoint.
    """

    def __init__(self, url: str, *, width: int = 1600, height: int = 900, start_timeout: float = 30.0) -> None:
        self.url = url
        self.size = (int(width), int(height))
        self.start_timeout = float(start_timeout)
        self._proc: subprocess.Popen[bytes] | None = None
        self._profile: str | None = None
        self._ws: Any = None

    def __enter__(self) -> Page:
        import websocket

        exe = find_chromium()
        self._profile = tempfile.mkdtemp(prefix="polcam-chromium-")
        args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                "--use-angle=swiftshader", "--disable-quic", "--no-first-run", "--no-default-browser-check",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-extensions", "--mute-audio", "--disable-dev-shm-usage",
                f"--user-data-dir={self._profile}", "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0", f"--window-size={self.size[0]},{self.size[1]}", self.url]
        try:
            # its scratch files go inside the profile, so they go with it (the browser is killed)
            env = {**os.environ, "TMPDIR": self._profile}
            self._proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, start_new_session=True, env=env)
        except OSError as exc:
            self._cleanup()
            raise BrowserUnavailable(f"{exe} cannot start: {exc}") from exc
        try:
            port = self._devtools_port()
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                targets = json.loads(r.read())
            page = next(t for t in targets if t.get("type") == "page")  # the tab opened on the url
            self._ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=30,
                                                   suppress_origin=True)
            tab = Page(self._ws)
            tab.call("Emulation.setDeviceMetricsOverride", width=self.size[0], height=self.size[1],
                     deviceScaleFactor=1, mobile=False)
            return tab
        except BaseException:
            self._cleanup()
            raise

    def _devtools_port(self) -> int:
        assert self._profile is not None and self._proc is not None
        marker = Path(self._profile) / "DevToolsActivePort"
        end = time.monotonic() + self.start_timeout
        while time.monotonic() < end:
            if self._proc.poll() is not None:
                raise BrowserUnavailable(f"chromium exited at start (status {self._proc.returncode})")
            try:
                first = marker.read_text().splitlines()[0]
                return int(first)
            except (OSError, IndexError, ValueError):
                time.sleep(0.1)
        raise BrowserUnavailable(f"chromium's DevTools endpoint did not come up in {self.start_timeout:.0f} s")

    def _cleanup(self) -> None:
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:  # noqa: BLE001 - closing a dead socket
                pass
            self._ws = None
        if self._proc is not None:
            try:
                os.killpg(self._proc.pid, signal.SIGKILL)  # the browser and its helper processes
            except ProcessLookupError:
                pass
            self._proc.wait()
            self._proc = None
        if self._profile is not None:
            shutil.rmtree(self._profile, ignore_errors=True)
            self._profile = None

    def __exit__(self, *exc: object) -> None:
        self._cleanup()


#: The planted test frame (:func:`planted_scene`): what each region holds, and the colour the
#: viewer must show for it.  Top half: unpolarized magenta; bottom half: grey with DoLP 0.5 at
#: AoLP 60 degrees.
PLANTED: dict[str, Any] = {
    "magenta": (0.9, 0.05, 0.9),     # per polarizer image, linear [0, 1]
    "grey": 0.6,
    "dolp": 0.5,
    "aolp_deg": 60.0,
}


def planted_scene(folder: str | Path, *, name: str = "planted", count: int = 1, height: int = 128,
                  width: int = 192) -> dict[str, tuple[int, int, int]]:
    """Write a distinctly coloured colour-sensor test frame (imx250myr, 12-bit) with its sidecar.

    Returns
    -------
    dict
        The RGB colours the viewer must show for it: ``"s0"`` (the S0 and
        diffuse panels of the top half, ``round(255 I)``: unpolarized, so S0 / 2
        = I and the imin diffuse is I), ``"dolp"`` (viridis at DoLP 0.5, bottom
        half) and ``"aolp"`` (hue of 60 degrees: pure green, bottom half).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    h2 = height // 2
    s0 = np.empty((height, width, 3))
    s0[:h2] = 2.0 * np.asarray(PLANTED["magenta"])
    s0[h2:] = 2.0 * PLANTED["grey"]
    dolp = np.zeros((height, width, 3))
    dolp[h2:] = PLANTED["dolp"]
    aolp = np.full((height, width, 3), np.deg2rad(PLANTED["aolp_deg"]))
    raw = mosaic(stack_from_stokes(s0, dolp, aolp), "imx250myr")
    for i in range(count):
        counts = np.round(np.clip(raw, 0, 1) * 4095).astype(np.uint16)
        write_frame(folder / f"{name}_{i:02d}.png",
                    Frame(mosaic=counts, layout=parse_layout("imx250myr"), bit_depth=12, black_level=0.0,
                          white_level=4095.0, metadata={"timestamp_ns": 1_000_000 * i}))
    pal = palettes()
    dolp_rgb = dict((c, rgb) for c, _, rgb in pal["dolp"])[int(dolp_ids(np.float32([[PLANTED["dolp"]]]))[0, 0])]
    aolp_rgb = dict((c, rgb) for c, _, rgb in pal["aolp"])[1 + int(round(PLANTED["aolp_deg"]))]
    return {"s0": tuple(int(round(255 * v)) for v in PLANTED["magenta"]), "dolp": dolp_rgb, "aolp": aolp_rgb}


def colour_fraction(shot: np.ndarray, rgb: tuple[int, int, int], *, tolerance: int = 10) -> float:
    """Fraction of the screenshot's pixels within ``tolerance`` (per channel) of ``rgb``."""
    diff = np.abs(shot.astype(np.int16) - np.asarray(rgb, dtype=np.int16)).max(axis=-1)
    return float((diff <= tolerance).mean())


def shows_planted(shot: np.ndarray, colours: dict[str, tuple[int, int, int]], *,
                  least: float = 0.002) -> bool:
    """True when every planted colour covers at least ``least`` of the screenshot."""
    return all(colour_fraction(shot, rgb) >= least for rgb in colours.values())


def viewer_screenshot(url: str, *, accept: Callable[[np.ndarray], bool], timeout: float = 60.0,
                      width: int = 1600, height: int = 900, settle: float = 0.0) -> tuple[np.ndarray, bool]:
    """Open ``url`` in headless Chromium and screenshot it once ``accept(shot)``; (shot, accepted).

    ``settle`` seconds are waited after acceptance and the screenshot taken
    again (lets the viewer finish drawing the other panels).
    """
    with open_page(url, width=width, height=height) as page:
        shot, ok = page.wait_for(accept, timeout=timeout)
        if ok and settle > 0:
            time.sleep(settle)
            shot, _ = page.wait_for(lambda _shot: True, timeout=timeout)  # retried while the page is busy
        return shot, ok


class Served:
    """A polcam command that serves the web viewer (``polcam view --web``, ``capture --rerun serve``).

    Started by :func:`serve`; ``url`` is the page it printed, ``server_pids``
    its child processes at that moment (the Rerun server).  Leaving the
    ``with`` block sends SIGINT (Ctrl-C) and waits for the command.
    """

    def __init__(self, args: list[str], *, stream: str = "stdout", timeout: float = 60.0,
                 env: dict[str, str] | None = None) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "polcam.cli", *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env)
        self.returncode: int | None = None
        source = self.proc.stdout if stream == "stdout" else self.proc.stderr
        assert source is not None
        end = time.monotonic() + timeout
        seen: list[str] = []
        url = None
        while url is None and time.monotonic() < end:
            line = source.readline()
            if not line:
                break
            seen.append(line)
            m = re.search(r"Rerun web viewer: open (http://\S+)", line)
            url = m.group(1) if m else None
        if url is None:
            self.stop()
            raise RuntimeError(f"polcam {' '.join(args)} printed no URL: {''.join(seen)[-2000:]}")
        self.url: str = url
        self.server_pids = child_pids(self.proc.pid)

    def stop(self, sig: int = signal.SIGINT, timeout: float = 30.0) -> int:
        """Send ``sig``, wait for the command, close its pipes; returns its exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for f in (self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()
        self.returncode = self.proc.returncode
        return self.returncode

    def __enter__(self) -> Served:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def serve(args: list[str], *, stream: str = "stdout", timeout: float = 60.0,
          env: dict[str, str] | None = None) -> Served:
    """Start ``polcam ARGS`` (a command that serves the web viewer) and wait for its URL.

    ``stream``: where it prints the URL (``view``: stdout; ``capture``: stderr).
    """
    return Served(args, stream=stream, timeout=timeout, env=env)


def child_pids(pid: int) -> list[int]:
    """The process ids whose parent is ``pid`` (Linux ``/proc``; empty elsewhere)."""
    kids = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                if int(Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    kids.append(int(d))
            except (OSError, IndexError, ValueError):
                pass
    return kids


def process_gone(pid: int, timeout: float = 10.0) -> bool:
    """Whether process ``pid`` has ended, waiting up to ``timeout`` seconds for it (Linux ``/proc``).

    Gone: no ``/proc/PID`` any more, or a zombie (``Z``) with no thread left.  A multi-threaded
    process whose main thread has exited also shows ``Z`` while its other threads still run (a
    server shutting down still accepts connections), so ``Z`` alone is not enough.
    """
    end = time.monotonic() + timeout
    while True:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
            if state == "Z" and len(os.listdir(f"/proc/{pid}/task")) <= 1:
                return True
        except OSError:
            return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.1)


def _drawn(shot: np.ndarray) -> bool:
    """The viewer has drawn images: many distinct colours, not a blank or loading page."""
    return shot.std() > 30 and len(np.unique(shot[::4, ::4].reshape(-1, 3), axis=0)) > 500


def doc_screenshots(out_dir: str | Path, *, work: str | Path | None = None) -> list[Path]:
    """The screenshots of docs/guide/viewer.md: a processed batch and a live capture, in ``out_dir``.

    Made the way the browser tests look at the viewer (:func:`serve`,
    :func:`viewer_screenshot`) on the fixtures: ``polcam process`` of
    fixtures/raw shown by ``polcam view --web``, and ``polcam capture --rerun
    serve`` replaying the colour fixture.  ``python -m polcam._browser docs/img``.
    """
    import cv2

    root = Path(__file__).resolve().parents[1]
    fixtures = root / "fixtures" / "raw"
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(work) if work is not None else Path(tempfile.mkdtemp(prefix="polcam-shots-"))
    env = {**os.environ, "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    made = []
    try:
        batch = tmp / "batch"
        subprocess.run([sys.executable, "-m", "polcam.cli", "process", str(fixtures), "-o", str(batch),
                        "--quiet", "--workers", "1"], check=True, env=env)
        with serve(["view", str(batch), "--web", "--port", "0"], env=env) as served:
            shot, ok = viewer_screenshot(served.url, accept=_drawn, timeout=90, settle=3)
        if not ok:
            raise RuntimeError("the batch view did not draw")
        cv2.imwrite(str(out_dir / "viewer-batch.png"), shot[:, :, ::-1])
        made.append(out_dir / "viewer-batch.png")
        replay = tmp / "replay"
        replay.mkdir(exist_ok=True)
        for ext in (".png", ".json"):
            shutil.copy(fixtures / f"synthetic_bunny5{ext}", replay / f"synthetic_bunny5{ext}")
        with serve(["capture", "--device", f"replay:{replay}", "--loop", "--frame-rate", "10", "--duration", "120",
                    "--no-save", "--view-scale", "1", "--raw-every", "1", "--rerun", "serve", "--port", "0"],
                   stream="stderr", env=env) as served:
            time.sleep(3)
            shot, ok = viewer_screenshot(served.url, accept=_drawn, timeout=90, settle=5)
        if not ok:
            raise RuntimeError("the live view did not draw")
        cv2.imwrite(str(out_dir / "viewer-capture.png"), shot[:, :, ::-1])
        made.append(out_dir / "viewer-capture.png")
    finally:
        if work is None:
            shutil.rmtree(tmp, ignore_errors=True)
    return made


if __name__ == "__main__":  # pragma: no cover
    for made in doc_screenshots(sys.argv[1] if len(sys.argv) > 1 else "docs/img"):
        print(made)
