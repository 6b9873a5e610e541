"""Finding raw frame files in folders: the one listing that process, stokes, demo and calibrate use."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from polcam.errors import FrameReadError
from polcam.io.readers import RAW_EXTENSIONS

__all__ = ["is_raw_file", "list_raw_files", "raw_files_in"]


def is_raw_file(path: Path) -> bool:
    """True for a visible file with a raw frame extension (sidecars ``.json`` and hidden temporaries are not)."""
    return path.is_file() and path.suffix.lower() in RAW_EXTENSIONS and not path.name.startswith(".")


def raw_files_in(folder: str | Path, *, recursive: bool = False) -> list[Path]:
    """The raw frame files of one folder, sorted by path (sub-folders too with ``recursive``)."""
    folder = Path(folder)
    it = folder.rglob("*") if recursive else folder.iterdir()
    return sorted(f for f in it if is_raw_file(f))


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
