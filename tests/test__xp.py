"""polcam._xp: the torch namespace's functions give numpy's results (the ones polarized-residual relies on)."""

from __future__ import annotations

import numpy as np
import pytest

from polcam._xp import NumpyXP, namespace


@pytest.fixture
def txp(dev):
    torch = pytest.importorskip("torch")
    return namespace(torch.zeros(1, device=dev)), torch, dev


@pytest.mark.parametrize("n", [1, 2, 7, 10, 1001])
def test_median_and_quantile_are_numpys(txp, n):
    xp, torch, dev = txp
    a = np.random.default_rng(n).normal(size=n).astype(np.float32)
    t = torch.as_tensor(a, device=dev)
    # an even count: numpy takes the mean of the two middle values (torch.median the lower one)
    assert xp.median(t) == pytest.approx(float(np.median(a)), abs=1e-7)
    for q in (0.0, 0.002, 0.5, 0.99, 1.0):
        assert xp.quantile(t, q) == pytest.approx(float(np.quantile(a, q)), abs=1e-6)
    assert NumpyXP.median(a) == np.median(a) and NumpyXP.quantile(a, 0.3) == np.quantile(a, 0.3)


def test_interp_is_numpys_including_beyond_the_ends(txp):
    xp, torch, dev = txp
    xs, ys = [0.1, 0.2, 0.5, 0.9], [1.0, 3.0, 3.5, 10.0]
    x = np.linspace(-0.5, 1.5, 101)
    got = xp.interp(torch.as_tensor(x, device=dev), xs, ys).cpu().numpy()
    np.testing.assert_allclose(got, np.interp(x, xs, ys), rtol=0, atol=1e-12)
    one = xp.interp(torch.as_tensor(x, device=dev), [0.3], [2.0]).cpu().numpy()
    np.testing.assert_array_equal(one, np.interp(x, [0.3], [2.0]))


def test_scalars_sorting_and_searching(txp):
    xp, torch, dev = txp
    a = torch.tensor([0.5, -1.0, 2.0], device=dev)
    assert xp.maximum(a, 0.0).tolist() == [0.5, 0.0, 2.0] and xp.minimum(1.0, a).tolist() == [0.5, -1.0, 1.0]
    # argmax of a bool mask: the first True, as numpy's
    m = np.array([[False, True], [True, True], [False, False]])
    assert xp.argmax(torch.as_tensor(m, device=dev), axis=0).tolist() == np.argmax(m, axis=0).tolist()
    cw = torch.tensor([1.0, 3.0, 6.0, 10.0], device=dev)
    for v in (0.5, 3.0, 5.0, 10.0):
        assert int(xp.searchsorted(cw, torch.tensor(v, device=dev))) == int(np.searchsorted(cw.cpu().numpy(), v))
    s = torch.tensor([3.0, 1.0, 3.0, 2.0], device=dev)
    assert xp.argsort(s, stable=True).tolist() == np.argsort(s.cpu().numpy(), kind="stable").tolist()
    v = torch.tensor([[3.0, 4.0], [0.0, 0.0]], device=dev)
    assert xp.vnorm(v, axis=-1).tolist() == [5.0, 0.0]
