"""Tests of polcam.io.packing against hand-computed bytes and bit-level references."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import FrameReadError, FrameWriteError, PixelFormatError
from polcam.io.packing import PACKING_BITS, pack, packed_size, unpack
from polcam.mosaic import PACKINGS, PIXEL_FORMATS

# --------------------------------------------------------------------------
# Independent references, written from the format descriptions (bit by bit,
# pure Python, no numpy): PFNC "p" formats are an LSB-first bit stream, the
# GigE Vision "Packed" formats a byte table per pixel pair.


def ref_lsb_stream(values: list[int], bits: int) -> bytes:
    """PFNC lsb packing: pixel k occupies bits k*bits .. k*bits+bits-1 of the little-endian stream."""
    acc = 0
    for k, v in enumerate(values):
        acc |= int(v) << (k * bits)
    return acc.to_bytes((len(values) * bits + 7) // 8, "little")


def ref_gige_packed(values: list[int], bits: int) -> bytes:
    """GigE Vision MonoNPacked: B0 = p0 high 8 bits, B1 = p1 low bits << 4 | p0 low bits, B2 = p1 high 8."""
    low = bits - 8
    mask = (1 << low) - 1
    out = bytearray()
    for p0, p1 in zip(values[0::2], values[1::2]):
        out += bytes([p0 >> low, ((p1 & mask) << 4) | (p0 & mask), p1 >> low])
    return bytes(out)


def reference_pack(values: list[int], packing: str) -> bytes:
    if packing == "8":
        return bytes(values)
    if packing == "16":
        return b"".join(int(v).to_bytes(2, "little") for v in values)
    if packing in ("10p", "12p"):
        return ref_lsb_stream(values, PACKING_BITS[packing])
    return ref_gige_packed(values, PACKING_BITS[packing])


# --------------------------------------------------------------------------
# Hand-computed byte patterns (from the byte tables in the module docstring,
# worked out on paper for these values).
HAND = [
    ("8", [0xAB, 0x12], "ab12"),
    ("16", [0xABC, 0x123], "bc0a2301"),
    # Mono12p: B0 = p0[7:0] = BC, B1 = p1[3:0]<<4 | p0[11:8] = 3A, B2 = p1[11:4] = 12
    ("12p", [0xABC, 0x123], "bc3a12"),
    # Mono12Packed: B0 = p0[11:4] = AB, B1 = p1[3:0]<<4 | p0[3:0] = 3C, B2 = p1[11:4] = 12
    ("12packed", [0xABC, 0x123], "ab3c12"),
    # Mono10p, p = 2AB, 155, 3C0, 00F:
    #   B0 = p0[7:0] = AB; B1 = p1[5:0]<<2 | p0[9:8] = 15<<2 | 2 = 56; B2 = p2[3:0]<<4 | p1[9:6] = 05;
    #   B3 = p3[1:0]<<6 | p2[9:4] = C0 | 3C = FC; B4 = p3[9:2] = 03
    ("10p", [0x2AB, 0x155, 0x3C0, 0x00F], "ab5605fc03"),
    # Mono10Packed: B0 = p0[9:2] = AA, B1 = p1[1:0]<<4 | p0[1:0] = 13, B2 = p1[9:2] = 55
    ("10packed", [0x2AB, 0x155], "aa1355"),
]


@pytest.mark.parametrize("packing,values,hexbytes", HAND)
def test_hand_computed_bytes(packing: str, values: list[int], hexbytes: str) -> None:
    want = bytes.fromhex(hexbytes)
    assert reference_pack(values, packing) == want  # the reference agrees with the paper work
    assert pack(np.array(values, dtype=np.uint16), packing=packing) == want
    got = unpack(want, packing=packing, width=len(values), height=1)
    assert got.tolist() == [values]


def test_every_registered_packing_is_covered() -> None:
    assert set(PACKINGS) == {p for p, _, _ in HAND}
    assert {f.packing for f in PIXEL_FORMATS.values()} <= set(PACKINGS)


@pytest.mark.parametrize("packing", PACKINGS)
def test_random_frames_match_reference(packing: str) -> None:
    rng = np.random.default_rng(7)
    bits = PACKING_BITS[packing]
    h, w = 6, 10
    values = rng.integers(0, 1 << bits, size=(h, w))
    values[0, :4] = [0, (1 << bits) - 1, 1, 1 << (bits - 1)]  # extremes and single bits
    want = reference_pack(values.ravel().tolist(), packing)
    packed = pack(values.astype(np.uint16), packing=packing)
    assert packed == want
    assert len(packed) == packed_size(packing, h * w)
    out = unpack(packed, packing=packing, width=w, height=h)
    assert out.dtype == (np.uint8 if packing == "8" else np.uint16)
    assert out.shape == (h, w)
    np.testing.assert_array_equal(out, values)


@pytest.mark.parametrize("packing", ["10p", "12p", "12packed", "10packed"])
def test_partial_last_group(packing: str) -> None:
    # 3 pixels: not a whole group for 10p (4) nor for the 2-pixel packings
    values = [(1 << PACKING_BITS[packing]) - 1, 5, 0x0F0 & ((1 << PACKING_BITS[packing]) - 1)]
    packed = pack(np.array(values), packing=packing)
    assert len(packed) == packed_size(packing, 3)
    if packing in ("10p", "12p"):
        assert packed == ref_lsb_stream(values, PACKING_BITS[packing])
    np.testing.assert_array_equal(unpack(packed, packing=packing, width=3, height=1)[0], values)


def test_packed_size_matches_pixel_format_frame_bytes() -> None:
    for fmt in PIXEL_FORMATS.values():
        for w, h in ((2448, 2048), (6, 4), (3, 1)):
            channels = 4 if fmt.kind == "angles" else 1
            assert packed_size(fmt.packing, w * h * channels) == fmt.frame_bytes(w, h)


def test_channels_are_pixel_interleaved() -> None:
    planes = np.arange(2 * 3 * 4, dtype=np.uint16).reshape(2, 3, 4) * 100
    data = pack(planes, packing="12p")
    out = unpack(data, packing="12p", width=3, height=2, channels=4)
    assert out.shape == (2, 3, 4)
    np.testing.assert_array_equal(out, planes)
    # pixel (0, 1) channel 2 is value index (0*3 + 1)*4 + 2 = 6 of the stream
    assert out[0, 1, 2] == planes.ravel()[6]


def test_unpack_accepts_uint8_array_and_returns_writable_copy() -> None:
    raw = np.frombuffer(bytes.fromhex("bc3a12"), dtype=np.uint8)
    out = unpack(raw, packing="12p", width=2, height=1)
    out[0, 0] = 7  # must not raise (not a view of read-only bytes)
    raw8 = bytes([1, 2, 3, 4])
    out8 = unpack(raw8, packing="8", width=2, height=2)
    out8[0, 0] = 9
    assert raw8 == bytes([1, 2, 3, 4])


@pytest.mark.parametrize("packing", ["12p", "10p", "12packed"])
def test_unpack_views_into_larger_or_strided_buffers(packing: str) -> None:
    values = np.random.default_rng(3).integers(0, 1 << PACKING_BITS[packing], size=(2, 8))
    data = pack(values, packing=packing)
    framed = np.frombuffer(b"HDR" + data + b"TAIL", dtype=np.uint8)[3:-4]  # a view at an odd offset
    np.testing.assert_array_equal(unpack(framed, packing=packing, width=8, height=2), values)
    spread = np.zeros(2 * len(data), dtype=np.uint8)
    spread[::2] = np.frombuffer(data, dtype=np.uint8)
    np.testing.assert_array_equal(unpack(spread[::2], packing=packing, width=8, height=2), values)


def test_wrong_byte_count_message() -> None:
    with pytest.raises(FrameReadError) as err:
        unpack(bytes(10), packing="12p", width=4, height=2, path="cam/frame_7.raw")
    msg = str(err.value)
    assert "frame_7.raw" in msg
    assert "expected 12 bytes" in msg and "found 10 bytes" in msg and "4x2" in msg


def test_unknown_packing_lists_supported() -> None:
    with pytest.raises(PixelFormatError) as err:
        unpack(bytes(4), packing="14p", width=2, height=1)
    assert "'14p'" in str(err.value) and "12packed" in str(err.value)
    with pytest.raises(PixelFormatError):
        pack(np.zeros(2, np.uint16), packing="14p")


@pytest.mark.parametrize("bad", [0, -2, 2.0, True])
def test_bad_sizes(bad: object) -> None:
    with pytest.raises(FrameReadError, match="width"):
        unpack(bytes(4), packing="8", width=bad, height=2)  # type: ignore[arg-type]


def test_bad_data_types() -> None:
    with pytest.raises(FrameReadError, match="uint8"):
        unpack(np.zeros(4, dtype=np.uint16), packing="8", width=2, height=2)
    with pytest.raises(FrameReadError, match="bytes"):
        unpack([1, 2, 3, 4], packing="8", width=2, height=2)  # type: ignore[arg-type]


@pytest.mark.parametrize("packing,value", [("12p", 4096), ("10p", 1024), ("8", 256), ("16", 65536),
                                           ("12packed", -1)])
def test_pack_refuses_values_that_do_not_fit(packing: str, value: int) -> None:
    with pytest.raises(FrameWriteError) as err:
        pack(np.array([0, value], dtype=np.int64), packing=packing)
    assert str(value) in str(err.value) and packing in str(err.value)


def test_pack_refuses_floats() -> None:
    with pytest.raises(FrameWriteError, match="float"):
        pack(np.zeros(4), packing="16")


def test_full_frame_12p_round_trip() -> None:
    """A whole 2448x2048 sensor frame (speed is measured in docs/benchmarks.md, not asserted)."""
    w, h = 2448, 2048
    rng = np.random.default_rng(1)
    values = rng.integers(0, 4096, size=(h, w), dtype=np.uint16)
    data = pack(values, packing="12p")
    assert len(data) == w * h * 3 // 2
    np.testing.assert_array_equal(unpack(data, packing="12p", width=w, height=h), values)
