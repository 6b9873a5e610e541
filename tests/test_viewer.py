"""polcam view: what PATH is, folders logged like process logs them, the web server's life."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from polcam.cli import main
from polcam.errors import FrameReadError, PolcamError
from polcam.sinks.rerun import ENTITIES, RerunSink
from polcam.viewer import kind_of, log_path

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "fixtures" / "raw"


def _raw_folder(tmp_path: Path, name: str = "fruits_crop") -> Path:
    raw = tmp_path / "raw"
    raw.mkdir(exist_ok=True)
    for ext in (".png", ".json"):
        shutil.copy(FIXTURES / f"{name}{ext}", raw / f"{name}{ext}")
    return raw


def _images(path: Path) -> dict[str, dict[int, np.ndarray]]:
    """{entity: {frame: uint8 image}} of the image entities of a .rrd (Rerun's own reader)."""
    import rerun.chunk as ch

    out: dict[str, dict[int, np.ndarray]] = {}
    for chunk in ch.RrdReader(path).stream():
        if chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        for prefix in ("Image", "SegmentationImage"):
            if f"{prefix}:buffer" not in rb.schema.names:
                continue
            for i, frame in enumerate(rb.column("frame").to_pylist()):
                fmt = rb.column(f"{prefix}:format")[i].as_py()[0]
                buf = np.asarray(rb.column(f"{prefix}:buffer")[i].as_py()[0], dtype=np.uint8)
                out.setdefault(str(chunk.entity_path), {})[frame] = buf.reshape(fmt["height"], fmt["width"], -1)
    return out


def test_kind_of_names_what_it_expected(tmp_path):
    raw = _raw_folder(tmp_path)
    assert kind_of(raw) == "raw"
    (tmp_path / "a.rrd").write_bytes(b"")
    assert kind_of(tmp_path / "a.rrd") == "rrd"
    (tmp_path / "out" / "f1").mkdir(parents=True)
    (tmp_path / "out" / "f1" / "meta.json").write_text("{}")
    assert kind_of(tmp_path / "out") == "processed" and kind_of(tmp_path / "out" / "f1") == "processed"
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "empty").mkdir()
    for bad, what in (("notes.txt", "not a Rerun recording"), ("empty", "neither frame folders"),
                      ("missing", "no such file or folder")):
        with pytest.raises(FrameReadError, match=rf"{bad}.*{what}.*expected an \.rrd recording"):
            kind_of(tmp_path / bad)


def test_a_processed_folder_is_viewed_as_process_logged_it(tmp_path):
    # two frames of different sensors; `polcam process --rerun` and the view of its output folder
    # (read back from disk by the same sink) must log the same values at the same frame times
    raw = _raw_folder(tmp_path)
    _raw_folder(tmp_path, "synthetic_bunny5")
    out, rrd = tmp_path / "out", tmp_path / "process.rrd"
    assert main(["process", str(raw), "-o", str(out), "--method", "imin", "--workers", "1",
                 "--rerun", str(rrd), "--quiet"]) == 0
    viewed = tmp_path / "view.rrd"
    sink = RerunSink(viewed, raw_every=1, view_scale=1.0)
    names = []
    assert log_path(sink, out, on_frame=names.append) == 2
    sink.close()
    assert names == ["fruits_crop", "synthetic_bunny5"]
    a, b = _images(rrd), _images(viewed)
    for role in ("raw", "s0", "dolp", "aolp", "diffuse", "specular"):
        e = ENTITIES[role]
        assert sorted(a[e]) == sorted(b[e]) == [0, 1], role
        for k in (0, 1):
            np.testing.assert_array_equal(a[e][k], b[e][k], err_msg=role)
    assert b[ENTITIES["s0"]][1].shape == (128, 128, 3)  # the colour frame at the cell resolution


def test_a_raw_folder_is_processed_with_the_defaults(tmp_path):
    # a mono frame: the view demosaics and separates it with the default methods, which is what
    # `polcam process` does without --method
    raw = _raw_folder(tmp_path)
    out, rrd = tmp_path / "out", tmp_path / "process.rrd"
    assert main(["process", str(raw), "-o", str(out), "--workers", "1", "--rerun", str(rrd), "--quiet"]) == 0
    viewed = tmp_path / "view.rrd"
    sink = RerunSink(viewed, raw_every=1, view_scale=1.0)
    assert log_path(sink, raw) == 1
    sink.close()
    a, b = _images(rrd), _images(viewed)
    for role in ("raw", "s0", "dolp", "aolp", "diffuse", "specular"):
        np.testing.assert_array_equal(a[ENTITIES[role]][0], b[ENTITIES[role]][0], err_msg=role)


def _children(pid: int) -> list[int]:
    kids = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            stat = Path(f"/proc/{d}/stat").read_text()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            kids.append(int(d))
    return kids


def _gone(pid: int, timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return True
        if state == "Z":  # exited, waiting for its parent to reap it
            return True
        time.sleep(0.1)
    return False


def _start_view(target: Path, *extra: str) -> tuple[subprocess.Popen[str], str]:
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, "-m", "polcam.cli", "view", str(target), "--web", "--port", "0",
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    line = proc.stdout.readline()
    m = re.search(r"open (http://\S+)", line)
    assert m, (line, proc.stderr.read() if proc.poll() is not None else "")
    return proc, m.group(1)


@pytest.fixture(scope="module")
def processed(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("processed")
    raw = _raw_folder(tmp)
    assert main(["process", str(raw), "-o", str(tmp / "out"), "--method", "imin", "--workers", "1",
                 "--quiet"]) == 0
    return tmp / "out"


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_the_server_stops_with_the_command(processed, sig):
    import socket

    proc, url = _start_view(processed)
    try:
        port = int(re.search(r"127\.0\.0\.1:(\d+)/", url).group(1))
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
        kids = _children(proc.pid)
        assert kids, "the web viewer runs as a child process"
        proc.send_signal(sig)
        proc.wait(30)
        assert proc.returncode == (0 if sig != signal.SIGKILL else -signal.SIGKILL)
        for k in kids:  # no orphan: SIGINT/SIGTERM stop it, a killed parent takes it along (PDEATHSIG)
            assert _gone(k), f"server process {k} outlived polcam view ({sig.name})"
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def test_binding_another_address_says_who_can_watch(processed):
    proc, url = _start_view(processed, "--bind", "0.0.0.0")
    try:
        warning = proc.stdout.readline()
        assert "anyone on the networks this machine is on can watch" in warning
        assert "127.0.0.1" not in url  # a URL another machine can open: this machine's name
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.parametrize("target", ["rrd", "folder"])
def test_native_viewer_without_a_display_points_to_the_web_viewer(processed, tmp_path, target):
    import os
    import subprocess
    import sys

    if target == "rrd":
        path = tmp_path / "run.rrd"
        assert main(["process", str(processed.parent / "raw"), "-o", str(tmp_path / "out"), "--method", "imin",
                     "--workers", "1", "--quiet", "--rerun", str(path)]) == 0
    else:
        path = processed
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")}
    r = subprocess.run([sys.executable, "-m", "polcam", "view", str(path)], capture_output=True, text=True,
                       env=env, timeout=60)
    assert r.returncode == 2 and "no display" in r.stderr and "polcam view --web" in r.stderr


def test_the_native_viewer_listens_on_the_address_asked_for(monkeypatch):
    # the SDK's own spawn listens on every interface: polcam starts the viewer itself, bound
    from polcam.sinks import rerun_web

    seen: dict[str, list[str]] = {}

    class FakeProc:  # the window cannot open here (no display); the command line is what matters
        returncode = 1

        def __init__(self, cmd, **kwargs):
            seen["cmd"] = [str(c) for c in cmd]

        def poll(self):
            return 1

    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(rerun_web.subprocess, "Popen", FakeProc)
    with pytest.raises(PolcamError, match="exited with status 1"):
        rerun_web.native_viewer(bind="127.0.0.1")
    cmd = seen["cmd"]
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1" and "--port" in cmd
