"""polcam._imageops: every filter on torch equals the OpenCV call it stands for (same kernel, same border)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from polcam import _imageops

SHAPES = [(37, 53), (37, 53, 3), (5, 200), (1, 7), (64, 9, 3)]


def _rand(shape, seed=0):
    return np.random.default_rng(seed).random(shape).astype(np.float32)


def _cases():
    # (name, numpy reference written with OpenCV directly, the module's function, smallest side it needs)
    ones = lambda k: np.ones((k, k), np.uint8)  # noqa: E731
    return [
        ("gaussian 3", lambda a: cv2.GaussianBlur(a, (3, 3), 0), lambda a: _imageops.gaussian(a, 3), 1),
        ("gaussian 7", lambda a: cv2.GaussianBlur(a, (7, 7), 0), lambda a: _imageops.gaussian(a, 7), 1),
        ("gaussian 21", lambda a: cv2.GaussianBlur(a, (21, 21), 0), lambda a: _imageops.gaussian(a, 21), 1),
        ("box sum 61", lambda a: cv2.boxFilter(a, -1, (61, 61), normalize=False),
         lambda a: _imageops.box(a, 61, normalize=False), 1),
        ("box mean 5", lambda a: cv2.blur(a, (5, 5)), lambda a: _imageops.box(a, 5), 1),
        ("median 3", lambda a: cv2.medianBlur(a, 3), lambda a: _imageops.median(a, 3), 5),
        ("median 5", lambda a: cv2.medianBlur(a, 5), lambda a: _imageops.median(a, 5), 5),
        ("dilate 7", lambda a: cv2.dilate(a, ones(7)), lambda a: _imageops.dilate(a, 7), 1),
        ("dilate 147", lambda a: cv2.dilate(a, ones(147)), lambda a: _imageops.dilate(a, 147), 1),
        ("erode 5", lambda a: cv2.erode(a, ones(5)), lambda a: _imageops.erode(a, 5), 1),
    ]


@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_numpy_goes_through_opencv_unchanged(shape):
    a = _rand(shape)
    for name, ref, fn, least in _cases():
        if min(shape[:2]) < least:
            continue
        np.testing.assert_array_equal(fn(a), ref(a), err_msg=name)


@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_torch_equals_opencv(shape, dev):
    torch = pytest.importorskip("torch")
    a = _rand(shape, seed=1)
    t = torch.as_tensor(a, device=dev)
    for name, ref, fn, least in _cases():
        if min(shape[:2]) < least:
            continue
        got = fn(t)
        assert got.device == t.device and got.dtype == t.dtype and tuple(got.shape) == shape, name
        # float32 sums in another order: within a few units of the last place, never more
        np.testing.assert_allclose(got.cpu().numpy(), ref(a), rtol=0, atol=2e-6, err_msg=name)


@pytest.mark.parametrize("shape", [(37, 53), (5, 200), (2, 3)], ids=str)
def test_sobel_and_masks_on_torch(shape, dev):
    torch = pytest.importorskip("torch")
    a = _rand(shape, seed=2)
    t = torch.as_tensor(a, device=dev)
    for dx, dy in ((1, 0), (0, 1)):
        np.testing.assert_allclose(_imageops.sobel(t, dx, dy).cpu().numpy(),
                                   cv2.Sobel(a, cv2.CV_32F, dx, dy, ksize=3), rtol=0, atol=2e-6)
        # the 5 x 5 kernel's taps sum to 16 times the 3 x 3's weight: float32 error grows with them
        np.testing.assert_allclose(_imageops.sobel(t, dx, dy, ksize=5).cpu().numpy(),
                                   cv2.Sobel(a, cv2.CV_32F, dx, dy, ksize=5), rtol=0, atol=2e-5)
    # a 0/1 mask eroded as OpenCV erodes its uint8 form (outside the image never counts)
    m = (a > 0.3).astype(np.uint8)
    got = _imageops.erode(torch.as_tensor(m, device=dev), 3).cpu().numpy()
    np.testing.assert_array_equal(got, cv2.erode(m, np.ones((3, 3), np.uint8)))


def test_sobel_refuses_other_sizes():
    with pytest.raises(ValueError, match="ksize 7"):
        _imageops.sobel(np.zeros((4, 4), np.float32), 1, 0, ksize=7)


def test_running_max_is_the_windowed_maximum():
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(3)
    for n, k in ((1, 1), (1, 9), (10, 3), (10, 11), (57, 13), (200, 61)):
        x = rng.normal(size=(2, n))
        got = _imageops._running_max(torch.as_tensor(x), k).numpy()
        r = k // 2
        want = np.array([[row[max(0, i - r):i + r + 1].max() for i in range(n)] for row in x])
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("src,dst", [((1024, 1224), (342, 408)), ((37, 53), (19, 13)), ((7, 9), (2, 3)),
                                     ((10, 10), (10, 10))], ids=str)
def test_resize_matches_opencv(src, dst, dev):
    torch = pytest.importorskip("torch")
    a = _rand(src, seed=4)
    ref = cv2.resize(a, dst[::-1], interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(_imageops.resize(a, dst[::-1], interpolation="area"), ref)
    got = _imageops.resize(torch.as_tensor(a, device=dev), dst[::-1], interpolation="area").cpu().numpy()
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-6)
    small = _rand(dst + (3,), seed=5)
    ref = cv2.resize(small, src[::-1], interpolation=cv2.INTER_LINEAR)
    got = _imageops.resize(torch.as_tensor(small, device=dev), src[::-1], interpolation="linear").cpu().numpy()
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-6)


def test_resize_refuses_what_it_does_not_do():
    torch = pytest.importorskip("torch")
    with pytest.raises(ValueError, match="interpolation 'cubic'"):
        _imageops.resize(np.zeros((4, 4), np.float32), (2, 2), interpolation="cubic")
    with pytest.raises(ValueError, match="only shrinking"):
        _imageops.resize(torch.zeros((4, 4)), (8, 8), interpolation="area")


def _shrunk_case():
    a = _rand((61, 90, 3), seed=4)
    small = cv2.resize(a, (22, 15), interpolation=cv2.INTER_AREA)
    return a, cv2.resize(cv2.GaussianBlur(small, (5, 5), 0), (90, 61), interpolation=cv2.INTER_LINEAR)


def test_shrunk_filters_at_the_coarse_scale_and_returns_the_input_size():
    a, want = _shrunk_case()
    got = _imageops.shrunk(a, 4, lambda s: cv2.GaussianBlur(s, (5, 5), 0))
    assert got.shape == a.shape
    np.testing.assert_array_equal(got, want)


def test_shrunk_on_torch_matches_opencv():
    torch = pytest.importorskip("torch")
    a, want = _shrunk_case()
    got = _imageops.shrunk(torch.as_tensor(a), 4, lambda s: _imageops.gaussian(s, 5))
    np.testing.assert_allclose(got.numpy(), want, rtol=0, atol=2e-6)
