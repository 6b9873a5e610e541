"""The tensor methods end to end: contract, solvers, tiles, workers, and the torch pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.polarimetry import synthesize
from polcam.separation import separate
from polcam.separation.tensor import FAST_TOL, separate_tensor, tile_windows
from polcam.separation.tensor.driver import initial_diffuse


def _scene(n=16):
    yy, xx = np.mgrid[0:n, 0:n] / n
    albedo = np.where((xx < 0.5)[..., None], [0.6, 0.25, 0.15], [0.15, 0.35, 0.6])
    D = albedo * (0.6 + 0.4 * np.cos(2 * (xx - 0.5)))[..., None]
    lobe = 0.5 * np.exp(-((xx - 0.45) ** 2 + (yy - 0.4) ** 2) / (2 * 0.1 ** 2))
    spec = lobe[..., None] * np.ones(3)
    phi = np.repeat(((np.arctan2(yy - 0.5, xx - 0.5) + np.pi / 2) % np.pi)[..., None], 3, -1)
    return np.clip(synthesize(D + spec, 0.7 * spec, phi), 0, 1), D


@pytest.mark.parametrize("method", ["tensor", "tensor-tau", "tensor-plain"])
def test_tensor_methods_end_to_end(method):
    stack, D = _scene()
    res = separate(stack, method=method, max_iter=60)
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == (16, 16, 3) and res.diffuse.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert np.all(res.diffuse >= 0) and np.all(res.diffuse <= mean + 1e-6)
    err_in = np.mean((mean - D) ** 2)
    err_out = np.mean((res.diffuse - D) ** 2)
    assert err_out < 0.25 * err_in                # > 6 dB better than doing nothing
    info = res.info
    assert info["iterations"] >= 1 and len(info["residuals"]) == info["iterations"]
    assert info["variant"] == method and "converged" in info and "residual" in info
    # deterministic with the seed
    again = separate(stack, method=method, max_iter=60)
    np.testing.assert_array_equal(again.diffuse, res.diffuse)


def test_tensor_refuses_what_it_cannot_use():
    stack, _ = _scene(8)
    with pytest.raises(MethodError, match="needs colour"):
        separate(stack[..., 0], method="tensor")
    with pytest.raises(MethodError, match="polarization stack"):
        separate(stack[0], method="tensor")
    # the dispatcher refuses it first, naming the options (the registered option list)
    with pytest.raises(MethodError, match="takes no option 'n5'; its options: n4, block"):
        separate(stack, method="tensor", n5=3)
    with pytest.raises(MethodError, match="unknown option"):          # called directly
        separate_tensor(stack, n5=3)
    with pytest.raises(MethodError, match="not a single-image method"):
        separate(stack, method="tensor", init="tensor")


def test_dark_input_gives_zero():
    res = separate(np.zeros((4, 8, 8, 3)), method="tensor")
    assert np.all(res.diffuse == 0) and res.info["converged"]


def test_fast_and_exact_agree_on_a_small_scene():
    """float64, the paper's initialisation: the fast solver's only departure is its randomized
    subspace (measured <= 5e-6 here); float32 and the shared initialisation (the defaults): Gram
    eigenvalues resolve singular values to sqrt(eps32) ~ 2.4e-4 of the largest and the run stops at
    FAST_TOL: within 1e-2 of a [0, 1] image, and an RMS difference 20 dB below the input's error."""
    stack, D = _scene(20)
    for method in ("tensor", "tensor-plain"):
        exact = separate(stack, method=method, solver="exact")
        f64 = separate(stack, method=method, solver="fast", precision="float64", tol=1e-5,
                       shared_init=False)
        np.testing.assert_allclose(f64.diffuse, exact.diffuse, atol=5e-5)
        assert f64.info["iterations"] == exact.info["iterations"]
        f32 = separate(stack, method=method)
        assert f32.info["solver"] == "fast" and f32.info["tol"] == FAST_TOL
        np.testing.assert_allclose(f32.diffuse, exact.diffuse, atol=1e-2)
        rms = np.sqrt(np.mean((f32.diffuse - exact.diffuse) ** 2))
        assert rms < 0.1 * np.sqrt(np.mean((stack.mean(axis=0) - D) ** 2))


def test_tiling_reproduces_the_untiled_result_when_the_input_fits_one_tile():
    stack, _ = _scene(16)
    whole = separate(stack, method="tensor", tile=None)
    for tile in (16, 40):
        one = separate(stack, method="tensor", tile=tile, overlap=4)
        np.testing.assert_array_equal(one.diffuse, whole.diffuse)
        assert one.info["tiles"] == 1 and one.info["tile"] is None


def test_tiled_separation_keeps_the_contract_and_does_not_depend_on_workers():
    stack, D = _scene(24)
    one = separate(stack, method="tensor", tile=12, overlap=4, workers=1)
    two = separate(stack, method="tensor", tile=12, overlap=4, workers=2)
    np.testing.assert_array_equal(one.diffuse, two.diffuse)
    info = one.info
    assert info["tiles"] == 9 and info["tile"] == [12, 12, 4] and len(info["iterations_per_tile"]) == 9
    assert info["iterations"] == max(info["iterations_per_tile"]) == len(info["residuals"])
    mean = stack.mean(axis=0)
    np.testing.assert_allclose(one.diffuse + one.specular, mean, atol=1e-6)
    assert np.all(one.diffuse >= 0) and np.all(one.diffuse <= mean + 1e-6)
    assert np.mean((one.diffuse - D) ** 2) < 0.25 * np.mean((mean - D) ** 2)


def test_rectangular_tiles_separate():
    stack, D = _scene(24)
    got = separate(stack, method="tensor", tile=(24, 12), overlap=4, workers=1)
    assert got.info["tile"] == [24, 12, 4] and got.info["tiles"] == len(tile_windows((24, 24), (24, 12), 4))
    mean = stack.mean(axis=0)
    assert np.mean((got.diffuse - D) ** 2) < 0.25 * np.mean((mean - D) ** 2)


def test_workers_agree_with_a_thread_running():
    """The tiles run in threads of this process: a thread running beside them changes nothing."""
    import threading

    stack, _ = _scene(24)
    alone = separate(stack, method="tensor", tile=12, overlap=4, workers=2)
    release = threading.Event()
    other = threading.Thread(target=release.wait, daemon=True)
    other.start()
    try:
        with_thread = separate(stack, method="tensor", tile=12, overlap=4, workers=2)
    finally:
        release.set()
        other.join()
    np.testing.assert_array_equal(with_thread.diffuse, alone.diffuse)


def test_initial_diffuse_in_the_background_gives_the_same_answer():
    # from 256 x 256 the four Yang'10 runs of the shared initial diffuse start in worker
    # processes before the representations are found; one worker runs them in turn afterwards
    stack, _ = _scene(256)
    kw = dict(tile=(128, 128), max_iter=3)
    one = separate(stack, method="tensor", workers=1, **kw)
    two = separate(stack, method="tensor", workers=2, **kw)
    np.testing.assert_array_equal(two.diffuse, one.diffuse)
    assert two.info["tiles"] == 9 and two.info["iterations"] == 3


def test_initial_diffuse_is_the_single_image_method_on_each_image():
    from polcam.separation.yang10 import separate_yang10

    stack, _ = _scene(16)
    reps = np.stack([stack, stack[:, ::-1]])
    got = initial_diffuse(reps, workers=2)
    for i in range(2):
        for a in range(4):
            want, _ = separate_yang10(np.clip(reps[i, a], 0, 1))
            np.testing.assert_allclose(got[i, a], np.clip(want, 0, reps[i, a]), atol=1e-12)


def _yellow_scene(h=96, w=160, seed=0):
    """Shaded yellow blocks with dark holes and a broad polarized white highlight: (stack, diffuse)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    shade = 0.55 + 0.35 * np.cos(1.3 * (xx - 0.4)) * np.cos(1.1 * (yy - 0.3))
    holes = ((np.mod(xx * w, 24) - 12) ** 2 + (np.mod(yy * w, 24) - 12) ** 2) < 16
    D = np.array([0.7, 0.55, 0.1]) * (shade * np.where(holes, 0.4, 1.0))[..., None]
    S = 0.35 * np.exp(-((xx - 0.55) ** 2 / 0.08 + (yy - 0.45) ** 2 / 0.05))[..., None] * np.ones(3)
    phi = np.repeat((0.5 + 0.8 * xx + 0.3 * yy)[..., None], 3, -1) % np.pi
    stack = synthesize(D + S, 0.8 * S, phi) + rng.normal(0, 0.004, (4, h, w, 3))
    return np.clip(stack, 0, 1), D


def test_no_seams_at_tile_borders_with_the_default_overlap():
    """Planted truth: the error of the diffuse jumps no more across tile borders than inside tiles
    (measured 1.09 with the default overlap)."""
    from polcam.separation.tensor.tiling import seam_jumps

    stack, D = _yellow_scene()
    got = separate(stack, method="tensor", tile=(48, 16), workers=1)
    assert got.info["tile"] == [48, 16, 6] and got.info["tiles"] > 20
    b, i = seam_jumps(got.diffuse - D, tile=(48, 16), overlap=6)
    assert b < 1.15 * i


@pytest.mark.slow
def test_no_seams_on_a_real_stack():
    """jcpd-15's yellow blocks, mosaicked and demosaiced: the share of the light the diffuse keeps
    jumps across the 96 x 32 tiles' borders as inside them with the default overlap (1.02; the
    input's own ratio 1.04), not with the former overlap of 2 (1.11)."""
    from polcam.demosaicing import demosaic, mosaic_stack
    from polcam.separation.tensor.tiling import seam_jumps

    full = _real_crop(whole=True)
    dem = np.clip(demosaic(mosaic_stack(full, layout="imx250myr"), layout="imx250myr"), 0, 1)
    crop = np.ascontiguousarray(dem[:, 284:540, 110:398])
    ratios = {}
    for ov in (2, None):
        res = separate(crop, method="tensor", **({} if ov is None else {"overlap": ov}))
        tile = res.info["tile"]
        b, i = seam_jumps(res.diffuse, tile=tile[:2], overlap=tile[2], reference=crop.mean(axis=0))
        ratios[ov] = b / i
    assert ratios[None] < 1.06 < ratios[2]


def _real_crop(whole=False):
    from pathlib import Path

    import cv2

    root = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "real-color-stacks" / "jcpd-15"
    if not (root / "0.png").exists():
        pytest.skip("real stacks not found (../shared/data)")
    ims = []
    for a in (0, 45, 90, 135):
        im = cv2.imread(str(root / f"{a}.png"), cv2.IMREAD_UNCHANGED)
        ims.append(im[..., ::-1].astype(np.float64) / (255.0 if im.dtype == np.uint8 else 65535.0))
    stack = np.stack(ims)
    return stack if whole else np.ascontiguousarray(stack[:, 380:444, 300:364])


def test_imin_bound_is_an_option_off_by_default():
    """With ``imin_bound=True`` the diffuse never exceeds the minimum of its stack's sinusoid;
    without it (the paper's method) it may, and ``above_imin`` reports how often."""
    from polcam.polarimetry import imin

    stack, D = _scene(20)                           # planted truth: D <= Imin everywhere
    assert np.all(D <= imin(stack) + 1e-12)
    for kw in ({}, {"solver": "exact"}, {"tile": 12, "overlap": 4, "workers": 1}):
        res = separate(stack, method="tensor", imin_bound=True, **kw)
        assert np.all(res.diffuse <= imin(stack) + 1e-6) and np.all(res.diffuse >= 0)
        assert res.info["clipped_to_imin"] == res.info["above_imin"]
        assert 0 <= res.info["above_imin"] <= 1
    # a real stack: the tensor diffuse exceeds Imin on many pixels (7-22 % of real scenes by more
    # than 3/255); the default leaves it there, the bound clips it
    real = _real_crop()
    free = separate(real, method="tensor")
    bound = separate(real, method="tensor", imin_bound=True)
    assert free.info["options"]["imin_bound"] is False and free.info["clipped_to_imin"] == 0.0
    assert free.info["above_imin"] > 0.01 and bound.info["clipped_to_imin"] == free.info["above_imin"]
    assert np.mean(free.diffuse > np.maximum(imin(real), 0) + 1e-3) > 0.005
    assert np.all(bound.diffuse <= np.maximum(imin(real), 0) + 1e-6)
    # the bound only lowers: where the free diffuse is under Imin, both agree
    under = np.all(free.diffuse <= np.maximum(imin(real), 0), axis=-1)
    np.testing.assert_allclose(bound.diffuse[under], free.diffuse[under], atol=1e-6)
    with pytest.raises(MethodError, match=r"imin_bound[ =]1"):
        separate(stack, method="tensor", imin_bound=1)


# ---------------------------------------------------------------------------
# the same pipeline on a torch device
# ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bunny() -> np.ndarray:
    from polcam.synth.render import render
    from polcam.synth.scenes import scene

    return render(scene("Bunny6"), size=72, seed=3).stack


def _psnr(a, b):
    from polcam.bench.quality import psnr

    return psnr(a, b)


@pytest.mark.parametrize("variant", ["tensor", "tensor-plain"])
def test_device_pipeline_matches_numpy_tiled(bunny, variant, dev):
    # tiled, so the blend and the per-tile batches are exercised end to end
    a = separate(bunny, method=variant, tile=(40, 24), workers=1)
    b = separate(bunny, method=variant, tile=(40, 24), device=dev)
    assert b.info["tiles"] == a.info["tiles"] > 1 and b.info["device"] == dev
    assert b.info["representations_filled"] == pytest.approx(a.info["representations_filled"])
    np.testing.assert_allclose(b.info["illuminant_chromaticity"], a.info["illuminant_chromaticity"],
                               rtol=1e-9)
    assert _psnr(b.diffuse, a.diffuse) > 70                   # float32 solvers, same problem
    assert set(b.info["timings"]) == {"illuminant", "representations", "init", "ialm"}


@pytest.mark.parametrize("init,shared", [("shen09", False), ("shen09", True), ("yang10", False)])
def test_device_pipeline_other_init_and_unshared(bunny, init, shared, dev):
    small = bunny[:, :32, :32]
    a = separate(small, method="tensor", init=init, shared_init=shared, workers=1)
    b = separate(small, method="tensor", init=init, shared_init=shared, device=dev)
    assert _psnr(b.diffuse, a.diffuse) > 70


def test_device_pipeline_illuminant_options(bunny, dev):
    small = bunny[:, :24, :24]
    for ill in ("white", (0.5, 0.3, 0.2)):
        a = separate(small, method="tensor", illuminant=ill, workers=1)
        b = separate(small, method="tensor", illuminant=ill, device=dev)
        np.testing.assert_allclose(b.info["illuminant_chromaticity"], a.info["illuminant_chromaticity"])
        assert _psnr(b.diffuse, a.diffuse) > 70
    with pytest.raises(MethodError, match="illuminant 'blue'"):
        separate(small, method="tensor", illuminant="blue", device=dev)
    with pytest.raises(MethodError, match="three positive values"):
        separate(small, method="tensor", illuminant=(0.5, 0.6, -0.1), device=dev)


def test_device_end_to_end_small(dev):
    stack, _ = _scene(12)
    a = separate(stack, method="tensor")
    b = separate(stack, method="tensor", device=dev)
    np.testing.assert_allclose(b.diffuse, a.diffuse, atol=1e-2)
    assert b.info["device"] == dev
