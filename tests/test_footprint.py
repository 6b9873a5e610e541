"""polcam.footprint: a frame's memory and disk estimates, sizes as text."""

from __future__ import annotations

import pytest

from polcam.footprint import frame_memory, output_bytes, parse_size


def test_parse_size():
    assert [parse_size(t) for t in ("0", "512", "64k", "1.5G", "8GiB", "2t")] == [
        0, 512, 64 << 10, 3 << 29, 8 << 30, 2 << 40]
    for bad in ("", "-1G", "lots", "1X"):
        with pytest.raises(ValueError, match="size"):
            parse_size(bad)


def test_frame_memory_figures():
    five_mp = frame_memory(2448, 2048, colour=True)                     # tensor, cell
    assert 1.1e9 < five_mp < 1.3e9
    assert frame_memory(2448, 2048, colour=True, resolution="full") > 3 * five_mp
    # the mono default runs the colour path on one channel's worth of pixels
    mono = frame_memory(2448, 2048, colour=False)
    assert five_mp / 2 < mono < five_mp
    assert frame_memory(2448, 2048, colour=True, method="imin") < five_mp
    assert frame_memory(2448, 2048, colour=False, method="imin") < mono


def test_output_bytes_is_the_uncompressed_products():
    assert output_bytes(64, 64, colour=True, resolution="full") == 64 * 64 * 4 * 5 * 3 + (64 << 10)
    assert output_bytes(64, 64, colour=False) == 32 * 32 * 4 * 5 + (64 << 10)
