"""The array namespaces polcam's two-backend code is written over: numpy and PyTorch.

The tensor method's operators, tiling and IALM loop
(:mod:`polcam.separation.tensor`), the joint bilateral filter
(:mod:`polcam.filters`), Yang'10 (:mod:`polcam.separation.yang10`) and the
helpers it shares (:mod:`polcam.separation._common`) are written once, against
the small set of functions below; :func:`namespace` picks the set from the type
of an array.  Only names whose spelling differs between numpy and PyTorch are
here (``axis`` against ``dim``, ``clip`` against ``clamp``, ``out=`` and
``where=`` forms); operators both spell the same (``+``, ``*=``, ``@``,
slicing, ``reshape``, ``sum`` without an axis) are used directly.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["NumpyXP", "TorchXP", "namespace"]


class NumpyXP:
    """The functions of :class:`TorchXP` for numpy arrays."""

    name = "numpy"
    float64 = np.float64
    float32 = np.float32
    #: dtype of index arrays
    index = np.intp

    @staticmethod
    def asarray(a: Any, like: Any = None, dtype: Any = None) -> np.ndarray:
        return np.asarray(a, dtype=dtype)

    @staticmethod
    def to_numpy(a: Any) -> np.ndarray:
        return np.asarray(a)

    @staticmethod
    def astype(a: np.ndarray, dtype: Any) -> np.ndarray:
        return a.astype(dtype, copy=False)

    @staticmethod
    def copy(a: np.ndarray) -> np.ndarray:
        return np.array(a, copy=True, order="C")

    @staticmethod
    def broadcast_to(a: np.ndarray, shape: Sequence[int]) -> np.ndarray:
        return np.broadcast_to(a, tuple(shape))

    @staticmethod
    def dtype_of(name: str) -> Any:
        return np.dtype(name)

    @staticmethod
    def zeros(shape: Sequence[int], like: np.ndarray, dtype: Any = None) -> np.ndarray:
        return np.zeros(shape, dtype=like.dtype if dtype is None else dtype)

    @staticmethod
    def arange(n: int, like: np.ndarray) -> np.ndarray:
        return np.arange(n, dtype=np.intp)

    @staticmethod
    def index_array(values: Any, like: np.ndarray) -> np.ndarray:
        return np.asarray(values, dtype=np.intp)

    @staticmethod
    def stack(arrays: Sequence[np.ndarray], axis: int = 0) -> np.ndarray:
        return np.stack(arrays, axis=axis)

    @staticmethod
    def permute(a: np.ndarray, axes: Sequence[int]) -> np.ndarray:
        return a.transpose(axes)

    @staticmethod
    def sum(a: np.ndarray, axis: Any, keepdims: bool = False) -> np.ndarray:
        return a.sum(axis=axis, keepdims=keepdims)

    @staticmethod
    def mean(a: np.ndarray, axis: Any = None) -> Any:
        return a.mean(axis=axis)

    @staticmethod
    def amax(a: np.ndarray, axis: Any, keepdims: bool = False) -> np.ndarray:
        return a.max(axis=axis, keepdims=keepdims)

    @staticmethod
    def amin(a: np.ndarray, axis: Any, keepdims: bool = False) -> np.ndarray:
        return a.min(axis=axis, keepdims=keepdims)

    where = staticmethod(np.where)

    @staticmethod
    def sqrt(a: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        return np.sqrt(a, out=out)

    @staticmethod
    def div(a: Any, b: Any, out: np.ndarray) -> np.ndarray:
        return np.divide(a, b, out=out)

    @staticmethod
    def divide_where(a: np.ndarray, b: np.ndarray, ok: np.ndarray, fill: float) -> np.ndarray:
        """``a / b`` where ``ok``, ``fill`` elsewhere (broadcast), never dividing outside ``ok``."""
        out = np.full(np.broadcast_shapes(a.shape, b.shape, ok.shape), fill, dtype=np.result_type(a, b))
        return np.divide(a, b, out=out, where=ok)

    exp = staticmethod(np.exp)
    log = staticmethod(np.log)
    tanh = staticmethod(np.tanh)
    floor = staticmethod(np.floor)
    hypot = staticmethod(np.hypot)
    isfinite = staticmethod(np.isfinite)
    einsum = staticmethod(np.einsum)
    maximum = staticmethod(np.maximum)
    minimum = staticmethod(np.minimum)
    arctan2 = staticmethod(np.arctan2)
    cos = staticmethod(np.cos)
    concatenate = staticmethod(np.concatenate)
    nonzero = staticmethod(np.nonzero)

    @staticmethod
    def clamp_min(a: np.ndarray, lo: Any, out: np.ndarray | None = None) -> np.ndarray:
        return np.maximum(a, lo, out=out)

    @staticmethod
    def nan_to_num(a: np.ndarray) -> np.ndarray:
        """NaN and infinities replaced by 0."""
        return np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)

    @staticmethod
    def is_floating(a: np.ndarray) -> bool:
        return bool(np.issubdtype(a.dtype, np.floating))

    @staticmethod
    def clip(a: np.ndarray, lo: Any, hi: Any, out: np.ndarray | None = None) -> np.ndarray:
        return np.clip(a, lo, hi, out=out)

    @staticmethod
    def pad_hw(a: np.ndarray, r: int, value: float) -> np.ndarray:
        """Pad the first two axes of an (H, W, ...) array by ``r`` on each side with ``value``."""
        widths = ((r, r), (r, r)) + ((0, 0),) * (a.ndim - 2)
        return np.pad(a, widths, mode="constant", constant_values=value)

    @staticmethod
    def sort0(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sorted values and indices along axis 0."""
        order = np.argsort(a, axis=0)
        return np.take_along_axis(a, order, axis=0), order

    @staticmethod
    def take(a: np.ndarray, idx: np.ndarray, axis: int) -> np.ndarray:
        return np.take(a, idx, axis=axis)

    @staticmethod
    def sub(a: Any, b: Any, out: np.ndarray) -> np.ndarray:
        return np.subtract(a, b, out=out)

    @staticmethod
    def add(a: Any, b: Any, out: np.ndarray) -> np.ndarray:
        return np.add(a, b, out=out)

    @staticmethod
    def mul(a: Any, b: Any, out: np.ndarray) -> np.ndarray:
        return np.multiply(a, b, out=out)

    @staticmethod
    def tiny(a: np.ndarray) -> float:
        return float(np.finfo(a.dtype).tiny)

    @staticmethod
    def vnorm(a: np.ndarray, axis: int = -1) -> np.ndarray:
        """Euclidean norm along ``axis``."""
        return np.linalg.norm(a, axis=axis)

    @staticmethod
    def median(a: np.ndarray) -> Any:
        """Median of all elements (the mean of the two middle ones for an even count): a numpy scalar."""
        return np.median(a)

    @staticmethod
    def quantile(a: np.ndarray, q: float) -> Any:
        """``q`` quantile of all elements, linear between the order statistics (numpy's default): a numpy scalar."""
        return np.quantile(a, q)

    @staticmethod
    def argsort(a: np.ndarray, axis: int = -1, stable: bool = False) -> np.ndarray:
        return np.argsort(a, axis=axis, kind="stable" if stable else None)

    @staticmethod
    def argmax(a: np.ndarray, axis: int) -> np.ndarray:
        return np.argmax(a, axis=axis)

    @staticmethod
    def cumsum(a: np.ndarray, axis: int = 0) -> np.ndarray:
        return np.cumsum(a, axis=axis)

    @staticmethod
    def searchsorted(sorted_: np.ndarray, v: Any, side: str = "left") -> Any:
        return np.searchsorted(sorted_, v, side=side)

    @staticmethod
    def interp(x: np.ndarray, xs: Any, ys: Any) -> np.ndarray:
        """Piecewise-linear interpolation of the points ``(xs, ys)`` (host sequences, ``xs`` increasing) at ``x``."""
        return np.interp(x, xs, ys)

    @staticmethod
    def sqnorms(a: np.ndarray) -> np.ndarray:
        """Squared Frobenius norm of each a[b], float64 (B,)."""
        flat = a.reshape(a.shape[0], -1)
        return np.array([float(np.dot(row, row)) for row in flat])

    @staticmethod
    def column(values: np.ndarray, like: np.ndarray) -> np.ndarray:
        """(B,) host values as a (B, 1, 1, 1) array of ``like``'s dtype."""
        return np.asarray(values, dtype=like.dtype).reshape(-1, 1, 1, 1)


class TorchXP:
    """The functions of the namespace for ``torch.Tensor`` (on the tensor's device)."""

    name = "torch"

    def __init__(self) -> None:
        import torch

        self.torch = torch
        self.float64 = torch.float64
        self.float32 = torch.float32
        self.index = torch.int64

    def asarray(self, a: Any, like: Any = None, dtype: Any = None) -> Any:
        # the dtype given to as_tensor: a Python float is not rounded to float32 first
        return self.torch.as_tensor(np.ascontiguousarray(a) if isinstance(a, np.ndarray) else a,
                                    dtype=dtype, device=None if like is None else like.device)

    @staticmethod
    def to_numpy(a: Any) -> np.ndarray:
        return a.detach().cpu().numpy()

    @staticmethod
    def astype(a: Any, dtype: Any) -> Any:
        return a.to(dtype)

    @staticmethod
    def copy(a: Any) -> Any:
        return a.contiguous().clone()

    @staticmethod
    def broadcast_to(a: Any, shape: Sequence[int]) -> Any:
        return a.expand(*shape)

    def dtype_of(self, name: str) -> Any:
        return {"float32": self.torch.float32, "float64": self.torch.float64}[name]

    def zeros(self, shape: Sequence[int], like: Any, dtype: Any = None) -> Any:
        return self.torch.zeros(tuple(shape), dtype=like.dtype if dtype is None else dtype, device=like.device)

    def arange(self, n: int, like: Any) -> Any:
        return self.torch.arange(n, device=like.device)

    def index_array(self, values: Any, like: Any) -> Any:
        return self.torch.as_tensor(np.asarray(values), dtype=self.torch.int64, device=like.device)

    def stack(self, arrays: Sequence[Any], axis: int = 0) -> Any:
        return self.torch.stack(list(arrays), dim=axis)

    @staticmethod
    def permute(a: Any, axes: Sequence[int]) -> Any:
        return a.permute(*axes)

    @staticmethod
    def sum(a: Any, axis: Any, keepdims: bool = False) -> Any:
        return a.sum(dim=axis, keepdim=keepdims)

    @staticmethod
    def mean(a: Any, axis: Any = None) -> Any:
        return a.mean() if axis is None else a.mean(dim=axis)

    @staticmethod
    def amax(a: Any, axis: Any, keepdims: bool = False) -> Any:
        return a.amax(dim=axis, keepdim=keepdims)

    @staticmethod
    def amin(a: Any, axis: Any, keepdims: bool = False) -> Any:
        return a.amin(dim=axis, keepdim=keepdims)

    def where(self, cond: Any, a: Any, b: Any) -> Any:
        t = self.torch
        ref = a if isinstance(a, t.Tensor) else b
        if not isinstance(a, t.Tensor):
            a = t.as_tensor(a, dtype=ref.dtype, device=ref.device)
        if not isinstance(b, t.Tensor):
            b = t.as_tensor(b, dtype=ref.dtype, device=ref.device)
        return t.where(cond, a, b)

    def sqrt(self, a: Any, out: Any = None) -> Any:
        return self.torch.sqrt(a) if out is None else self.torch.sqrt(a, out=out)

    def div(self, a: Any, b: Any, out: Any) -> Any:
        if not isinstance(a, self.torch.Tensor):
            return self.torch.mul(self.torch.reciprocal(b), a, out=out)
        return self.torch.div(a, b, out=out)

    def divide_where(self, a: Any, b: Any, ok: Any, fill: float) -> Any:
        return self.where(ok, a / self.where(ok, b, 1.0), fill)

    def exp(self, a: Any, out: Any = None) -> Any:
        return self.torch.exp(a) if out is None else self.torch.exp(a, out=out)

    def log(self, a: Any) -> Any:
        return self.torch.log(a)

    def tanh(self, a: Any) -> Any:
        return self.torch.tanh(a)

    def floor(self, a: Any) -> Any:
        return self.torch.floor(a)

    def hypot(self, a: Any, b: Any) -> Any:
        return self.torch.hypot(a, b)

    def isfinite(self, a: Any) -> Any:
        return self.torch.isfinite(a)

    def einsum(self, spec: str, *ops: Any) -> Any:
        return self.torch.einsum(spec, *ops)

    def _pair(self, a: Any, b: Any) -> tuple[Any, Any]:
        """Both as tensors (a Python number takes the other's dtype and device)."""
        t = self.torch
        if not isinstance(a, t.Tensor):
            a = t.as_tensor(a, dtype=b.dtype, device=b.device)
        elif not isinstance(b, t.Tensor):
            b = t.as_tensor(b, dtype=a.dtype, device=a.device)
        return a, b

    def maximum(self, a: Any, b: Any) -> Any:
        return self.torch.maximum(*self._pair(a, b))

    def minimum(self, a: Any, b: Any) -> Any:
        return self.torch.minimum(*self._pair(a, b))

    def arctan2(self, a: Any, b: Any) -> Any:
        return self.torch.atan2(a, b)

    def cos(self, a: Any) -> Any:
        return self.torch.cos(a)

    def concatenate(self, arrays: Sequence[Any], axis: int = 0) -> Any:
        return self.torch.cat(list(arrays), dim=axis)

    def nonzero(self, a: Any) -> tuple[Any, ...]:
        return self.torch.nonzero(a, as_tuple=True)

    def vnorm(self, a: Any, axis: int = -1) -> Any:
        return self.torch.linalg.vector_norm(a, dim=axis)

    def median(self, a: Any) -> float:
        # numpy's median: the mean of the two middle values for an even count (torch.median takes
        # the lower one); kthvalue, as torch.quantile refuses more than 2^24 elements
        f = a.reshape(-1)
        n = f.numel()
        lo = f.kthvalue((n + 1) // 2).values
        hi = f.kthvalue(n // 2 + 1).values
        return 0.5 * (float(lo) + float(hi))

    def quantile(self, a: Any, q: float) -> float:
        # numpy's linear method from two order statistics (torch.quantile refuses over 2^24 elements)
        f = a.reshape(-1)
        pos = q * (f.numel() - 1)
        lo = int(np.floor(pos))
        hi = min(lo + 1, f.numel() - 1)
        v_lo = float(f.kthvalue(lo + 1).values)
        v_hi = float(f.kthvalue(hi + 1).values) if hi != lo else v_lo
        return v_lo + (pos - lo) * (v_hi - v_lo)

    def argsort(self, a: Any, axis: int = -1, stable: bool = False) -> Any:
        return self.torch.argsort(a, dim=axis, stable=stable)

    def argmax(self, a: Any, axis: int) -> Any:
        # the first maximum, as numpy's (torch's argmax takes no bool)
        return (a.to(self.torch.uint8) if a.dtype == self.torch.bool else a).argmax(dim=axis)

    @staticmethod
    def cumsum(a: Any, axis: int = 0) -> Any:
        return a.cumsum(dim=axis)

    def searchsorted(self, sorted_: Any, v: Any, side: str = "left") -> Any:
        if not isinstance(v, self.torch.Tensor):
            v = self.torch.as_tensor(v, dtype=sorted_.dtype, device=sorted_.device)
        if v.ndim == 0:
            return self.torch.searchsorted(sorted_, v.reshape(1), right=side == "right")[0]
        return self.torch.searchsorted(sorted_, v, right=side == "right")

    def interp(self, x: Any, xs: Any, ys: Any) -> Any:
        t = self.torch
        xs = t.as_tensor(np.asarray(xs, np.float64), device=x.device)
        ys = t.as_tensor(np.asarray(ys, np.float64), device=x.device)
        xd = x.to(t.float64)
        if xs.numel() == 1:
            return t.full_like(xd, float(ys[0]))
        # np.interp: constant beyond the ends, linear between the bracketing points
        i = t.searchsorted(xs, xd.contiguous(), right=True).clamp(1, xs.numel() - 1)
        x0, x1, y0, y1 = xs[i - 1], xs[i], ys[i - 1], ys[i]
        wgt = ((xd - x0) / t.where(x1 > x0, x1 - x0, t.ones_like(x1))).clamp(0.0, 1.0)
        return y0 + wgt * (y1 - y0)

    def clamp_min(self, a: Any, lo: Any, out: Any = None) -> Any:
        return a.clamp_min(lo) if out is None else self.torch.clamp_min(a, lo, out=out)

    def nan_to_num(self, a: Any) -> Any:
        return self.torch.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)

    @staticmethod
    def is_floating(a: Any) -> bool:
        return bool(a.is_floating_point())

    def clip(self, a: Any, lo: Any, hi: Any, out: Any = None) -> Any:
        t = self.torch
        if isinstance(lo, t.Tensor) != isinstance(hi, t.Tensor):      # clamp takes two numbers or two tensors
            lo, hi = (v if isinstance(v, t.Tensor) else t.as_tensor(v, dtype=a.dtype, device=a.device)
                      for v in (lo, hi))
        if out is None:
            return self.torch.clamp(a, lo, hi)
        if out is not a:
            out.copy_(a)
        self.torch.maximum(out, lo, out=out)
        self.torch.minimum(out, hi, out=out)
        return out

    def pad_hw(self, a: Any, r: int, value: float) -> Any:
        # torch pads the last axes first: move H, W last, pad, move back
        nd = a.ndim
        moved = a.permute(*range(2, nd), 0, 1)
        p = self.torch.nn.functional.pad(moved, (r, r, r, r), value=value)
        return p.permute(nd - 2, nd - 1, *range(nd - 2))

    def sort0(self, a: Any) -> tuple[Any, Any]:
        return self.torch.sort(a, dim=0)

    @staticmethod
    def take(a: Any, idx: Any, axis: int) -> Any:
        return a.index_select(axis % a.ndim, idx)

    def sub(self, a: Any, b: Any, out: Any) -> Any:
        return self.torch.sub(a, b, out=out)

    def add(self, a: Any, b: Any, out: Any) -> Any:
        return self.torch.add(a, b, out=out)

    def mul(self, a: Any, b: Any, out: Any) -> Any:
        return self.torch.mul(a, b, out=out)

    def tiny(self, a: Any) -> float:
        return float(self.torch.finfo(a.dtype).tiny)

    def sqnorms(self, a: Any) -> np.ndarray:
        n = self.torch.linalg.vector_norm(a.reshape(a.shape[0], -1), dim=1).to(self.torch.float64)
        return (n * n).cpu().numpy()

    def column(self, values: np.ndarray, like: Any) -> Any:
        return self.torch.as_tensor(np.asarray(values, dtype=np.float64), device=like.device
                                    ).to(like.dtype).reshape(-1, 1, 1, 1)


_TORCH: TorchXP | None = None


def namespace(a: Any) -> Any:
    """:class:`NumpyXP` for a numpy array (or anything not a tensor), :class:`TorchXP` for a tensor."""
    global _TORCH
    if isinstance(a, np.ndarray) or type(a).__module__.split(".")[0] != "torch":
        return NumpyXP
    if _TORCH is None:
        _TORCH = TorchXP()
    return _TORCH
