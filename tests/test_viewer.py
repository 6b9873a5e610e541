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

from polcam._browser import child_pids, process_gone
from polcam.cli import main
from polcam.errors import FrameReadError, PolcamError
from polcam.sinks.rerun import ENTITIES, RerunSink
from polcam.viewer import kind_of, log_path, resolve

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
    sink = RerunSink(tmp_path / "b.rrd", live=False)
    sink.log_stats(0, None, fps=1.0)
    sink.close()
    assert kind_of(tmp_path / "b.rrd") == "rrd"
    (tmp_path / "out" / "f1").mkdir(parents=True)
    (tmp_path / "out" / "f1" / "meta.json").write_text("{}")
    for name in ("s0", "dolp", "aolp", "diffuse", "specular"):
        (tmp_path / "out" / "f1" / f"{name}.exr").write_bytes(b"")
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
        kids = child_pids(proc.pid)
        assert kids, "the web viewer runs as a child process"
        proc.send_signal(sig)
        proc.wait(30)
        assert proc.returncode == (0 if sig != signal.SIGKILL else -signal.SIGKILL)
        for k in kids:  # no orphan: SIGINT/SIGTERM stop it, a killed parent takes it along (PDEATHSIG)
            assert process_gone(k), f"server process {k} outlived polcam view ({sig.name})"
        # the port stops accepting; polled, as the kernel closes the listening socket after the exit
        deadline = time.monotonic() + 10
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=2).close()
            except OSError:
                break
            assert time.monotonic() < deadline, f"port {port} still accepts after polcam view ended ({sig.name})"
            time.sleep(0.2)
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


def _run_view(*args: str, cwd: Path | None = None, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """``polcam view ARGS`` to its end (a refusal ends it; a server would not)."""
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-m", "polcam", "view", *args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=timeout)


def _zombies_of(pid: int) -> list[int]:
    out = []
    for k in child_pids(pid):
        try:
            if Path(f"/proc/{k}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
                out.append(k)
        except OSError:
            pass
    return out


def _adjacent_free_port() -> int:
    """A free port p with p - 1 and p + 1 free too (a web viewer's page and data ports, and one below)."""
    import socket

    for _ in range(100):
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
        try:
            with socket.socket() as b, socket.socket() as c, socket.socket() as d:
                for sock, p in ((b, port - 1), (c, port), (d, port + 1)):
                    sock.bind(("127.0.0.1", p))
                return port
        except OSError:
            continue
    raise AssertionError("no three adjacent free ports")


@pytest.mark.parametrize("which", ["page", "data"])
def test_a_port_another_server_holds_is_refused(processed, which):
    # another Rerun web viewer already serves on the port (or on the data port, port + 1):
    # polcam view must not stream into it, and says so before starting anything
    from polcam.sinks.rerun_web import WebServer

    with WebServer(port=_adjacent_free_port()) as other:
        port = other.port if which == "page" else other.port - 1  # "data": only port + 1 is taken
        taken = other.port
        r = _run_view(str(processed), "--web", "--port", str(port))
        assert r.returncode == 2, (r.stdout, r.stderr)
        assert f"port {taken} is in use: something is already listening on 127.0.0.1:{taken}" in r.stderr
        assert "open http" not in r.stdout and "logged" not in r.stdout
        assert other.pid is not None and process_gone(other.pid, timeout=0.5) is False  # the other server untouched


def test_a_server_that_answers_on_our_port_is_never_taken_for_ours(monkeypatch):
    # the race the check before the start cannot close: the port is taken between the check and
    # the start. The readiness check must see that the server answering there is not the child it
    # started, and the failed child must be reaped (no <defunct> process left behind)
    from polcam.sinks import rerun_web

    with rerun_web.WebServer(port=_adjacent_free_port()) as other:
        assert other.grpc_port == other.port + 1  # both ports of the one asked for are answered
        monkeypatch.setattr(rerun_web, "check_port_free", lambda bind, port: None)
        with pytest.raises(PolcamError, match=rf"{other.port}|did not start|did not open"):
            rerun_web.WebServer(port=other.port, start_timeout=15)
        assert _zombies_of(os.getpid()) == []
        assert rerun_web.listening_owner(other.pid, other.port) is True
        assert rerun_web.listening_owner(os.getpid(), other.port) is False


@pytest.mark.parametrize("content", ["empty", "garbage", "truncated"])
@pytest.mark.parametrize("web", [True, False])
def test_an_invalid_rrd_is_refused_before_serving(processed, tmp_path, content, web):
    good = tmp_path / "good.rrd"
    assert main(["process", str(processed.parent / "raw"), "-o", str(tmp_path / "out"), "--method", "imin",
                 "--workers", "1", "--quiet", "--rerun", str(good)]) == 0
    data = good.read_bytes()
    bad = tmp_path / "bad.rrd"
    bad.write_bytes({"empty": b"", "garbage": b"not a recording\n" * 100,
                     "truncated": data[: len(data) // 2]}[content])
    r = _run_view(str(bad), *(["--web", "--port", "0"] if web else []))
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert f"{bad}: not a readable Rerun recording" in r.stderr and "expected a whole .rrd" in r.stderr
    assert "open http" not in r.stdout
    assert "Traceback" not in r.stderr
    assert kind_of(good) == "rrd"  # the whole file is accepted


def test_a_recording_cut_at_a_message_boundary_is_shown_with_a_note(tmp_path):
    # a capture still writing its .rrd (or one killed): whole messages, no footer yet
    from polcam.viewer import check_recording

    sink = RerunSink(tmp_path / "run.rrd", live=False)
    sink.log_stats(0, None, fps=1.0)
    sink._rec.flush()
    partial = (tmp_path / "run.rrd").read_bytes()  # written so far, before close writes the footer
    sink.close()
    (tmp_path / "partial.rrd").write_bytes(partial)
    notes = check_recording(tmp_path / "partial.rrd")
    assert notes and "ends without Rerun's footer" in notes[0]
    assert check_recording(tmp_path / "run.rrd") == []


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """`polcam demo` on the mono fixture (imin: quick), the folder it writes."""
    tmp = tmp_path_factory.mktemp("demo")
    raw = _raw_folder(tmp)
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    r = subprocess.run([sys.executable, "-m", "polcam", "demo", "--input", str(raw), "--out", str(tmp / "demo-output"),
                        "--separate", "imin"], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    return tmp / "demo-output"


def test_a_demo_folder_is_its_recording_or_its_layers(demo, tmp_path):
    assert {p.name for p in demo.iterdir()} >= {"capture", "stokes", "layers", "demo.rrd"}
    assert tuple(resolve(demo)[:2]) == ("rrd", demo / "demo.rrd")
    copy = tmp_path / "demo-output"
    shutil.copytree(demo, copy)
    (copy / "demo.rrd").unlink()
    shutil.rmtree(copy / "capture")  # the raw frames stay where meta.json names them (absolutely)
    assert tuple(resolve(copy)[:2]) == ("processed", copy / "layers")  # not its stokes/ folders
    sink = RerunSink(tmp_path / "v.rrd", raw_every=1, view_scale=1.0, live=False)
    assert log_path(sink, copy) == 1
    sink.close()
    assert set(_images(tmp_path / "v.rrd")) >= {ENTITIES[r] for r in ("raw", "s0", "aolp_dolp", "diffuse")}


def test_a_folder_of_another_kind_is_refused_before_any_server_starts(demo):
    r = _run_view(str(demo / "stokes"), "--web", "--port", "0")
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "no diffuse.exr or diffuse.tif: not a `polcam process` frame folder (a `polcam stokes` output?)" in r.stderr
    assert "expected an .rrd recording, a `polcam process` output folder, a `polcam demo` output folder" in r.stderr
    assert "open http" not in r.stdout


def test_the_raw_panel_shows_when_process_ran_from_another_folder(tmp_path, monkeypatch):
    # `polcam process raw -o out` run in one folder, viewed from another: meta.json names the raw
    # frame absolutely, so the raw panel still finds it
    import json

    _raw_folder(tmp_path)
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    r = subprocess.run([sys.executable, "-m", "polcam", "process", "raw", "-o", "out", "--method", "imin",
                        "--workers", "1", "--quiet"], cwd=tmp_path, capture_output=True, text=True, env=env,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    meta_path = tmp_path / "out" / "fruits_crop" / "meta.json"
    meta = json.loads(meta_path.read_text())
    assert meta["input"] == str(tmp_path / "raw" / "fruits_crop.png")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)

    def raw_frames(name: str) -> dict[int, np.ndarray]:
        sink = RerunSink(tmp_path / name, raw_every=1, view_scale=1.0, live=False)
        log_path(sink, tmp_path / "out")
        sink.close()
        return _images(tmp_path / name).get(ENTITIES["raw"], {})

    assert sorted(raw_frames("abs.rrd")) == [0]
    # a meta.json written before inputs were stored absolutely: relative to where process ran
    meta["input"] = "raw/fruits_crop.png"
    meta_path.write_text(json.dumps(meta))
    assert sorted(raw_frames("rel.rrd")) == [0]
    # a different file at that relative place is not taken for the input (its hash differs)
    meta["input_sha256"] = "0" * 64
    meta_path.write_text(json.dumps(meta))
    assert raw_frames("other.rrd") == {}


def _blueprint_views(path: Path) -> dict[str, str]:
    """{view name: view class} of the blueprint stored in a .rrd (Rerun's reader)."""
    import rerun.chunk as rrc

    reader = rrc.RrdReader(path)
    (store,) = reader.blueprints()
    names: dict[str, str] = {}
    kinds: dict[str, str] = {}
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        for col, into in (("ViewBlueprint:display_name", names), ("ViewBlueprint:class_identifier", kinds)):
            if col in rb.schema.names:
                into[str(chunk.entity_path)] = rb.column(col).to_pylist()[-1][0]
    return {names[k]: kinds[k] for k in kinds}


def test_a_batch_shows_no_capture_statistics(processed, tmp_path):
    # `process --rerun` (and `view` of a folder) lay out images only; a capture adds its statistics
    from polcam.acquisition import run_capture
    from polcam.camera.replay import ReplayCamera

    batch = tmp_path / "batch.rrd"
    assert main(["process", str(processed.parent / "raw"), "-o", str(tmp_path / "out"), "--method", "imin",
                 "--workers", "1", "--quiet", "--rerun", str(batch)]) == 0
    live = tmp_path / "live.rrd"
    with ReplayCamera(processed.parent / "raw") as cam:
        run_capture(cam, out=None, separate="imin", rerun=live, raw_every=1, view_scale=1.0)
    images = {"raw": "2D", "S0": "2D", "DoLP (viridis, 0..1)": "2D", "AoLP x DoLP (hue, value)": "2D",
              "AoLP (hue, 0..180 deg)": "2D", "diffuse": "2D", "specular": "2D"}
    stats = {"frames per second": "TimeSeries", "dropped, incomplete": "TimeSeries",
             "separation seconds": "TimeSeries"}
    assert _blueprint_views(batch) == images
    assert _blueprint_views(live) == {**images, **stats}
