"""Batched Hermitian eigensolver on CUDA: cuSOLVER's ``cusolverDnXsyevBatched`` through ctypes.

``torch.linalg.eigh`` sends a batch of matrices larger than 32 x 32 to one
cuSOLVER call per matrix (PyTorch issue 175585): on an H100, 902 real
96 x 96 matrices took 1.1 s, 451 complex ones 0.54 s, while a batch of 32 x 32
ones (``syevjBatched``) took 1 ms.  The tiles of the fast tensor solver have
Gram matrices of side 96, so the PyTorch backend decomposes them with
``cusolverDnXsyevBatched`` (cuSOLVER 11.7 / CUDA 12.6 and later), which does
a whole batch of any size in one call.  The library is the one PyTorch already
loaded (found in ``/proc/self/maps``), so no CUDA package is added; the call
runs on PyTorch's current stream with workspace allocated by PyTorch.

:func:`eigh` falls back to ``torch.linalg.eigh`` where this is unavailable
(another platform, an older cuSOLVER, a CPU tensor).  Diagonal matrices (a
zero Fourier slice) are solved directly; a matrix the batched call does not
converge on, or whose result fails the check ``||G V - V diag(w)|| <= 1e-3 ||G||``
(1e-9 in double precision; cuSOLVER 12 once returned NaN eigenvectors with a
success code), is decomposed again in double precision (:data:`fallbacks`
counts them).
"""

from __future__ import annotations

import ctypes
import threading
from typing import Any

__all__ = ["available", "eigh"]

# cudaDataType and cuSOLVER / cuBLAS enum values (library_types.h, cusolver_common.h, cublas_api.h)
_CUDA_TYPE = {"float32": 0, "float64": 1, "complex64": 4, "complex128": 5}
_EIG_MODE_VECTOR = 1
_EIG_MODE_NOVECTOR = 0
_FILL_LOWER = 0

_lock = threading.Lock()
_lib: Any = None
_tried = False
_handles: dict[tuple[int, int], tuple[ctypes.c_void_p, ctypes.c_void_p]] = {}
#: Largest side sent to the batched call: on an H100 it took 54 ms for two real 768 x 768
#: matrices, PyTorch's one-at-a-time path 17 ms (and 4 ms for 902 of side 96, against 1.1 s).
BATCHED_MAX_N = 256
#: Matrices the batched call failed on, decomposed again in double precision (a count).
fallbacks = 0
#: Largest accepted ||G V - V diag(w)||_max / ||G||_max of a batched result (single, double precision).
CHECK_TOL = (1e-3, 1e-9)


def _find_library() -> str | None:
    """Path of the libcusolver PyTorch loaded (None if it loaded none we can see).

    Only that copy is used: another one on the system may be of another CUDA
    version than the runtime PyTorch runs on.
    """
    try:
        with open("/proc/self/maps") as fh:
            for line in fh:
                path = line.split()[-1]
                if "/libcusolver.so" in path and "libcusolverMg" not in path:
                    return path
    except OSError:  # pragma: no cover - not Linux
        pass
    return None


def _load() -> Any:
    """The cuSOLVER library with the batched eigensolver's signatures set, or None."""
    global _lib, _tried
    with _lock:
        if _tried:
            return _lib
        _tried = True
        import torch

        if not torch.cuda.is_available():
            return None
        # make PyTorch load its cuSOLVER (a tiny decomposition) so that the same copy is used
        torch.linalg.eigh(torch.eye(2, device="cuda"))
        path = _find_library()
        if path is None:
            return None
        try:
            lib = ctypes.CDLL(path)
            fn = lib.cusolverDnXsyevBatched
            size = lib.cusolverDnXsyevBatched_bufferSize
        except (OSError, AttributeError):
            return None
        p, i64, i32, sz = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int, ctypes.c_size_t
        lib.cusolverDnCreate.argtypes = [ctypes.POINTER(p)]
        lib.cusolverDnCreateParams.argtypes = [ctypes.POINTER(p)]
        lib.cusolverDnSetStream.argtypes = [p, p]
        size.argtypes = [p, p, i32, i32, i64, i32, p, i64, i32, p, i32,
                         ctypes.POINTER(sz), ctypes.POINTER(sz), i64]
        fn.argtypes = [p, p, i32, i32, i64, i32, p, i64, i32, p, i32, p, sz, p, sz, p, i64]
        for f in (lib.cusolverDnCreate, lib.cusolverDnCreateParams, lib.cusolverDnSetStream, size, fn):
            f.restype = ctypes.c_int
        _lib = lib
        return lib


def available() -> bool:
    """True if batched eigendecompositions run through ``cusolverDnXsyevBatched``."""
    try:
        return _load() is not None
    except Exception:  # pragma: no cover - a broken CUDA set-up: the torch fallback
        return False


def _handle(lib: Any, device: int) -> tuple[ctypes.c_void_p, ctypes.c_void_p]:
    key = (device, threading.get_ident())
    if key not in _handles:
        h, prm = ctypes.c_void_p(), ctypes.c_void_p()
        if lib.cusolverDnCreate(ctypes.byref(h)) or lib.cusolverDnCreateParams(ctypes.byref(prm)):
            raise RuntimeError("cusolverDnCreate failed")
        _handles[key] = (h, prm)
    return _handles[key]


def eigh(g: Any, *, vectors: bool = True) -> tuple[Any, Any]:
    """Eigenpairs of a batch of Hermitian matrices, ascending, like ``torch.linalg.eigh``.

    Parameters
    ----------
    g
        (B, n, n) torch tensor, real or complex, float32 or float64, Hermitian
        (only one triangle is read).
    vectors
        False: eigenvalues only (the second result is None).

    Returns
    -------
    w : torch.Tensor
        (B, n) real eigenvalues, ascending.
    v : torch.Tensor or None
        (B, n, n) eigenvectors in the columns.
    """
    import torch

    lib = _load() if g.is_cuda and g.ndim == 3 else None
    name = str(g.dtype).removeprefix("torch.")
    if (lib is None or name not in _CUDA_TYPE or g.shape[-1] > BATCHED_MAX_N
            or g.shape[0] * g.shape[1] * g.shape[2] >= 2**31):
        if vectors:
            return torch.linalg.eigh(g)
        return torch.linalg.eigvalsh(g), None
    b, n, _ = g.shape
    # cuSOLVER reads column-major: the row-major buffer of g is g^T = conj(g), whose
    # eigenvectors are the conjugates of g's; written back column-major they read V^H.
    # Diagonal matrices (a zero Fourier slice, where the representations are identical) need
    # no decomposition: a stand-in takes their slots and _repair fills them in.
    diag = torch.diagonal(g, dim1=-2, dim2=-1)
    plain = (g - torch.diag_embed(diag)).abs().amax(dim=(-1, -2)) == 0       # diagonal (or zero)
    a = torch.where(plain[:, None, None], _stand_in(n, g), g).contiguous()
    w = torch.empty((b, n), dtype=a.real.dtype, device=a.device)
    info = torch.zeros(b, dtype=torch.int32, device=a.device)
    h, prm = _handle(lib, a.device.index or 0)
    stream = torch.cuda.current_stream(a.device).cuda_stream
    if lib.cusolverDnSetStream(h, ctypes.c_void_p(stream)):
        raise RuntimeError("cusolverDnSetStream failed")
    ta, tw = _CUDA_TYPE[name], _CUDA_TYPE[str(w.dtype).removeprefix("torch.")]
    mode = _EIG_MODE_VECTOR if vectors else _EIG_MODE_NOVECTOR
    dev_bytes, host_bytes = ctypes.c_size_t(), ctypes.c_size_t()
    st = lib.cusolverDnXsyevBatched_bufferSize(h, prm, mode, _FILL_LOWER, n, ta, a.data_ptr(), n, tw,
                                                 w.data_ptr(), ta, ctypes.byref(dev_bytes),
                                                 ctypes.byref(host_bytes), b)
    if st:
        raise RuntimeError(f"cusolverDnXsyevBatched_bufferSize: status {st} (n={n}, batch={b}, {name})")
    work = torch.empty(max(dev_bytes.value, 1), dtype=torch.uint8, device=a.device)
    host = ctypes.create_string_buffer(max(host_bytes.value, 1))
    st = lib.cusolverDnXsyevBatched(h, prm, mode, _FILL_LOWER, n, ta, a.data_ptr(), n, tw, w.data_ptr(), ta,
                                     work.data_ptr(), dev_bytes.value, ctypes.addressof(host),
                                     host_bytes.value, info.data_ptr(), b)
    if st:
        raise RuntimeError(f"cusolverDnXsyevBatched: status {st} (n={n}, batch={b}, {name})")
    return _repair(g, plain, w, a.mH if vectors else None, info)


def _repair(g: Any, plain: Any, w: Any, v: Any, info: Any) -> tuple[Any, Any]:
    """The batched call's results made whole.

    ``plain`` marks the diagonal matrices of ``g`` (their slots held a stand-in):
    they are solved directly.  Every other result is checked, and those that
    fail or that ``info`` reports as not converged are decomposed again
    (:func:`_retry`).
    """
    import torch

    n = g.shape[-1]
    if bool(plain.any()):
        # a diagonal matrix is its own decomposition: sorted diagonal, permuted unit vectors
        dw, order = torch.sort(torch.diagonal(g, dim1=-2, dim2=-1).real, dim=-1)
        w = torch.where(plain[:, None], dw.to(w.dtype), w)
        if v is not None:
            eye = torch.eye(n, dtype=g.dtype, device=g.device)
            v = torch.where(plain[:, None, None], eye[:, order].permute(1, 0, 2), v)
    # cuSOLVER 12 (CUDA 13) was seen returning NaN eigenvectors for a complex64 matrix of a
    # batch with info = 0: every result is checked, ||G V - V diag(w)|| against ||G||
    ok = (info == 0) & torch.isfinite(w).all(dim=-1)
    if v is not None:
        scale = torch.clamp_min(g.abs().amax(dim=(-1, -2)), torch.finfo(w.dtype).tiny)
        resid = (g @ v - v * w.to(v.dtype)[:, None, :]).abs().amax(dim=(-1, -2)) / scale
        ok &= resid <= CHECK_TOL[w.dtype == torch.float64]       # False for NaN
    bad = torch.nonzero(~ok).reshape(-1)
    if bad.numel():
        w, v = _retry(g, bad, w, v)
    return w, v


def _stand_in(n: int, like: Any) -> Any:
    """A well-conditioned Hermitian matrix (tridiagonal, distinct eigenvalues) for batch slots not solved."""
    import torch

    t = 3.0 * torch.eye(n, dtype=like.dtype, device=like.device)
    off = torch.ones(n - 1, dtype=like.dtype, device=like.device)
    return t - torch.diag_embed(off, 1) - torch.diag_embed(off, -1)


def _retry(g: Any, bad: Any, w: Any, v: Any) -> tuple[Any, Any]:
    """The matrices the batched call did not converge on, in double precision.

    cuSOLVER's single-precision solvers can fail on a matrix LAPACK handles;
    PyTorch's double-precision path on the device, else numpy on the host.
    """
    import numpy as np
    import torch

    global fallbacks
    fallbacks += int(bad.numel())
    wide = torch.complex128 if g.is_complex() else torch.float64
    sub = g[bad].to(wide)
    try:
        sw, sv = torch.linalg.eigh(sub)
    except RuntimeError:
        hw, hv = np.linalg.eigh(sub.cpu().numpy())
        sw, sv = torch.as_tensor(hw, device=g.device), torch.as_tensor(hv, device=g.device)
    w[bad] = sw.to(w.dtype)
    if v is not None:
        v[bad] = sv.to(v.dtype)
    return w, v
