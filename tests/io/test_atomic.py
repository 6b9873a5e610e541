"""Tests of polcam.io.atomic: all-or-nothing writes and clear errors."""

from __future__ import annotations

import errno
import os
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from polcam.errors import FrameWriteError
from polcam.io import atomic
from polcam.io.atomic import atomic_path, atomic_write


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_atomic_write_writes_and_leaves_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    with atomic_write(target) as fh:
        fh.write(b"hello")
        assert not target.exists()  # nothing visible until the block ends
    assert target.read_bytes() == b"hello"
    assert _listing(tmp_path) == ["out.bin"]


def test_text_mode(tmp_path: Path) -> None:
    with atomic_write(tmp_path / "t.json", "w") as fh:
        fh.write("{\"a\": \"é\"}\n")
    assert (tmp_path / "t.json").read_text(encoding="utf-8") == "{\"a\": \"é\"}\n"


def test_temp_file_is_hidden_and_in_the_target_folder(tmp_path: Path) -> None:
    target = tmp_path / "img.exr"
    with atomic_write(target):
        temps = list(tmp_path.iterdir())
        assert len(temps) == 1 and temps[0].name.startswith(".img.exr.")
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".") and tmp.suffix == ".exr"
        tmp.write_bytes(b"x")


@pytest.mark.parametrize("existing", [False, True])
def test_exception_mid_write_keeps_target(tmp_path: Path, existing: bool) -> None:
    target = tmp_path / "data.raw"
    if existing:
        target.write_bytes(b"old content")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_write(target) as fh:
            fh.write(b"half of the new")
            raise RuntimeError("boom")
    if existing:
        assert target.read_bytes() == b"old content"
        assert _listing(tmp_path) == ["data.raw"]
    else:
        assert _listing(tmp_path) == []


def test_enospc_in_the_write_becomes_frame_write_error(tmp_path: Path) -> None:
    target = tmp_path / "full.raw"
    target.write_bytes(b"previous")
    with pytest.raises(FrameWriteError) as err:
        with atomic_write(target) as fh:
            fh.write(b"partial")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    msg = str(err.value)
    assert "full.raw" in msg and "No space left on device" in msg and "ENOSPC" in msg
    assert target.read_bytes() == b"previous"
    assert _listing(tmp_path) == ["full.raw"]


def test_enospc_at_fsync_in_an_image_writer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from polcam.io.writers import write_image

    target = tmp_path / "layer.exr"
    write_image(target, np.zeros((4, 6), np.float32))
    before = target.read_bytes()

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.os, "fsync", no_space)
    with pytest.raises(FrameWriteError) as err:
        write_image(target, np.ones((4, 6), np.float32))
    assert "layer.exr" in str(err.value) and "No space left" in str(err.value)
    assert target.read_bytes() == before
    assert _listing(tmp_path) == ["layer.exr"]


def test_erofs_at_rename(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def read_only(src: str, dst: str) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(atomic.os, "replace", read_only)
    with pytest.raises(FrameWriteError, match=r"ro\.bin.*Read-only file system"):
        with atomic_write(tmp_path / "ro.bin") as fh:
            fh.write(b"x")
    assert _listing(tmp_path) == []


def test_permission_denied_creating_the_temp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def denied(*args: object, **kwargs: object) -> tuple[int, str]:
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", denied)
    with pytest.raises(FrameWriteError) as err:
        with atomic_write(tmp_path / "locked.bin") as fh:
            fh.write(b"x")  # pragma: no cover - never reached
    assert "locked.bin" in str(err.value) and "Permission denied" in str(err.value)


def _can_write_despite_mode(folder: Path) -> bool:
    try:
        fd, name = tempfile.mkstemp(dir=folder)
    except OSError:
        return False
    os.close(fd)
    os.unlink(name)
    return True


def test_read_only_folder(tmp_path: Path) -> None:
    from polcam.io.writers import write_image

    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        if _can_write_despite_mode(folder):
            pytest.skip("this user ignores folder permissions (root); covered by the mkstemp test")
        with pytest.raises(FrameWriteError) as err:
            write_image(folder / "d.exr", np.zeros((2, 2), np.float32))
        assert "d.exr" in str(err.value) and "Permission denied" in str(err.value)
    finally:
        folder.chmod(stat.S_IRWXU)
    assert _listing(folder) == []


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(FrameWriteError, match="does not exist"):
        with atomic_write(tmp_path / "nope" / "x.bin") as fh:
            fh.write(b"x")  # pragma: no cover


def test_target_is_a_folder(tmp_path: Path) -> None:
    (tmp_path / "dir.bin").mkdir()
    with pytest.raises(FrameWriteError, match="folder"):
        with atomic_write(tmp_path / "dir.bin") as fh:
            fh.write(b"x")  # pragma: no cover


def test_bad_mode() -> None:
    with pytest.raises(ValueError, match="mode"):
        with atomic_write("x", "ab"):
            pass  # pragma: no cover


def test_atomic_path_success_and_failures(tmp_path: Path) -> None:
    target = tmp_path / "img.tif"
    target.write_bytes(b"old")
    with atomic_path(target) as tmp:
        tmp.write_bytes(b"new image")
    assert target.read_bytes() == b"new image"
    assert _listing(tmp_path) == ["img.tif"]

    with pytest.raises(FrameWriteError, match="no data"):
        with atomic_path(target):
            pass  # the "library" wrote nothing
    with pytest.raises(KeyError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"partial")
            raise KeyError("library failed")
    assert target.read_bytes() == b"new image"
    assert _listing(tmp_path) == ["img.tif"]


def test_permissions_follow_umask_or_the_replaced_file(tmp_path: Path) -> None:
    new = tmp_path / "new.bin"
    with atomic_write(new) as fh:
        fh.write(b"a")
    mask = os.umask(0o022)
    os.umask(mask)
    assert stat.S_IMODE(new.stat().st_mode) == 0o666 & ~mask

    old = tmp_path / "old.bin"
    old.write_bytes(b"a")
    old.chmod(0o640)
    with atomic_write(old) as fh:
        fh.write(b"b")
    assert stat.S_IMODE(old.stat().st_mode) == 0o640


def test_process_killed_mid_write_leaves_target_intact(tmp_path: Path) -> None:
    target = tmp_path / "frame.raw"
    target.write_bytes(b"complete old frame")
    code = (
        "import os, sys\n"
        "from polcam.io.atomic import atomic_write\n"
        "with atomic_write(sys.argv[1]) as fh:\n"
        "    fh.write(b'x' * 100000)\n"
        "    fh.flush()\n"
        "    os._exit(3)\n"  # a crash: no clean-up code runs
    )
    proc = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True, timeout=60)
    assert proc.returncode == 3, proc.stderr.decode()
    assert target.read_bytes() == b"complete old frame"
    leftovers = [p for p in tmp_path.iterdir() if p.name != "frame.raw"]
    assert all(p.name.startswith(".frame.raw.") for p in leftovers)  # only a hidden temp may remain


def test_os_reason_names_the_system_error_and_looks_through_polcam_errors():
    from polcam.io.atomic import os_reason

    full = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert os_reason(full) == f"{os.strerror(errno.ENOSPC)} (ENOSPC)"
    try:
        raise FrameWriteError("writing failed", path="x") from full
    except FrameWriteError as exc:
        assert os_reason(exc) == f"{os.strerror(errno.ENOSPC)} (ENOSPC)"
    assert os_reason(ValueError("odd")) == "odd"


def test_probe_folder_creates_proves_and_cleans_up(tmp_path):
    from polcam.io.atomic import probe_folder

    folder = tmp_path / "a" / "b"
    free = probe_folder(folder)
    assert folder.is_dir() and list(folder.iterdir()) == []      # the probe is gone
    assert free is None or free > 0
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(FrameWriteError, match="cannot create the output folder: .*ENOTDIR"):
        probe_folder(blocker / "sub")
    with pytest.raises(FrameWriteError, match="cannot create the output folder: .*EEXIST"):
        probe_folder(blocker)
