"""polcam.separation._lapack: Hermitian eigensolvers called without the GIL."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from polcam.separation import _lapack


def _hermitian(rng, n, dtype):
    a = rng.standard_normal((n + 3, n))
    if np.dtype(dtype).kind == "c":
        a = a + 1j * rng.standard_normal(a.shape)
    g = (a.conj().T @ a).astype(dtype)
    return 0.5 * (g + g.conj().T)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.complex64, np.complex128])
@pytest.mark.parametrize("driver", ["evd", "evr"])
@pytest.mark.parametrize("order", ["C", "F"])
@pytest.mark.parametrize("n", [1, 7, 64])
def test_eigenpairs_match_scipy(dtype, driver, order, n):
    rng = np.random.default_rng(n)
    g = _hermitian(rng, n, dtype)
    assert _lapack.available(dtype, driver)
    w, v = _lapack.eigh(np.array(g, order=order), driver=driver)
    w_ref = sla.eigvalsh(g.astype(np.complex128 if np.iscomplexobj(g) else np.float64))
    tol = 1e-4 if np.dtype(dtype) in (np.dtype(np.float32), np.dtype(np.complex64)) else 1e-10
    np.testing.assert_allclose(w, w_ref, atol=tol * w_ref.max())
    assert np.all(np.diff(w) >= 0)                                     # ascending
    np.testing.assert_allclose((v * w) @ v.conj().T, g, atol=tol * np.abs(g).max())
    np.testing.assert_allclose(v.conj().T @ v, np.eye(n), atol=tol * 10)


def test_one_triangle_is_read():
    rng = np.random.default_rng(3)
    g = _hermitian(rng, 20, np.complex64)
    w_ref = np.linalg.eigvalsh(g.astype(np.complex128))
    for upper in (True, False):
        f = np.asfortranarray(g)
        junk = np.tril(np.ones((20, 20)), -1) if upper else np.triu(np.ones((20, 20)), 1)
        f[junk.astype(bool)] = 99.0                          # the triangle not read is garbage
        w, _ = _lapack.eigh(f, upper=upper, driver="evr")
        np.testing.assert_allclose(w, w_ref, atol=1e-4 * w_ref.max())


def test_unsupported_input_returns_none_for_the_fallback():
    assert _lapack.eigh(np.zeros((3, 3), np.int64)) is None
    assert _lapack.eigh(np.zeros((3, 4), np.float32)) is None
    assert not _lapack.available(np.float16)


def test_the_routines_are_called_as_foreign_functions_that_release_the_gil():
    # ctypes releases the GIL around calls through CFUNCTYPE pointers (not PYFUNCTYPE ones,
    # flagged FUNCFLAG_PYTHONAPI); scipy's own wrappers hold it, which is why this module exists
    import ctypes

    assert _lapack._FUNCS, "no LAPACK routine was found in scipy.linalg.cython_lapack"
    for fn in _lapack._FUNCS.values():
        assert isinstance(fn, ctypes._CFuncPtr)
        assert not fn._flags_ & ctypes._FUNCFLAG_PYTHONAPI
