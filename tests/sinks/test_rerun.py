"""The Rerun sink: compact 8-bit encodings, entity paths, timelines, read back with Rerun's reader."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from polcam.sinks.rerun import (
    ENTITIES,
    RerunSink,
    aolp_ids,
    blueprint,
    dolp_ids,
    mosaic_u8,
    palettes,
    s0_u8,
    unit_u8,
)


def _read(path):
    """{entity: {"frames": set, "rows": [record batches]}} of a .rrd, static rows under "static"."""
    import rerun.chunk as ch

    out: dict[str, dict] = defaultdict(lambda: {"frames": set(), "batches": [], "static": []})
    for chunk in ch.RrdReader(path).stream():
        rb = chunk.to_record_batch()
        e = out[str(chunk.entity_path)]
        if chunk.is_static:
            e["static"].append(rb)
            continue
        e["batches"].append(rb)
        if "frame" in rb.schema.names:
            e["frames"] |= set(rb.column("frame").to_pylist())
    return out


def _image(batches, prefix, frame):
    for rb in batches:
        frames = rb.column("frame").to_pylist()
        if frame in frames:
            i = frames.index(frame)
            fmt = rb.column(f"{prefix}:format")[i].as_py()[0]
            buf = np.asarray(rb.column(f"{prefix}:buffer")[i].as_py()[0], dtype=np.uint8)
            return fmt, buf
    raise AssertionError(f"frame {frame} not logged")


def test_unit_u8_rounds_and_saturates():
    x = np.array([[-0.5, 0.0, 0.1, 0.5, 1.0, 1.7]], dtype=np.float32)
    expect = np.clip(np.rint(x.astype(np.float64) * 255), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(unit_u8(x), expect)
    np.testing.assert_array_equal(unit_u8(x, scale=0.5), np.clip(np.rint(x * 127.5), 0, 255).astype(np.uint8))
    rgb = np.stack([x, x * 0.5, x * 0.25], axis=-1)
    np.testing.assert_array_equal(unit_u8(rgb)[..., 2], np.clip(np.rint(x * 0.25 * 255), 0, 255).astype(np.uint8))
    # 16-bit fixed point and 8-bit display values
    q = np.array([[0, 8192, 16384, 30000]], dtype=np.uint16)
    np.testing.assert_array_equal(unit_u8(q, scale=1 / 16384), [[0, 128, 255, 255]])
    u = np.array([[0, 7, 255]], dtype=np.uint8)
    np.testing.assert_array_equal(unit_u8(u, scale=1 / 255), u)


def test_dolp_classes():
    d = np.array([[0.0, 0.5, 1.0, 1.5]], dtype=np.float32)
    np.testing.assert_array_equal(dolp_ids(d), [[1, 128, 255, 255]])


def test_aolp_classes_wrap_at_180_degrees():
    deg = np.array([[0.0, 45.0, 90.0, 179.4, 179.6]])
    ids = aolp_ids(np.deg2rad(deg).astype(np.float32))
    np.testing.assert_array_equal(ids, [[1, 46, 91, 180, 1]])  # 179.6 rounds to 180 = 0 degrees


def test_palettes_match_the_colour_maps():
    import matplotlib

    pal = palettes()
    dolp = {i: c for i, _, c in pal["dolp"]}
    assert sorted(dolp) == list(range(0, 256)) and dolp[0] == (0, 0, 0)  # 0: too dark to say
    vir = matplotlib.colormaps["viridis"]
    for i in (1, 64, 128, 200, 255):
        ref = np.array(vir((i - 1) / 254)[:3]) * 255
        assert np.abs(np.array(dolp[i]) - ref).max() <= 3, (i, dolp[i], ref)
    aolp = {i: (label, c) for i, label, c in pal["aolp"]}
    assert sorted(aolp) == list(range(0, 181)) and aolp[0][1] == (0, 0, 0)
    # AoLP a degrees is hue 2a: 0 red, 60 (hue 120) green, 120 (hue 240) blue
    assert aolp[1] == ("AoLP 0 deg", (255, 0, 0))
    assert aolp[61][1] == (0, 255, 0) and aolp[121][1] == (0, 0, 255)
    assert aolp[31][1] == (255, 255, 0)  # AoLP 30: hue 60, yellow


def test_mosaic_u8_keeps_the_top_bits():
    m = np.array([[0, 15, 16, 2048, 4095]], dtype=np.uint16)
    np.testing.assert_array_equal(mosaic_u8(m, bit_depth=12), np.rint(m / 16.0).clip(0, 255).astype(np.uint8))
    m8 = np.array([[3, 200]], dtype=np.uint8)
    np.testing.assert_array_equal(mosaic_u8(m8, bit_depth=8), m8)


def test_sink_writes_the_entities_of_the_design(tmp_path):
    path = tmp_path / "live.rrd"
    sink = RerunSink(path, raw_every=2, view_scale=0.5)
    rng = np.random.default_rng(3)
    ic = rng.random((8, 12)).astype(np.float32)
    dolp = rng.random((8, 12)).astype(np.float32)
    aolp = (rng.random((8, 12)) * np.pi).astype(np.float32)
    mosaic = rng.integers(0, 4096, (16, 24)).astype(np.uint16)
    for i in range(3):
        sink.log_raw(i, 1000 + i, mosaic, bit_depth=12)
        sink.log_polarization(i, 1000 + i, s0=2 * ic, dolp=dolp, aolp=aolp)
        sink.log_layers(i, 1000 + i, diffuse=ic * 0.5, specular=ic * 0.5)
        sink.log_stats(i, 1000 + i, fps=20.0, dropped=i, incomplete=0, separation_seconds=0.01,
                       maps_fps=15.0, layers_fps=1.5)
    sink.close()
    data = _read(path)
    assert set(ENTITIES.values()) <= set(data)
    for role in ("s0", "dolp", "aolp", "diffuse", "specular", "fps", "dropped", "incomplete",
                 "separation_seconds", "maps_fps", "layers_fps"):
        assert data[ENTITIES[role]]["frames"] == {0, 1, 2}, role
    assert data[ENTITIES["raw"]]["frames"] == {0, 2}  # every second frame
    # images are 8-bit at half the size given; DoLP is a class image with its palette static
    fmt, buf = _image(data[ENTITIES["s0"]]["batches"], "Image", 1)
    assert (fmt["width"], fmt["height"]) == (6, 4) and buf.size == 24
    expect = s0_u8(2 * ic).reshape(4, 2, 6, 2).astype(np.float64).mean(axis=(1, 3))
    assert np.abs(buf.reshape(4, 6) - expect).max() <= 1.0
    fmt, buf = _image(data[ENTITIES["raw"]]["batches"], "Image", 2)
    np.testing.assert_array_equal(buf.reshape(16, 24), mosaic_u8(mosaic, bit_depth=12))
    assert data[ENTITIES["dolp"]]["static"] and data[ENTITIES["aolp"]]["static"]
    fmt, buf = _image(data[ENTITIES["aolp"]]["batches"], "SegmentationImage", 0)
    np.testing.assert_array_equal(buf.reshape(4, 6), aolp_ids(aolp)[::2, ::2])  # nearest: no averaging
    batch = data[ENTITIES["dropped"]]["batches"][0]
    assert "device_time" in batch.schema.names


def test_sink_refuses_bad_targets_and_options(tmp_path):
    with pytest.raises(ValueError, match="rrd"):
        RerunSink(tmp_path / "live.txt")
    with pytest.raises(ValueError, match="view_scale"):
        RerunSink(tmp_path / "a.rrd", view_scale=2.0)
    with pytest.raises(ValueError, match="raw_every"):
        RerunSink(tmp_path / "b.rrd", raw_every=0)
    sink = RerunSink(tmp_path / "c.rrd")
    with pytest.raises(ValueError, match="unknown statistics"):
        sink.log_stats(0, None, frames_per_hour=1.0)
    sink.close()


def test_blueprint_views_every_image_entity():
    import rerun.blueprint as rrb

    def origins_of(bp):
        assert isinstance(bp, rrb.Blueprint)
        origins = {}

        def walk(node):
            for child in getattr(node, "contents", None) or []:
                if hasattr(child, "origin"):
                    origins[str(child.origin)] = type(child).__name__
                else:
                    walk(child)

        walk(bp.root_container)
        return origins

    for live in (True, False):
        origins = origins_of(blueprint(live=live))
        for role in ("raw", "s0", "dolp", "aolp", "aolp_dolp", "diffuse", "specular"):
            assert origins[ENTITIES[role]] == "Spatial2DView"
        assert (origins.get("/stats") == "TimeSeriesView") is live  # statistics for a live capture only


def test_s0_is_logged_as_s0_on_a_fixed_8_bit_scale():
    # S0 = (I0 + I45 + I90 + I135) / 2 is in [0, 2] for images in [0, 1]: code round(255 S0 / 2)
    s0 = np.array([[0.0, 0.5, 1.0, 2.0, 2.5]], dtype=np.float32)
    np.testing.assert_array_equal(s0_u8(s0), [[0, 64, 128, 255, 255]])
    # 8-bit Ic values (what the live colour maps hold) with the factor from Ic to S0
    ic = np.array([[0, 100, 255]], dtype=np.uint8)
    np.testing.assert_array_equal(s0_u8(ic, scale=2 / 255), ic)


def test_colour_dolp_and_aolp_are_those_of_the_luminance_weighted_stokes_vector():
    from polcam.polarimetry import aolp as st_aolp
    from polcam.polarimetry import dolp as st_dolp
    from polcam.polarimetry import stokes
    from polcam.sinks.rerun import luminance_orientation
    from polcam.synth.patterns import stack_from_stokes

    rng = np.random.default_rng(7)
    s0 = rng.uniform(0.2, 1.8, (5, 6, 3))
    dolp = rng.uniform(0.0, 1.0, (5, 6, 3))
    aolp = rng.uniform(0.0, np.pi, (5, 6, 3))
    stack = stack_from_stokes(s0, dolp, aolp).astype(np.float64)          # (4, 5, 6, 3)
    lum = stack @ np.array([0.25, 0.5, 0.25])                              # (R + 2G + B) / 4 per angle
    ref = stokes(lum)
    d, a = luminance_orientation(s0, dolp, aolp)
    np.testing.assert_allclose(d, st_dolp(ref), atol=1e-5)
    diff = np.angle(np.exp(2j * (a - st_aolp(ref)))) / 2
    assert np.abs(diff).max() < 1e-4
    assert a.min() >= 0 and a.max() < np.pi


def _images(path) -> dict[str, np.ndarray]:
    """{entity: frame 0's image as (h, w[, c]) uint8} of a .rrd, read back with Rerun's reader."""
    out = {}
    for entity, e in _read(path).items():
        for prefix in ("Image", "SegmentationImage"):
            if any(f"{prefix}:buffer" in rb.schema.names for rb in e["batches"]):
                fmt, buf = _image([rb for rb in e["batches"] if f"{prefix}:buffer" in rb.schema.names], prefix, 0)
                img = buf.reshape(fmt["height"], fmt["width"], -1)
                out[entity] = img[..., 0] if img.shape[2] == 1 else img
    return out


def test_the_same_frame_through_capture_and_process_logs_the_same_values(tmp_path):
    # one frame of a real mono sensor (fixtures/raw/fruits_crop, IMX250MZR, 8-bit): live capture
    # (replay camera, live maps, imin layers) and `polcam process --rerun` (demosaic, Stokes, imin,
    # files written and read back) must put the same values at every image entity path
    import shutil
    from pathlib import Path

    from polcam.acquisition import run_capture
    from polcam.camera.replay import ReplayCamera
    from polcam.cli import main

    fixtures = Path(__file__).resolve().parents[2] / "fixtures" / "raw"
    raw = tmp_path / "raw"
    raw.mkdir()
    for ext in (".png", ".json"):
        shutil.copy(fixtures / f"fruits_crop{ext}", raw / f"fruits_crop{ext}")
    live = tmp_path / "live.rrd"
    with ReplayCamera(raw) as cam:
        summary = run_capture(cam, out=None, separate="imin", rerun=live, raw_every=1, view_scale=1.0)
    assert summary["frames_processed"] == 1
    batch = tmp_path / "batch.rrd"
    assert main(["process", str(raw), "-o", str(tmp_path / "out"), "--method", "imin", "--workers", "1",
                 "--rerun", str(batch), "--quiet"]) == 0
    a, b = _images(live), _images(batch)
    roles = ("raw", "s0", "dolp", "aolp", "diffuse", "specular")
    assert {ENTITIES[r] for r in roles} <= set(a) and {ENTITIES[r] for r in roles} <= set(b)
    assert a[ENTITIES["raw"]].shape == (512, 640) and a[ENTITIES["s0"]].shape == (256, 320)
    for role in roles:
        x, y = a[ENTITIES[role]].astype(int), b[ENTITIES[role]].astype(int)
        assert x.shape == y.shape, role
        diff = np.abs(x - y)
        if role == "aolp":
            # classes wrap (1 and 180 are neighbours); the live AoLP comes from OpenCV's cartToPolar
            # (within ~0.005 degrees of arctan2): a pixel right at a class boundary may cross it
            diff = np.minimum(diff, 180 - diff)
            assert diff.max() <= 1 and (diff == 0).mean() > 0.999, (role, (diff == 0).mean())
            continue
        # the same formulas in float32 passes: exact halves round alike (TIE_BREAK), so all equal
        assert diff.max() == 0, (role, diff.max(), (diff == 0).mean())
    # and S0 is S0: the processed s0 file, on the code's scale
    from polcam.io import read_image

    s0_file, _ = read_image(tmp_path / "out" / "fruits_crop" / "s0.exr")
    np.testing.assert_array_equal(b[ENTITIES["s0"]], s0_u8(s0_file[..., 0] if s0_file.ndim == 3 else s0_file))
    assert 0.9 < s0_file.max() <= 2.0  # a bright scene: S0 above 1 exists, the code does not saturate below 2


def test_dolp_and_aolp_are_not_shown_where_s0_is_too_dark(tmp_path):
    from polcam.sinks.rerun import DARK_CODE

    path = tmp_path / "dark.rrd"
    sink = RerunSink(path, view_scale=1.0)
    s0 = np.array([[0.0, 2.4 / 127.5, 2.6 / 127.5, 1.0]], dtype=np.float32)  # codes 0, 2, 3, 128
    dolp = np.full((1, 4), 0.5, np.float32)
    aolp = np.full((1, 4), np.deg2rad(30.0), np.float32)
    sink.log_polarization(0, None, s0=s0, dolp=dolp, aolp=aolp)
    # colour: the brightest channel decides
    rgb = np.stack([s0, np.zeros_like(s0), np.zeros_like(s0)], axis=-1)
    sink.log_polarization(1, None, s0=rgb, dolp=np.repeat(dolp[..., None], 3, -1),
                          aolp=np.repeat(aolp[..., None], 3, -1))
    sink.close()
    data = _read(path)
    assert DARK_CODE == 3
    for frame in (0, 1):
        _, d = _image(data[ENTITIES["dolp"]]["batches"], "SegmentationImage", frame)
        _, a = _image(data[ENTITIES["aolp"]]["batches"], "SegmentationImage", frame)
        np.testing.assert_array_equal(d, [0, 0, 128, 128])
        np.testing.assert_array_equal(a, [0, 0, 31, 31])


def test_aolp_dolp_classes_and_palette():
    # hue 2 x AoLP as the AoLP map, value min(1, DoLP / 0.25) in 32 steps; colours against
    # colorsys's HSV -> RGB (an independent conversion)
    import colorsys

    from polcam.sinks.rerun import AOLP_DOLP_FULL, AOLP_DOLP_STEPS, aolp_dolp_ids

    assert (AOLP_DOLP_FULL, AOLP_DOLP_STEPS) == (0.25, 32)
    deg = np.array([[0.0, 60.0, 60.0, 60.0, 179.6, 90.0]])
    dolp = np.array([[0.5, 0.0, 0.125, 0.3, 1.0, 0.0161]], dtype=np.float32)
    ids = aolp_dolp_ids(np.deg2rad(deg).astype(np.float32), dolp)
    assert ids.dtype == np.uint16
    # 0.125 is level 15.5: halves round up; 0.0161 is level 1.996 -> 2
    np.testing.assert_array_equal(ids, [[1 + 180 * 31, 61, 61 + 180 * 16, 61 + 180 * 31, 1 + 180 * 31, 91 + 180 * 2]])
    pal = {i: (label, c) for i, label, c in palettes()["aolp_dolp"]}
    assert sorted(pal) == list(range(0, 180 * 32 + 1)) and pal[0][1] == (0, 0, 0)
    for a in range(0, 180, 7):
        for k in range(32):
            ref = np.array(colorsys.hsv_to_rgb(2 * a / 360, 1.0, k / 31)) * 255
            got = np.array(pal[1 + a + 180 * k][1])
            assert np.abs(got - ref).max() <= 2, (a, k, got, ref)
    assert pal[61 + 180 * 16][0] == "AoLP 60 deg, DoLP 0.129"
    assert pal[61 + 180 * 31][0] == "AoLP 60 deg, DoLP >= 0.250" and pal[61 + 180 * 31][1] == (0, 255, 0)
    assert pal[61][1] == (0, 0, 0)  # unpolarized: no colour, whatever its angle


def test_aolp_dolp_is_logged_and_masked_where_dark(tmp_path):
    from polcam.sinks.rerun import aolp_dolp_ids

    path = tmp_path / "both.rrd"
    sink = RerunSink(path, view_scale=1.0)
    s0 = np.array([[0.0, 2.4 / 127.5, 2.6 / 127.5, 1.0]], dtype=np.float32)  # codes 0, 2, 3, 128
    dolp = np.array([[0.5, 0.5, 0.05, 0.2]], np.float32)
    aolp = np.deg2rad(np.array([[30.0, 30.0, 100.0, 150.0]])).astype(np.float32)
    sink.log_polarization(0, None, s0=s0, dolp=dolp, aolp=aolp)
    sink.close()
    data = _read(path)
    assert data[ENTITIES["aolp_dolp"]]["static"]  # its palette
    for rb in data[ENTITIES["aolp_dolp"]]["batches"]:
        fmt = rb.column("SegmentationImage:format")[0].as_py()[0]
        raw = np.asarray(rb.column("SegmentationImage:buffer")[0].as_py()[0], dtype=np.uint8)
    got = raw.view("<u2").reshape(fmt["height"], fmt["width"])
    expect = aolp_dolp_ids(aolp, dolp)
    expect[0, :2] = 0  # too dark to have an orientation
    np.testing.assert_array_equal(got, expect)
    assert got[0, 2] == 101 + 180 * round(0.05 / 0.25 * 31) and got[0, 3] == 151 + 180 * 25
