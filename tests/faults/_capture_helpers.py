"""What the capture fault tests share: the capture command as a real process, a small real disk,
faults injected at the OS boundary where mounting is refused, and the checks every test makes.

The disk: a tmpfs mounted for the test (root in a container allows it); where mounting is refused,
the child process gets a ``sitecustomize`` on its ``PYTHONPATH`` that makes ``os.open``/``os.mkdir``
fail with the wanted errno for paths under the output folder (after a budget of files), the way
a full or read-only disk refuses them.  polcam's own code paths are never patched.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from polcam.camera import aravis_available
from polcam.camera.emulator import emulator_available

REPO = Path(__file__).resolve().parents[2]

needs_aravis = pytest.mark.skipif(not aravis_available(), reason="Aravis 0.8 is not installed")
needs_emulator = pytest.mark.skipif(
    not (aravis_available() and emulator_available()), reason="Aravis GigE emulator not installed"
)

#: Settings of Aravis' fake cameras in these tests: 256 x 256 Mono8 (64 KiB a frame).
FAKE = ["--pixel-format", "Mono8", "--layout", "imx250mzr", "--roi", "0", "0", "256", "256"]
FRAME_BYTES = 256 * 256


def capture_cmd(device: str, out: Path | None, *extra: str) -> list[str]:
    """``python -m polcam capture`` with the live view off unless ``extra`` asks for it."""
    cmd = [sys.executable, "-m", "polcam", "capture", "--device", device]
    if out is not None:
        cmd += ["--out", str(out)]
    if "--separate" not in extra:
        cmd += ["--separate", "none"]
    return cmd + list(extra)


def start(cmd: list[str], env: dict[str, str] | None = None, cwd: Path | None = None) -> subprocess.Popen[str]:
    """Start a command in its own session (so a test can signal its whole process group)."""
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=cwd or REPO, start_new_session=True)


def finish(proc: subprocess.Popen[str], timeout: float = 60.0) -> tuple[str, str]:
    """Wait for the process, killing its group if it overruns; (stdout, stderr)."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=30)
        raise AssertionError(f"{proc.args} did not end in {timeout} s: {out}\n{err}") from None


def visible_frames(out: Path) -> list[str]:
    """Frame files in a capture folder (sidecars and summaries excluded)."""
    return sorted(p.name for p in out.glob("frame_*") if p.suffix != ".json")


def wait_for_frames(proc: subprocess.Popen[str], out: Path, n: int, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if out.is_dir() and len(visible_frames(out)) >= n:
            return
        if proc.poll() is not None:
            raise AssertionError(f"capture exited early: {proc.communicate()}")
        time.sleep(0.05)
    raise AssertionError(f"no {n} frames in {out} within {timeout} s")


def ramp(side: dict[str, Any]) -> np.ndarray:
    """What Aravis' fake cameras send in Mono8: (x + y + frame id) mod 255 (gain 0)."""
    x0, y0, w, h = side["roi"]
    y, x = np.mgrid[y0:y0 + h, x0:x0 + w]
    return ((x + y + side["frame_id"]) % 255).astype(np.uint8)


def summary_from(out: Path, text: str) -> dict[str, Any]:
    """The summary a capture wrote: where its output names it, else ``out/summary.json``."""
    m = re.search(r"summary written to (\S+)", text)
    path = Path(m.group(1)) if m else out / "summary.json"
    assert path.is_file(), f"no summary at {path}; output:\n{text}"
    return json.loads(path.read_text())


def check_accounted(out: Path, summary: dict[str, Any], *, ramp_frames: bool = True) -> None:
    """Every frame the camera delivered is saved whole or counted; no sidecar without its frame.

    Checks: the frames on disk are exactly the summary's ``files``; each has its sidecar and
    every sidecar its frame; no temporary file is left; each frame has its full size and
    (``ramp_frames``) the fake camera's pattern for its frame id; ``received = saved + failed +
    unsaved`` and ``good = received + queue_overflow + left_at_stop``.
    """
    files = visible_frames(out)
    assert summary["files"] == files and summary["frames_saved"] == len(files)
    stems = {Path(f).stem for f in files}
    sidecars = {p.stem for p in out.glob("frame_*.json")}
    assert sidecars == stems, f"sidecars without frames: {sorted(sidecars - stems)}; " \
                              f"frames without sidecars: {sorted(stems - sidecars)}"
    assert not [p.name for p in out.glob(".frame_*")], "temporary files left"
    for name in files:
        data = (out / name).read_bytes()
        side = json.loads((out / name).with_suffix(".json").read_text())
        if ramp_frames:
            assert len(data) == FRAME_BYTES, name
            np.testing.assert_array_equal(np.frombuffer(data, np.uint8).reshape(256, 256), ramp(side))
    s = summary
    assert s["frames_received"] == s["frames_saved"] + s["frames_save_failed"] + s["frames_unsaved"], s
    assert s["frames_good"] == s["frames_received"] + s["queue_overflow"] + s["frames_left_at_stop"], s


# ---------------------------------------------------------------------------
# a small disk: a real tmpfs, or faults injected in the child process
# ---------------------------------------------------------------------------

def _mount(args: list[str]) -> bool:
    try:
        return subprocess.run(args, capture_output=True, timeout=20).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


@contextlib.contextmanager
def small_disk(where: Path, size_kib: int, *, readonly: bool = False,
               make: tuple[str, ...] = ()) -> Iterator[bool]:
    """Mount a ``size_kib`` tmpfs on ``where`` (folders ``make`` created in it, then remounted
    read-only with ``readonly``); yields True, or False where mounting is refused or
    ``$POLCAM_TEST_NO_MOUNT`` is set (``where`` is then a plain folder, and the test injects the
    fault with :func:`inject_env`)."""
    where.mkdir(parents=True, exist_ok=True)
    allowed = os.geteuid() == 0 and not os.environ.get("POLCAM_TEST_NO_MOUNT")
    mounted = allowed and _mount(["mount", "-t", "tmpfs", "-o", f"size={size_kib}k", "tmpfs", str(where)])
    try:
        for sub in make:
            (where / sub).mkdir(parents=True, exist_ok=True)
        if mounted and readonly and not _mount(["mount", "-o", "remount,ro", str(where)]):
            _mount(["umount", "-l", str(where)])
            mounted = False
        yield mounted
    finally:
        if mounted:
            _mount(["umount", "-l", str(where)])


_SITECUSTOMIZE = '''
import errno as _errno, os as _os
_ROOT = {root!r}
_ERR = getattr(_errno, {err!r})
_budget = [{budget}]
_open, _mkdir = _os.open, _os.mkdir

def _under(path):
    try:
        return _os.path.abspath(_os.fsdecode(path)).startswith(_ROOT)
    except TypeError:
        return False

def open(path, flags, mode=0o777, *args, **kwargs):
    if flags & _os.O_CREAT and _under(path):
        if _budget[0] <= 0:
            raise OSError(_ERR, _os.strerror(_ERR), _os.fsdecode(path))
        _budget[0] -= 1
    return _open(path, flags, mode, *args, **kwargs)

def mkdir(path, mode=0o777, *args, **kwargs):
    if _under(path) and _ERR != _errno.ENOSPC:
        raise OSError(_ERR, _os.strerror(_ERR), _os.fsdecode(path))
    return _mkdir(path, mode, *args, **kwargs)

_os.open, _os.mkdir = open, mkdir
'''


def inject_env(tmp: Path, root: Path, err: str, *, files: int = 0) -> dict[str, str]:
    """An environment whose Python processes get ``err`` (``"ENOSPC"``, ``"EROFS"``) when creating
    files under ``root`` once ``files`` have been created (``EROFS`` also refuses new folders)."""
    assert hasattr(errno, err)
    site = tmp / "inject-site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(_SITECUSTOMIZE.format(root=str(root.resolve()), err=err,
                                                                 budget=int(files)))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def env_with_tmpdir(tmp: Path, env: dict[str, str] | None = None) -> dict[str, str]:
    """``env`` (default: this one) with ``TMPDIR`` a fresh folder of the test (summary fallback)."""
    d = tmp / "tmpdir"
    d.mkdir(exist_ok=True)
    return {**(env or os.environ), "TMPDIR": str(d)}
