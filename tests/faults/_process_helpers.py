"""Helpers of the ``polcam process`` fault tests: synthetic raw frames, real runs, real signals, and
the checks every fault test makes (every frame accounted for, no frame's files disagreeing with
its meta.json)."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[2]
PRODUCTS = ("diffuse", "specular", "s0", "dolp", "aolp")
#: Per-frame options that make a 64x64 colour frame take about a second of the tensor solver's iterations (frames in progress
#: when a signal arrives).
SLOW = ("--method", "tensor", "--option", "max_iter=120", "--option", "tol=0")


def make_frames(folder: Path, n: int, *, size: int = 64, colour: bool = True, seed: int = 0,
                prefix: str = "f") -> list[Path]:
    """``n`` synthetic 12-bit raw mosaics as ``.npy`` with a sidecar giving the layout."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    paths = []
    for i in range(n):
        base = 600 + 400 * np.sin(xx / (5.0 + i)) * np.cos(yy / 7.0) + 2000 * (((xx // 16) + (yy // 16)) % 2)
        m = np.clip(base + rng.normal(0, 20, base.shape), 0, 4095).astype(np.uint16)
        p = folder / f"{prefix}{i:02d}.npy"
        np.save(p, m)
        (folder / f"{prefix}{i:02d}.json").write_text(json.dumps(
            {"layout": "imx250myr" if colour else "imx250mzr", "bit_depth": 12}))
        paths.append(p)
    return paths


def env(extra_path: Path | None = None) -> dict[str, str]:
    """The environment of a ``polcam`` child: this checkout first on the path."""
    e = dict(os.environ)
    parts = [str(REPO)] + ([str(extra_path)] if extra_path else []) + [e.get("PYTHONPATH", "")]
    e["PYTHONPATH"] = os.pathsep.join(p for p in parts if p)
    return e


def start(raw: Path | list[Path], out: Path, *args: str, extra_path: Path | None = None) -> subprocess.Popen:
    """``polcam process RAW -o OUT --json ARGS`` in its own process group (signals reach only it)."""
    inputs = [str(p) for p in (raw if isinstance(raw, list) else [raw])]
    return subprocess.Popen([sys.executable, "-m", "polcam", "process", *inputs, "-o", str(out), "--json", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env(extra_path),
                            start_new_session=True)


def run(raw: Path | list[Path], out: Path, *args: str, timeout: float = 120,
        extra_path: Path | None = None, child: bool = False) -> tuple[int, list[dict[str, Any]], str]:
    """Run ``polcam process RAW -o OUT --json ARGS`` to the end: exit status, JSON events, stderr.

    In this process (``polcam.cli.main``, output captured) unless ``child`` or ``extra_path`` (a
    ``sitecustomize`` for the child) asks for a separate process.
    """
    if child or extra_path is not None:
        p = start(raw, out, *args, extra_path=extra_path)
        stdout, stderr = p.communicate(timeout=timeout)
        return p.returncode, events(stdout), stderr
    import io

    from polcam.cli import main

    inputs = [str(q) for q in (raw if isinstance(raw, list) else [raw])]
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        code = main(["process", *inputs, "-o", str(out), "--json", *args])
    return code, events(o.getvalue()), e.getvalue()


def events(stdout: str) -> list[dict[str, Any]]:
    """The JSON lines of ``--json`` output."""
    return [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]


def wait_for(cond: Callable[[], Any], timeout: float = 60, what: str = "condition") -> Any:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = cond()
        if v:
            return v
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, parent PID) of a process, or None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()
    return fields[0], int(fields[1])


def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    st = _stat(pid)
    return st is not None and st[0] not in ("Z", "X")


def descendants(pid: int) -> set[int]:
    """Every live process below ``pid``."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            if st is not None and st[0] not in ("Z", "X"):
                children.setdefault(st[1], []).append(int(d.name))
    out: set[int] = set()
    todo = [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            if c not in out:
                out.add(c)
                todo.append(c)
    return out


def cpu_seconds(pid: int) -> float:
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def workers_of(main_pid: int) -> list[int]:
    """The frame workers of a run: descendants whose command line is a forkserver child or spawn worker
    (the fork server's children), not the fork server or the resource tracker themselves."""
    found = []
    for pid in descendants(main_pid):
        st = _stat(pid)
        if st is not None and st[1] != main_pid:     # grandchildren: the fork server's children
            found.append(pid)
    return sorted(found)


def busy_worker(main_pid: int, timeout: float = 60) -> int:
    """A worker of the run that is computing a frame (its CPU time grows)."""
    def pick() -> int | None:
        ws = workers_of(main_pid)
        before = {w: cpu_seconds(w) for w in ws}
        time.sleep(0.3)
        for w in ws:
            if cpu_seconds(w) > before[w]:          # an idle worker waits on its pipe: no CPU time
                return w
        return None
    return wait_for(pick, timeout, "a busy worker")


def summary(out: Path) -> dict[str, Any]:
    return json.loads((out / "summary.json").read_text())


def check_accounted(out: Path, inputs: list[Path], summ: dict[str, Any] | None = None) -> dict[str, set[str]]:
    """Every input is in summary.json exactly once: done, skipped, failed (with a reason naming it),
    cancelled (with a reason) or not started.  Returns the input names by outcome."""
    s = summ if summ is not None else summary(out)
    by: dict[str, set[str]] = {k: set() for k in ("done", "skipped", "failed", "cancelled", "not_started")}
    for r in s["results"]:
        if r["status"] in ("done", "skipped"):
            by[r["status"]].add(Path(r["input"]).name)
    for f in s["failed"]:
        assert f["error"].strip() and "\n" not in f["error"], f
        assert Path(f["input"]).name in f["error"] or f["input"] in f["error"], f
        by["failed"].add(Path(f["input"]).name)
    for c in s["cancelled"]:
        assert c["reason"].strip(), c
        by["cancelled"].add(Path(c["input"]).name)
    by["not_started"] = {Path(p).name for p in s["not_started"]}
    names = [n for v in by.values() for n in v]
    assert sorted(names) == sorted(p.name for p in inputs), by
    assert s["frames"] == len(inputs)
    return by


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_consistent(out: Path) -> list[str]:
    """No frame folder's files disagree with its meta.json: each product listed with its size and
    SHA-256 is that file, its image has the shape meta.json records, and that shape is the one its
    resolution gives for the input's size.  Returns the names of the finished frames."""
    from polcam.io import read_image

    finished = []
    for meta_path in sorted(out.rglob("meta.json")):
        meta = json.loads(meta_path.read_text())
        folder = meta_path.parent
        h, w = np.load(meta["input"], mmap_mode="r").shape
        div = 2 if meta["resolution"] == "cell" else 1
        assert set(meta["files"]) == {f"{p}.exr" for p in PRODUCTS}, folder
        for name, rec in meta["files"].items():
            f = folder / name
            assert f.stat().st_size == rec["bytes"] and sha256(f) == rec["sha256"], f"{f} differs from meta.json"
            img, _ = read_image(f)
            product = name.split(".")[0]
            assert list(img.shape) == meta["product_shapes"][product], f
            assert img.shape[:2] == (h // div, w // div), f"{f}: {img.shape} for {meta['resolution']}"
        finished.append(folder.relative_to(out).as_posix())
    return finished


def frame_mtimes(out: Path) -> dict[str, float]:
    """Modification times of every file under ``out`` except the run's own lock/reserve files."""
    return {str(p): p.stat().st_mtime for p in out.rglob("*") if p.is_file()}


@contextlib.contextmanager
def small_disk(where: Path, size: str) -> Iterator[tuple[Path, Path | None]]:
    """A real small file system: a tmpfs of ``size`` mounted at ``where/disk`` (root).

    Yields ``(folder, None)``; where mounting is refused, ``(folder, sitecustomize dir)``: a folder
    on the ordinary disk and a ``sitecustomize`` for the child's PYTHONPATH that makes file creation
    under the folder fail with ENOSPC once ``size`` bytes of files exist there (checked at each
    ``os.open``/``open`` with O_CREAT, the operating-system boundary of the child).
    ``POLCAM_TEST_NO_MOUNT=1`` takes the second way where mounting works too.
    """
    mnt = where / "disk"
    mnt.mkdir()
    mounted = False
    if os.geteuid() == 0 and shutil.which("mount") and not os.environ.get("POLCAM_TEST_NO_MOUNT"):
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True)
        mounted = r.returncode == 0
    try:
        if mounted:
            yield mnt, None
        else:
            site = enospc_site(where, mnt, _bytes(size))
            yield mnt, site
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def enospc_site(where: Path, root: Path, limit: int) -> Path:
    """A ``sitecustomize`` folder for a child's PYTHONPATH: creating a file under ``root`` fails
    with ENOSPC once ``limit`` bytes of files exist there (at ``os.open``/``open``)."""
    site = where / f"enospc-site-{limit}"
    site.mkdir()
    (site / "sitecustomize.py").write_text(textwrap.dedent(f'''
        import builtins, errno, io, os
        _ROOT = {str(root)!r}
        _LIMIT = {int(limit)}
        def _used():
            return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(_ROOT) for f in fs
                       if os.path.exists(os.path.join(d, f)))
        def _check(path, creating):
            p = os.path.abspath(os.fsdecode(path)) if isinstance(path, (str, bytes, os.PathLike)) else ""
            if creating and p.startswith(_ROOT) and _used() >= _LIMIT:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), p)
        _open, _bopen = os.open, builtins.open
        def _os_open(path, flags, *a, **k):
            _check(path, flags & os.O_CREAT)
            return _open(path, flags, *a, **k)
        def _b_open(file, mode="r", *a, **k):
            _check(file, any(c in mode for c in "wax"))
            return _bopen(file, mode, *a, **k)
        os.open, builtins.open, io.open = _os_open, _b_open, _b_open
    '''))
    return site


def _bytes(size: str) -> int:
    s = size.strip().lower()
    mult = {"k": 1 << 10, "m": 1 << 20, "g": 1 << 30}.get(s[-1], 1)
    return int(float(s.rstrip("kmg")) * mult)


def kill_group(p: subprocess.Popen, sig: int) -> None:
    """Send ``sig`` to the run's process group (what a terminal or a job scheduler does)."""
    os.killpg(p.pid, sig)


def finish(p: subprocess.Popen, timeout: float = 60) -> tuple[int, list[dict[str, Any]], str]:
    stdout, stderr = p.communicate(timeout=timeout)
    return p.returncode, events(stdout), stderr


def reap_group(p: subprocess.Popen) -> None:
    """Make sure nothing of a run is left (test clean-up)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(p.pid, signal.SIGKILL)
    with contextlib.suppress(Exception):
        p.communicate(timeout=10)


def slow_writes_site(where: Path, root: Path, seconds: float) -> Path:
    """A ``sitecustomize`` folder for a child's PYTHONPATH: every file created under ``root`` waits
    ``seconds`` first (at ``os.open`` with O_CREAT), so a frame's outputs take a while to write and a
    signal can be sent while a frame is half-written."""
    site = where / "slow-site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(textwrap.dedent(f'''
        import os, time
        _ROOT, _WAIT, _open = {str(root)!r}, {seconds!r}, os.open
        def _os_open(path, flags, *a, **k):
            if flags & os.O_CREAT and os.path.abspath(os.fsdecode(path)).startswith(_ROOT) \\
                    and os.path.basename(os.fsdecode(path)).startswith(".") and ".tmp" in os.fsdecode(path):
                time.sleep(_WAIT)
            return _open(path, flags, *a, **k)
        os.open = _os_open
    '''))
    return site
