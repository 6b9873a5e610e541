"""polcam.io.listing: the one listing of raw frame files."""

from __future__ import annotations

import pytest

from polcam.errors import FrameReadError
from polcam.io.listing import list_raw_files, raw_files_in


def test_folders_expanded_sorted_sidecars_and_hidden_skipped(tmp_path):
    for name in ("b.png", "a.raw", "a.json", ".a.tmp.png", "notes.txt", "sub/c.npy"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in raw_files_in(tmp_path)] == ["a.raw", "b.png"]
    assert [p.name for p in raw_files_in(tmp_path, recursive=True)] == ["a.raw", "b.png", "c.npy"]
    single = tmp_path / "notes.txt"
    assert list_raw_files([single, tmp_path]) == [single, tmp_path / "a.raw", tmp_path / "b.png"]


def test_missing_path_is_named(tmp_path):
    with pytest.raises(FrameReadError, match="nowhere: no such file or folder"):
        list_raw_files([tmp_path / "nowhere"])
    assert list_raw_files([]) == []


def test_recursive_follows_folder_links_and_names_loops_and_dangling_links(tmp_path):
    import os

    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.png").write_bytes(b"x")
    os.symlink("a", tmp_path / "b")                        # a link to a folder: followed
    os.symlink("..", tmp_path / "a" / "up")                # back to an ancestor: a loop
    os.symlink("nowhere.png", tmp_path / "a" / "gone.png")  # dangling
    skipped: list = []
    found = raw_files_in(tmp_path, recursive=True, skipped=skipped)
    assert [p.relative_to(tmp_path).as_posix() for p in found] == ["a/x.png", "b/x.png"]
    reasons = {p.relative_to(tmp_path).as_posix(): why for p, why in skipped}
    assert reasons["a/up"] == f"symbolic link loop: it leads back to {tmp_path}"
    assert reasons["b/up"] == f"symbolic link loop: it leads back to {tmp_path}"
    assert reasons["a/gone.png"] == "dangling symbolic link to nowhere.png"
