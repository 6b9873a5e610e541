"""The PyTorch backend of the tensor method (``device="cpu"``, ``"cuda"``, ...).

Install with the ``torch`` extra (``pip install polcam[torch]``, pinned to
``torch==2.13.0``: an unpinned install pulls a multi-GB CUDA build).  Chosen by
the ``device`` option of the tensor methods; numpy stays the default backend
and the reference of this one.  Every step of the method runs on the device
through the same code as numpy's (:mod:`.operators`, :mod:`.tiling`,
:mod:`.ialm`); what this module supplies to the IALM is:

* :func:`make_tsvt`: the t-SVT of a batch of tiles at once (what a GPU needs to
  be busy), computed for every Fourier slice from all eigenpairs of its Gram
  matrix, one batched decomposition per slice
  (:func:`polcam.separation._cusolver.eigh`: cuSOLVER's batched solver on CUDA,
  ``torch.linalg.eigh`` elsewhere), the same operator as the numpy fast
  solver's full path;
* :func:`spectral_norms`: the largest singular value of each tile's slices (mu0);
* :func:`chunks`: the element-wise updates as one call on the whole batch.

The initial diffuse (Yang'10) on the device is :func:`polcam.separation.yang10.separate_yang10`
itself, written over the array namespace (:mod:`polcam._xp`) like the steps above.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from polcam.errors import MethodError
from polcam.separation import _cusolver
from polcam.separation._tsvt import packed_dft

__all__ = ["available", "check_device", "make_tsvt", "spectral_norms", "chunks", "device_batch"]


def available() -> bool:
    """True if PyTorch can be imported."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def check_device(device: str) -> None:
    """Raise :class:`~polcam.errors.MethodError` unless ``device`` can run the backend."""
    try:
        import torch
    except ImportError:
        raise MethodError(
            f"device {device!r} needs PyTorch, which is not installed: "
            "pip install 'polcam[torch]' (torch==2.13.0), or leave device=None for numpy"
        ) from None
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise MethodError(f"device {device!r}: not a torch device name ({exc})") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise MethodError(f"device {device!r}: PyTorch sees no CUDA GPU on this machine")


def _svt_gram(a: Any, t: Any) -> tuple[Any, Any]:
    """Batched SVT of matrices a (B, k, m) at thresholds t (B,), from the Gram matrices' eigenpairs."""
    import torch

    tall = a.shape[-2] >= a.shape[-1]
    b = a if tall else a.mH
    g = b.mH @ b
    lam, v = _cusolver.eigh(g)
    lam = lam.clamp_min(0)
    t2 = (t * t)[:, None]
    keep = lam > t2
    s = torch.sqrt(torch.where(keep, lam, torch.ones_like(lam)))
    f = torch.where(keep, 1.0 - t[:, None] / s, torch.zeros_like(s)).to(b.real.dtype)
    x = ((b @ v) * f[:, None, :].to(b.dtype)) @ v.mH
    return (x if tall else x.mH), keep.sum(dim=-1)


class _GramTSVT:
    """The t-SVT of a batch (B, n4, k, m): packed real DFT, batched Gram SVT per frequency, inverse."""

    def __init__(self, n4: int, dtype: Any) -> None:
        self.f, self.finv, self.slices = packed_dft(n4)
        self.dtype = dtype
        self.mats: tuple[Any, Any] | None = None

    @staticmethod
    def _mix(mat: Any, x: Any) -> Any:
        b, n4, k, m = x.shape
        return (mat @ x.reshape(b, n4, k * m)).reshape(x.shape)

    def __call__(self, z: Any, t: np.ndarray) -> tuple[Any, list[list[int]]]:
        import torch

        if self.mats is None:                 # on the device of the first tensor seen
            self.mats = (torch.as_tensor(self.f, device=z.device, dtype=self.dtype),
                         torch.as_tensor(self.finv, device=z.device, dtype=self.dtype))
        zf = self._mix(self.mats[0], z)
        tt = torch.as_tensor(np.asarray(t, dtype=np.float64), device=z.device).to(z.dtype)
        out = torch.empty_like(zf)
        ranks = []
        for rows in self.slices:
            a = zf[:, rows[0]] if len(rows) == 1 else torch.complex(zf[:, rows[0]], zf[:, rows[1]])
            x, r = _svt_gram(a, tt)
            if len(rows) == 1:
                out[:, rows[0]] = x
            else:
                out[:, rows[0]] = x.real
                out[:, rows[1]] = x.imag
            ranks.append(r)
        del zf
        return self._mix(self.mats[1], out), torch.stack(ranks, dim=1).tolist()

    def keep(self, idx: list[int]) -> None:
        pass

    def counts(self, j: int) -> dict[str, int]:
        return {}


def make_tsvt(solver: str, *, n4: int, batch: int, dtype: Any, threads: int = 1,
              options: dict[str, Any] | None = None) -> Any:
    """The t-SVT of a batch, as :func:`polcam.separation.tensor.numpy_backend.make_tsvt` (``"fast"`` only)."""
    if solver != "fast":
        raise MethodError(f"the PyTorch backend runs the fast solver; got solver={solver!r}")
    return _GramTSVT(n4, dtype)


def spectral_norms(d: Any) -> np.ndarray:
    """``||bcirc(D_b)||_2`` of each tile of a batch (B, n4, k, m): (B,) float64 on the host.

    The largest eigenvalue of every Fourier slice's Gram matrix, in the working precision.
    """
    import torch

    B, n4, k, m = d.shape
    f, _, slices = packed_dft(n4)
    zd = (torch.as_tensor(f, device=d.device, dtype=d.dtype) @ d.reshape(B, n4, k * m)).reshape(d.shape)
    spec = torch.zeros(B, dtype=torch.float64, device=d.device)
    for rows in slices:
        a = zd[:, rows[0]] if len(rows) == 1 else torch.complex(zd[:, rows[0]], zd[:, rows[1]])
        b = a if k >= m else a.mH
        top = _cusolver.eigh(b.mH @ b, vectors=False)[0][:, -1].clamp_min(0).sqrt().to(torch.float64)
        spec = torch.maximum(spec, top)
    return spec.cpu().numpy()


@contextlib.contextmanager
def chunks(n4: int, threads: int) -> Iterator[Callable[[Callable[[Any], Any]], list[Any]]]:
    """``each(fn)``: one call ``fn(c)`` on the whole batch (the device parallelises)."""
    whole = (slice(None),)
    yield lambda fn: [fn(whole)]


def device_batch(tiles: int, per_tile: int, device: Any, cpu_batch: int) -> int:
    """Tiles per IALM call on a torch device: as many as fit in a third of its free memory.

    ``per_tile`` is the bytes of one tile's tensor; the IALM holds about 24 of
    them.  On the CPU, ``cpu_batch`` tiles.
    """
    import torch

    if device.type != "cuda":
        return max(1, min(tiles, cpu_batch))
    free, _ = torch.cuda.mem_get_info(device)
    return max(1, min(tiles, int(free / 3 // (24 * per_tile))))
