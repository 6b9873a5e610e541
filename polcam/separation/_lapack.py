"""Hermitian eigensolvers that release the GIL, for the fast t-SVT's threads.

scipy's Python LAPACK wrappers (``scipy.linalg.eigh``, ``scipy.linalg.lapack``)
hold the GIL while LAPACK runs, so two threads decomposing two Fourier slices
take as long as one thread doing both (measured: two 768 x 768 syevd in two
threads 95 ms against 81 ms one after the other).  numpy's ``eigh`` releases
it but its LAPACK was 2-3 times slower here.  This module calls the same
LAPACK routines scipy ships, through the function pointers of scipy's public
Cython LAPACK API (``scipy.linalg.cython_lapack``), with ctypes, which
releases the GIL during foreign calls.

Routines: ``?syevd`` (real, divide and conquer), ``?heevr`` (complex, MRRR:
174 against heevd's 236 ms at 768) and ``?heevd`` (complex, faster at small
sizes: 0.84 against 1.33 ms at 96).
:func:`eigh` returns ``None`` when a routine is unavailable or reports an
error, and the caller falls back to ``scipy.linalg.eigh``.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

__all__ = ["available", "eigh"]

_INT = ctypes.POINTER(ctypes.c_int)
_PTR = ctypes.c_void_p
_CHAR = ctypes.c_char_p

# (routine, argument types after the leading character arguments) per dtype
_SIGNATURES: dict[str, list[Any]] = {
    # jobz, uplo, n, a, lda, w, work, lwork, iwork, liwork, info
    "syevd": [_CHAR, _CHAR, _INT, _PTR, _INT, _PTR, _PTR, _INT, _PTR, _INT, _INT],
    # jobz, range, uplo, n, a, lda, vl, vu, il, iu, abstol, m, w, z, ldz, isuppz,
    # work, lwork, rwork, lrwork, iwork, liwork, info
    "heevr": [_CHAR, _CHAR, _CHAR, _INT, _PTR, _INT, _PTR, _PTR, _INT, _INT, _PTR, _INT, _PTR, _PTR,
              _INT, _PTR, _PTR, _INT, _PTR, _INT, _PTR, _INT, _INT],
    # jobz, uplo, n, a, lda, w, work, lwork, rwork, lrwork, iwork, liwork, info
    "heevd": [_CHAR, _CHAR, _INT, _PTR, _INT, _PTR, _PTR, _INT, _PTR, _INT, _PTR, _INT, _INT],
}
_PREFIX = {np.dtype(np.float32): "s", np.dtype(np.float64): "d",
           np.dtype(np.complex64): "c", np.dtype(np.complex128): "z"}
_FUNCS: dict[tuple[np.dtype, str], Any] = {}
_WORK: dict[tuple[np.dtype, str, int], tuple[int, ...]] = {}


def _load() -> None:
    try:
        from scipy.linalg import cython_lapack
    except ImportError:  # pragma: no cover - scipy is a dependency
        return
    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
    get_ptr = ctypes.pythonapi.PyCapsule_GetPointer
    get_ptr.restype, get_ptr.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    for dt, p in _PREFIX.items():
        for kind in (("syevd",) if dt.kind == "f" else ("heevr", "heevd")):
            cap = getattr(cython_lapack, "__pyx_capi__", {}).get(p + kind)
            if cap is None:  # pragma: no cover - every scipy since 0.16 has them
                continue
            ptr = get_ptr(cap, get_name(cap))
            _FUNCS[dt, kind] = ctypes.CFUNCTYPE(None, *_SIGNATURES[kind])(ptr)


def _kind(dt: np.dtype, driver: str) -> str:
    return "syevd" if dt.kind == "f" else ("heevr" if driver == "evr" else "heevd")


_load()


def available(dtype: Any, driver: str = "evr") -> bool:
    """True if :func:`eigh` can decompose matrices of this dtype with this driver."""
    dt = np.dtype(dtype)
    return dt in _PREFIX and (dt, _kind(dt, driver)) in _FUNCS


def _i(v: int) -> ctypes.c_int:
    return ctypes.c_int(int(v))


def _workspace(dt: np.dtype, kind: str, n: int) -> tuple[int, ...]:
    """Optimal workspace sizes (LAPACK's query), cached per dtype, routine and size."""
    key = (dt, kind, n)
    if key in _WORK:
        return _WORK[key]
    real = np.dtype(dt.char.lower()) if dt.kind == "c" else dt
    work = np.zeros(1, dt)
    iwork = np.zeros(1, np.intc)
    info = _i(0)
    a = np.zeros((1, 1), dt, order="F")
    w = np.zeros(max(n, 1), real)
    fn = _FUNCS[dt, kind]
    if kind == "syevd":
        fn(b"V", b"U", ctypes.byref(_i(n)), a.ctypes.data, ctypes.byref(_i(max(n, 1))), w.ctypes.data,
           work.ctypes.data, ctypes.byref(_i(-1)), iwork.ctypes.data, ctypes.byref(_i(-1)), ctypes.byref(info))
        sizes = (int(work[0].real), int(iwork[0]))
    elif kind == "heevd":
        rwork = np.zeros(1, real)
        fn(b"V", b"U", ctypes.byref(_i(n)), a.ctypes.data, ctypes.byref(_i(max(n, 1))), w.ctypes.data,
           work.ctypes.data, ctypes.byref(_i(-1)), rwork.ctypes.data, ctypes.byref(_i(-1)), iwork.ctypes.data,
           ctypes.byref(_i(-1)), ctypes.byref(info))
        sizes = (int(work[0].real), int(rwork[0]), int(iwork[0]))
    else:
        rwork = np.zeros(1, real)
        zero = np.zeros(1, real)
        m = _i(0)
        z = np.zeros((1, 1), dt, order="F")
        isuppz = np.zeros(2 * max(n, 1), np.intc)
        fn(b"V", b"A", b"U", ctypes.byref(_i(n)), a.ctypes.data, ctypes.byref(_i(max(n, 1))),
           zero.ctypes.data, zero.ctypes.data, ctypes.byref(_i(0)), ctypes.byref(_i(0)),
           zero.ctypes.data, ctypes.byref(m), w.ctypes.data, z.ctypes.data,
           ctypes.byref(_i(max(n, 1))), isuppz.ctypes.data, work.ctypes.data, ctypes.byref(_i(-1)),
           rwork.ctypes.data, ctypes.byref(_i(-1)), iwork.ctypes.data, ctypes.byref(_i(-1)),
           ctypes.byref(info))
        sizes = (int(work[0].real), int(rwork[0]), int(iwork[0]))
    if info.value != 0:  # pragma: no cover - a query does not fail
        raise RuntimeError(f"LAPACK workspace query failed (info {info.value})")
    _WORK[key] = sizes
    return sizes


def eigh(g: np.ndarray, *, upper: bool = True, driver: str = "evr") -> tuple[np.ndarray, np.ndarray] | None:
    """Eigenvalues (ascending) and eigenvectors of a Hermitian matrix, without the GIL.

    Parameters
    ----------
    g
        (n, n) float32/float64/complex64/complex128 Hermitian matrix whose
        triangle ``upper`` (in its own index order) holds the matrix; it is
        overwritten.  A C-ordered matrix is read through its Fortran view (the
        transpose), so its other triangle is read then: for a C-ordered input
        both triangles must hold the matrix (real symmetric, or a complex
        matrix made exactly Hermitian).
    upper
        Which triangle of ``g`` to read.
    driver
        For complex matrices: ``"evr"`` (heevr, MRRR) or ``"evd"`` (heevd,
        divide and conquer); real ones always use syevd.

    Returns
    -------
    (w, v) or None
        ``w`` (n,) real ascending, ``v`` (n, n) with the eigenvectors in its
        columns; ``None`` if no GIL-free routine exists for the dtype or
        LAPACK reported an error (the caller then uses ``scipy.linalg.eigh``).
    """
    dt = g.dtype
    if not available(dt, driver) or g.ndim != 2 or g.shape[0] != g.shape[1]:
        return None
    kind = _kind(dt, driver)
    fn = _FUNCS[dt, kind]
    n = g.shape[0]
    if n == 0:
        return None
    if g.flags.f_contiguous:
        a, uplo = g, (b"U" if upper else b"L")
    elif g.flags.c_contiguous:
        # the Fortran view of a C-ordered matrix is its transpose: the same triangle of
        # a symmetric matrix, the conjugate of a Hermitian one (which both triangles hold)
        a, uplo = g.T, (b"L" if upper else b"U")
        if dt.kind == "c":
            a = np.asfortranarray(g)
            uplo = b"U" if upper else b"L"
    else:
        a, uplo = np.asfortranarray(g), (b"U" if upper else b"L")
    real = np.dtype(dt.char.lower()) if dt.kind == "c" else dt
    w = np.empty(n, real)
    info = _i(0)
    sizes = _workspace(dt, kind, n)
    if kind == "syevd":
        work = np.empty(max(sizes[0], 1), dt)
        iwork = np.empty(max(sizes[1], 1), np.intc)
        fn(b"V", uplo, ctypes.byref(_i(n)), a.ctypes.data, ctypes.byref(_i(n)), w.ctypes.data,
           work.ctypes.data, ctypes.byref(_i(work.size)), iwork.ctypes.data, ctypes.byref(_i(iwork.size)),
           ctypes.byref(info))
        return (w, a) if info.value == 0 else None
    if kind == "heevd":
        work = np.empty(max(sizes[0], 1), dt)
        rwork = np.empty(max(sizes[1], 1), real)
        iwork = np.empty(max(sizes[2], 1), np.intc)
        fn(b"V", uplo, ctypes.byref(_i(n)), a.ctypes.data, ctypes.byref(_i(n)), w.ctypes.data,
           work.ctypes.data, ctypes.byref(_i(work.size)), rwork.ctypes.data, ctypes.byref(_i(rwork.size)),
           iwork.ctypes.data, ctypes.byref(_i(iwork.size)), ctypes.byref(info))
        return (w, a) if info.value == 0 else None
    z = np.empty((n, n), dt, order="F")
    isuppz = np.empty(2 * n, np.intc)
    work = np.empty(max(sizes[0], 1), dt)
    rwork = np.empty(max(sizes[1], 1), real)
    iwork = np.empty(max(sizes[2], 1), np.intc)
    zero = np.zeros(1, real)
    m = _i(0)
    fn(b"V", b"A", uplo, ctypes.byref(_i(n)), a.ctypes.data, ctypes.byref(_i(n)),
       zero.ctypes.data, zero.ctypes.data, ctypes.byref(_i(0)), ctypes.byref(_i(0)),
       zero.ctypes.data, ctypes.byref(m), w.ctypes.data, z.ctypes.data, ctypes.byref(_i(n)),
       isuppz.ctypes.data, work.ctypes.data, ctypes.byref(_i(work.size)), rwork.ctypes.data,
       ctypes.byref(_i(rwork.size)), iwork.ctypes.data, ctypes.byref(_i(iwork.size)),
       ctypes.byref(info))
    if info.value != 0 or m.value != n:
        return None
    return w, z
