"""Finding raw frame files in folders: the one listing that process, stokes, demo and calibrate use."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from polcam.errors import FrameReadError
from polcam.io.readers import RAW_EXTENSIONS

__all__ = ["is_raw_file", "list_raw_files", "raw_files_in"]


def is_raw_file(path: Path) -> bool:
    """True for a visible file with a raw frame extension (sidecars ``.json`` and hidden temporaries are not)."""
    return path.is_file() and path.suffix.lower() in RAW_EXTENSIONS and not path.name.startswith(".")


def raw_files_in(folder: str | Path, *, recursive: bool = False,
                 skipped: list[tuple[Path, str]] | None = None) -> list[Path]:
    """The raw frame files of one folder, sorted by path (sub-folders too with ``recursive``).

    With ``recursive``, symbolic links to folders are followed, except a link
    back to a folder it sits in (a loop); such links, dangling links and
    unreadable folders are left out and, when ``skipped`` is given, appended
    to it as ``(path, reason)``.
    """
    folder = Path(folder)
    if not recursive:
        return sorted(f for f in folder.iterdir() if is_raw_file(f))
    out: list[Path] = []

    def note(path: Path, why: str) -> None:
        if skipped is not None:
            skipped.append((path, why))

    def walk(d: Path, ancestors: dict[tuple[int, int], Path]) -> None:
        try:
            entries = sorted(os.scandir(d), key=lambda e: e.name)
        except OSError as exc:
            note(d, f"cannot list the folder: {exc.strerror or exc}")
            return
        for e in entries:
            path = Path(e.path)
            try:
                if e.is_dir():
                    st = path.stat()
                    key = (st.st_dev, st.st_ino)
                    if key in ancestors:
                        note(path, f"symbolic link loop: it leads back to {ancestors[key]}")
                        continue
                    walk(path, {**ancestors, key: path})
                elif is_raw_file(path):
                    out.append(path)
                elif e.is_symlink() and not path.exists():
                    note(path, f"dangling symbolic link to {os.readlink(path)}")
            except OSError as exc:  # ELOOP of a link to itself, permissions
                note(path, f"skipped: {exc.strerror or exc}")

    st = folder.stat()
    walk(folder, {(st.st_dev, st.st_ino): folder})
    return sorted(out)


def list_raw_files(paths: Iterable[str | Path], *, recursive: bool = False) -> list[Path]:
    """Raw frame files among ``paths``: folders expanded (:func:`raw_files_in`), files kept as given.

    Parameters
    ----------
    paths
        Files and folders, in the order given.
    recursive
        Descend into sub-folders.

    Returns
    -------
    list of pathlib.Path
        Possibly empty (a caller decides whether no frames is an error).

    Raises
    ------
    FrameReadError
        A path that is neither a file nor a folder (named in the message).
    """
    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            out += raw_files_in(p, recursive=recursive)
        elif p.is_file():
            out.append(p)
        else:
            raise FrameReadError("no such file or folder", path=p)
    return out
