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
