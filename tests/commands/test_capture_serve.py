"""``polcam capture --rerun serve --port N --bind ADDR``: the live web viewer's address, as a user runs it."""

from __future__ import annotations

import shutil
import socket
from pathlib import Path

from polcam._browser import serve

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "raw"


def _replay(tmp_path: Path) -> Path:
    src = tmp_path / "replay"
    src.mkdir()
    for f in ("fruits_crop.png", "fruits_crop.json"):
        shutil.copy(FIXTURES / f, src / f)
    return src


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _capture(src: Path, *extra: str) -> list[str]:
    return ["capture", "--device", f"replay:{src}", "--loop", "--frame-rate", "5", "--duration", "60",
            "--no-save", "--separate", "none", "--rerun", "serve", *extra]


def test_capture_serves_on_the_port_asked_for_on_loopback(tmp_path):
    port = _free_port()
    with serve(_capture(_replay(tmp_path), "--port", str(port)), stream="stderr") as served:
        assert served.url.startswith(f"http://127.0.0.1:{port}")
        socket.create_connection(("127.0.0.1", port), timeout=5).close()   # the page is there
        assert served.proc.poll() is None
    assert served.returncode == 0
    try:  # and gone with the command
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
        raise AssertionError(f"port {port} still served after the capture ended")
    except OSError:
        pass


def test_capture_bound_to_every_address_says_who_can_watch(tmp_path):
    with serve(_capture(_replay(tmp_path), "--port", "0", "--bind", "0.0.0.0"), stream="stderr") as served:
        assert "127.0.0.1" not in served.url   # a URL another machine can open
        warning = served.proc.stderr.readline()   # the line after the URL
        assert "anyone on the networks this machine is on can watch" in warning, warning
    assert served.returncode == 0
