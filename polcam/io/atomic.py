"""Atomic file output: a target is either fully written or left as it was.

Every file polcam writes goes first to a hidden temporary file in the *same
folder* as the target (so the final rename never crosses a file system), is
flushed and ``fsync``-ed, and only then renamed onto the target with
:func:`os.replace`, which is atomic on POSIX and Windows.  If anything fails
before the rename (an exception in the caller's code, a full disk, a library
error) the temporary file is removed and the target is untouched: a crash
never leaves a half-written output behind.

Two context managers:

:func:`atomic_write`
    yields an open file object, for code that writes bytes or text itself.
:func:`atomic_path`
    yields a temporary *path* with the target's extension, for libraries that
    write by file name and pick the format from the extension (OpenImageIO,
    :func:`numpy.save` given a name, ...).

Operating-system write errors (``ENOSPC``, ``EACCES``, ``EROFS``, ``EDQUOT``,
...) are turned into :class:`polcam.errors.FrameWriteError` naming the target
and the reason.  Other exceptions (a bug, ``KeyboardInterrupt``) propagate
unchanged after the clean-up.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
import threading
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import IO, Any

from polcam.errors import FrameWriteError, PolcamError

__all__ = ["atomic_path", "atomic_write", "fsync_dir", "os_reason", "probe_folder"]

_WRITE_MODES = ("w", "wb", "wt")

_umask_cache: int | None = None


def _umask() -> int:
    """The process umask, read without changing it where the system allows."""
    global _umask_cache
    if _umask_cache is None:
        value = None
        try:  # Linux: read it from /proc, no race with other threads
            with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
                for line in fh:
                    if line.startswith("Umask:"):
                        value = int(line.split()[1], 8)
                        break
        except OSError:
            value = None
        if value is None:  # portable fallback: set and restore
            value = os.umask(0o022)
            os.umask(value)
        _umask_cache = value
    return _umask_cache


def _final_mode(target: Path) -> int:
    """Permission bits the finished file gets: those of the file it replaces, else 0o666 & ~umask."""
    try:
        return target.stat().st_mode & 0o7777
    except OSError:
        return 0o666 & ~_umask()


def os_reason(exc: BaseException) -> str:
    """The system's reason of a failed write, e.g. ``No space left on device (ENOSPC)``.

    An OSError gives its message and errno name; a polcam error raised from one
    gives that OSError's; anything else its own text.
    """
    if isinstance(exc, OSError):
        reason = exc.strerror or str(exc)
        name = errno.errorcode.get(exc.errno) if exc.errno is not None else None
        return f"{reason} ({name})" if name else reason
    if isinstance(exc, PolcamError):
        if isinstance(exc.__cause__, OSError):
            return os_reason(exc.__cause__)
        return getattr(exc, "reason", None) or str(exc)
    return str(exc)


_describe = os_reason


def probe_folder(folder: str | PathLike[str], *, cannot: str = "cannot write to the output folder",
                 probe_bytes: int = 65536) -> int | None:
    """Create ``folder`` if needed and prove that files can be written there; its free bytes.

    A hidden probe file of ``probe_bytes`` is written, ``fsync``-ed and
    removed, so a read-only file system, a missing permission or a full disk
    is found before any work rather than after it.

    Returns
    -------
    int or None
        The bytes free for this user on the folder's file system (None where
        the platform cannot say).

    Raises
    ------
    FrameWriteError
        The folder cannot be created (a file of that name: EEXIST) or cannot be written;
        the message names the folder, starts with ``cannot`` and gives the
        system's reason.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FrameWriteError(f"cannot create the output folder: {os_reason(exc)}", path=folder) from exc
    probe = folder / f".polcam-probe-{os.getpid()}-{threading.get_ident()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        try:
            block = b"\0" * int(probe_bytes)
            if os.write(fd, block) != len(block):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        raise FrameWriteError(f"{cannot}: {os_reason(exc)}", path=folder) from exc
    finally:
        with contextlib.suppress(OSError):
            probe.unlink()
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):  # no statvfs (Windows): the probe has to do
        return None
    return st.f_bavail * st.f_frsize


def fsync_dir(folder: Path) -> None:
    """Make the rename durable; not every system can open a folder, so best effort."""
    flags = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)
    try:
        fd = os.open(folder, flags)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _remove_quietly(path: str | Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


def _make_temp(target: Path, *, suffix: str) -> tuple[int, str]:
    folder = target.parent
    if target.exists() and target.is_dir():
        raise FrameWriteError("cannot write: the target is a folder", path=target)
    if not folder.is_dir():
        raise FrameWriteError(f"cannot write: folder {str(folder)!r} does not exist", path=target)
    try:
        return tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix, dir=folder)
    except OSError as exc:
        raise FrameWriteError(f"cannot write: {_describe(exc)}", path=target) from exc


@contextlib.contextmanager
def atomic_write(
    path: str | PathLike[str], mode: str = "wb", *, encoding: str = "utf-8"
) -> Iterator[IO[Any]]:
    """Open a temporary file that replaces ``path`` when the block ends without error.

    Parameters
    ----------
    path
        The target file.  Its folder must exist.
    mode
        ``"wb"`` (bytes, default) or ``"w"``/``"wt"`` (text).
    encoding
        Text encoding for the text modes.

    Yields
    ------
    file object
        Open for writing; written data reaches ``path`` only after the block
        exits normally (flush, ``fsync``, :func:`os.replace`).

    Raises
    ------
    FrameWriteError
        Any :class:`OSError` while creating, writing, syncing or renaming
        (full disk, read-only folder, permission denied, ...); the message
        names ``path`` and the system's reason.  The target is left as it was
        and the temporary file is removed.
    ValueError
        For a mode other than the write modes above.
    """
    if mode not in _WRITE_MODES:
        raise ValueError(f"atomic_write mode {mode!r}: expected one of {', '.join(_WRITE_MODES)}")
    target = Path(path)
    fd, tmp = _make_temp(target, suffix=".tmp")
    try:
        if "b" in mode:
            fh: IO[Any] = os.fdopen(fd, "wb")
        else:
            fh = os.fdopen(fd, "w", encoding=encoding, newline="")
    except BaseException:
        os.close(fd)
        _remove_quietly(tmp)
        raise
    try:
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _final_mode(target))
        os.replace(tmp, target)
    except OSError as exc:
        _remove_quietly(tmp)
        raise FrameWriteError(f"cannot write: {_describe(exc)}", path=target) from exc
    except BaseException:
        _remove_quietly(tmp)
        raise
    fsync_dir(target.parent)


@contextlib.contextmanager
def atomic_path(path: str | PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path, beside ``path`` and with its extension, renamed onto it on success.

    For libraries that write by file name.  The library must create (or
    overwrite) the yielded path; when the block exits normally the file is
    ``fsync``-ed and renamed onto ``path``.

    Parameters
    ----------
    path
        The target file.  Its folder must exist.

    Yields
    ------
    pathlib.Path
        Hidden temporary file name in the target's folder, ending in the
        target's extension (libraries choose the format from it).  It exists
        (empty) when yielded.

    Raises
    ------
    FrameWriteError
        An :class:`OSError` while creating, syncing or renaming, or a block
        that left the temporary file missing or empty.  The target is left as
        it was and the temporary file is removed.
    """
    target = Path(path)
    fd, tmp = _make_temp(target, suffix=".tmp" + target.suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        try:
            size = os.path.getsize(tmp)
        except FileNotFoundError:
            size = -1
        if size <= 0:
            raise FrameWriteError("cannot write: the writer produced no data", path=target)
        wfd = os.open(tmp, os.O_RDWR)
        try:
            os.fsync(wfd)
        finally:
            os.close(wfd)
        os.chmod(tmp, _final_mode(target))
        os.replace(tmp, target)
    except OSError as exc:
        _remove_quietly(tmp)
        raise FrameWriteError(f"cannot write: {_describe(exc)}", path=target) from exc
    except BaseException:
        _remove_quietly(tmp)
        raise
    fsync_dir(target.parent)
