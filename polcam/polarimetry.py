"""Linear Stokes parameters and the polarization sinusoid from four polarizer angles.

All functions take a polarization stack ``I`` of shape ``(4, ...)`` in the
angle order 0, 45, 90, 135 degrees (any trailing shape: (H, W), (H, W, 3), ...)
holding linear intensities, and return arrays of the trailing shape.

Conventions (docs/architecture.md):

* ``S0 = (I0 + I45 + I90 + I135) / 2``, ``S1 = I0 - I90``, ``S2 = I45 - I135``.
* An ideal polarizer at angle t transmits ``I(t) = Ic + Isv cos(2t - 2 phi)`` with
  ``Ic = S0 / 2``, ``Isv = sqrt(S1^2 + S2^2) / 2`` and ``phi`` the AoLP: the
  least-squares fit of the sinusoid to the four samples has this closed form.
* DoLP ``= sqrt(S1^2 + S2^2) / S0`` in [0, 1] (0 where ``S0 <= 0``).
* AoLP ``= atan2(S2, S1) / 2`` wrapped to [0, pi), in radians, measured from the
  image x axis in the direction of the 45-degree polarizer of the layout.
* ``Imin = Ic - Isv`` and ``Imax = Ic + Isv``: the least and most light any
  polarizer orientation passes.
* The fit residual ``(I0 + I90) - (I45 + I135)`` is zero for any ideal
  measurement; its magnitude flags misregistration, demosaicing artefacts,
  noise and miscalibration.

:func:`maps` computes any of these in one fused pass (float32 throughout,
strip by strip, each strip on the stack while it is in cache); the single-map
functions and :func:`polcam.pipeline.products` go through it.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import cv2
import numpy as np

__all__ = [
    "MAPS",
    "Stokes",
    "Sinusoid",
    "maps",
    "maps_from_stokes",
    "maps_together",
    "stokes",
    "dolp",
    "aolp",
    "fit_sinusoid",
    "imin",
    "imax",
    "fit_residual",
    "synthesize",
]

_ANGLES_RAD = np.deg2rad(np.array([0.0, 45.0, 90.0, 135.0]))


class Stokes(NamedTuple):
    """Linear Stokes parameters, each of the stack's trailing shape."""

    s0: np.ndarray
    s1: np.ndarray
    s2: np.ndarray


class Sinusoid(NamedTuple):
    """Fit ``I(t) = ic + isv * cos(2 t - 2 phi)`` per pixel (and channel)."""

    ic: np.ndarray
    isv: np.ndarray
    phi: np.ndarray


def _check(stack: np.ndarray) -> np.ndarray:
    arr = np.asarray(stack)
    if arr.ndim < 1 or arr.shape[0] != 4:
        raise ValueError(
            f"polarization stack of shape {arr.shape}: expected 4 angle images "
            "(0, 45, 90, 135 degrees) along the first axis"
        )
    if not np.issubdtype(arr.dtype, np.floating):
        arr = arr.astype(np.float32)
    return arr


# ---------------------------------------------------------------------------
# the fused kernel: every map in one pass over the stack, strip by strip
# ---------------------------------------------------------------------------

#: Every map :func:`maps` computes, and what it is.
MAPS: dict[str, str] = {
    "s0": "S0 = (I0 + I45 + I90 + I135) / 2",
    "s1": "S1 = I0 - I90",
    "s2": "S2 = I45 - I135",
    "dolp": "degree of linear polarization, [0, 1] (0 where S0 <= 0)",
    "aolp": "angle of linear polarization, radians in [0, pi)",
    "ic": "Ic = S0 / 2, the mean over the four angles",
    "isv": "Isv = sqrt(S1^2 + S2^2) / 2, the sinusoid's amplitude",
    "imin": "Imin = Ic - Isv",
    "imax": "Imax = Ic + Isv",
    "residual": "fit residual (I0 + I90) - (I45 + I135)",
}

_CHUNK = 1 << 16          # elements of one strip: its dozen float32 buffers stay in the L2 cache
_PARALLEL_MIN = 1 << 20   # below this many elements one thread does it all


def _threads(n: int) -> int:
    if n < _PARALLEL_MIN:
        return 1
    try:
        cpus = len(os.sched_getaffinity(0))  # the CPUs this process may run on
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        cpus = os.cpu_count() or 1
    return max(1, min(4, cpus, n // _PARALLEL_MIN))


def _magnitude(a: np.ndarray, b: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> np.ndarray:
    """``sqrt(a^2 + b^2)`` into ``out`` (within an ulp of ``hypot``; the same wherever the strip
    starts, unlike a fused SIMD loop whose tail rounds differently)."""
    np.multiply(a, a, out=out)
    out += np.multiply(b, b, out=tmp)
    return np.sqrt(out, out=out)


def _strip(src: tuple[np.ndarray, ...], from_stack: bool, outs: dict[str, np.ndarray],
           scratch: dict[str, np.ndarray]) -> None:
    """The maps of one strip of the sources (1-D, the four intensities or S0, S1, S2) into ``outs``.

    The operations and their order are those of the closed forms in the module
    docstring, element by element, so the maps do not depend on the strip size.
    """
    n = src[0].size
    dt = src[0].dtype.type
    half, zero, one, pi = dt(0.5), dt(0.0), dt(1.0), dt(np.pi)

    def buf(name: str, slot: str) -> np.ndarray:
        if name in outs:
            return outs[name]
        return scratch[slot][:n]

    need_s12 = any(k in outs for k in ("s1", "s2", "dolp", "aolp", "isv", "imin", "imax"))
    need_s0 = any(k in outs for k in ("s0", "dolp", "ic", "imin", "imax"))
    if from_stack:
        i0, i1, i2, i3 = src
        if need_s0:
            s0 = buf("s0", "s0")
            np.add(i0, i1, out=s0)
            s0 += i2
            s0 += i3
            s0 *= half
        if need_s12:
            s1 = np.subtract(i0, i2, out=buf("s1", "s1"))
            s2 = np.subtract(i1, i3, out=buf("s2", "s2"))
        if "residual" in outs:
            r = outs["residual"]
            t = scratch["t"][:n]
            np.add(i0, i2, out=r)
            r -= np.add(i1, i3, out=t)
    else:
        s0, s1, s2 = src
    if any(k in outs for k in ("dolp", "isv", "imin", "imax")):
        mag = _magnitude(s1, s2, scratch["mag"][:n], scratch["t"][:n])
        if "dolp" in outs:
            d = outs["dolp"]
            with np.errstate(divide="ignore", invalid="ignore"):
                np.divide(mag, s0, out=d)
            d[~(s0 > zero)] = zero
            np.clip(d, zero, one, out=d)
        if any(k in outs for k in ("isv", "imin", "imax")):
            isv = np.multiply(mag, half, out=buf("isv", "isv"))
            ic = np.multiply(s0, half, out=buf("ic", "ic"))
            if "imin" in outs:
                np.subtract(ic, isv, out=outs["imin"])
            if "imax" in outs:
                np.add(ic, isv, out=outs["imax"])
    if "ic" in outs and not any(k in outs for k in ("isv", "imin", "imax")):
        np.multiply(s0, half, out=outs["ic"])
    if "aolp" in outs:
        ang = outs["aolp"]
        np.arctan2(s2, s1, out=ang)
        ang *= half
        # mod pi of a value in [-pi/2, pi/2], rounded as numpy's mod rounds it: + pi where it is
        # not above 0 (a branch-free OpenCV threshold; 0 goes to pi and back to 0 below)
        if ang.dtype == np.float32:
            t = cv2.threshold(ang, 0.0, float(pi), cv2.THRESH_BINARY_INV, dst=scratch["t"][:n])[1]
            ang += t
        else:
            ang += np.where(ang > zero, zero, pi)
        ang[ang >= pi] = zero  # the sum can round up to exactly pi for tiny negative inputs


class _Request(NamedTuple):
    names: tuple[str, ...]
    dtype: np.dtype
    clip: tuple[float, float] | None


def _run(src: tuple[np.ndarray, ...], from_stack: bool, requests: list[_Request],
         shape: tuple[int, ...]) -> list[dict[str, np.ndarray]]:
    flat = tuple(np.ascontiguousarray(p).reshape(-1) for p in src)
    n = flat[0].size
    outs = [{k: np.empty(n, dtype=r.dtype) for k in r.names} for r in requests]
    chunk = min(_CHUNK, max(n, 1))
    starts = list(range(0, n, chunk))
    workers = _threads(n)

    def job(part: list[int]) -> None:
        scratch = [{k: np.empty(chunk, dtype=r.dtype) for k in ("s0", "s1", "s2", "t", "mag", "isv", "ic")}
                   for r in requests]
        inputs = [tuple(np.empty(chunk, dtype=r.dtype) for _ in flat) for r in requests]
        for a in part:
            b = min(a + chunk, n)
            for r, out, sc, buf in zip(requests, outs, scratch, inputs, strict=True):
                strips = tuple(p[a:b] for p in flat)
                if r.clip is not None or strips[0].dtype != r.dtype:
                    strips = tuple(np.copyto(q[:b - a], p, casting="unsafe") or q[:b - a]
                                   for q, p in zip(buf, strips, strict=True))
                    if r.clip is not None:
                        for q in strips:
                            np.clip(q, r.clip[0], r.clip[1], out=q)
                _strip(strips, from_stack, {k: v[a:b] for k, v in out.items()}, sc)

    if workers == 1:
        job(starts)
    else:
        size = -(-len(starts) // workers)
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for fut in [pool.submit(job, starts[i:i + size]) for i in range(0, len(starts), size)]:
                fut.result()
    return [{k: v.reshape(shape) for k, v in out.items()} for out in outs]


def _request(stack_dtype: np.dtype, names: Iterable[str], dtype: Any = None,
             clip: tuple[float, float] | None = None) -> _Request:
    names = tuple(dict.fromkeys(names))
    unknown = [n for n in names if n not in MAPS]
    if unknown:
        raise ValueError(f"unknown maps {unknown}: expected names among {', '.join(MAPS)}")
    dt = np.dtype(stack_dtype if dtype is None else dtype)
    if dt.kind != "f":
        raise ValueError(f"maps dtype {dt}: expected a float dtype")
    if clip is not None:
        clip = (float(clip[0]), float(clip[1]))
    return _Request(names, dt, clip)


def maps(stack: np.ndarray, names: Iterable[str] = ("s0", "dolp", "aolp"), *, dtype: Any = None,
         clip: tuple[float, float] | None = None) -> dict[str, np.ndarray]:
    """Several polarization maps of a stack in one fused pass.

    The stack is read once, strip by strip (on up to four threads for large
    stacks), and each strip computes every map asked for while its inputs are
    in cache: no full-size temporary beyond the results.  Each map equals the
    function of the same name (:func:`stokes`, :func:`dolp`, :func:`aolp`,
    :func:`imin`, :func:`imax`, :func:`fit_residual`).

    Parameters
    ----------
    stack
        (4, ...) intensities at 0, 45, 90, 135 degrees, any trailing shape
        ((H, W) mono, (H, W, 3) RGB); float32 stays float32, float64 float64,
        integers become float32.
    names
        Keys of :data:`MAPS`.
    dtype
        Float dtype the maps are computed and returned in (default: the
        stack's; float64 from a float32 stack is computed strip by strip, with
        no float64 copy of the stack).
    clip
        ``(low, high)``: the intensities are clipped to this range first (NaN
        stays NaN), as ``maps(np.clip(stack, low, high))`` without the copy.

    Returns
    -------
    dict
        ``name -> array`` of the stack's trailing shape, in ``dtype``.

    Raises
    ------
    ValueError
        A stack without four angles on its first axis, or an unknown name.
    """
    i = _check(stack)
    return _run(tuple(i), True, [_request(i.dtype, names, dtype, clip)], i.shape[1:])[0]


def maps_together(stack: np.ndarray, *requests: Mapping[str, Any]) -> list[dict[str, np.ndarray]]:
    """Several :func:`maps` requests on one stack, in one pass over it.

    Each request is a mapping with ``names`` and optionally ``dtype`` and
    ``clip`` (the keywords of :func:`maps`); the results equal those of
    separate :func:`maps` calls.  The pipeline uses it to compute a frame's
    products (float32, the stack as it is) and a separation method's sinusoid
    fit (float64, the stack clipped to [0, 1]) while the stack is read once.

    Returns
    -------
    list of dict
        One ``name -> array`` dict per request, in order.
    """
    i = _check(stack)
    reqs = [_request(i.dtype, r["names"], r.get("dtype"), r.get("clip")) for r in requests]
    return _run(tuple(i), True, reqs, i.shape[1:])


def maps_from_stokes(s: Stokes, names: Iterable[str] = ("dolp", "aolp")) -> dict[str, np.ndarray]:
    """:func:`maps` of given Stokes parameters (``dolp``, ``aolp``, ``isv``, ``ic``, ``imin``,
    ``imax``, and ``s0``/``s1``/``s2`` themselves), by the same fused kernel.

    Parameters
    ----------
    s
        S0, S1, S2 of one (broadcastable) shape, float (integers become float32).
    names
        Keys of :data:`MAPS` except ``residual`` (it needs the four intensities).

    Returns
    -------
    dict
        ``name -> array`` of the Stokes parameters' shape.
    """
    names = tuple(dict.fromkeys(names))
    if "residual" in names:
        raise ValueError("the fit residual needs the four intensities: use maps(stack) for it")
    return _from_stokes(s, names)


def _from_stokes(s: Stokes, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    parts = np.broadcast_arrays(*(np.asarray(p) for p in s))
    dt = np.result_type(*parts, np.float32)
    parts = [p.astype(dt, copy=False) for p in parts]
    return _run(tuple(parts), False, [_request(dt, names)], parts[0].shape)[0]


def stokes(stack: np.ndarray) -> Stokes:
    """Linear Stokes parameters of a polarization stack.

    Parameters
    ----------
    stack
        (4, ...) intensities at 0, 45, 90, 135 degrees.

    Returns
    -------
    Stokes
        ``s0`` in [0, 2 max(I)], ``s1`` and ``s2`` in [-max(I), max(I)].

    Examples
    --------
    One pixel seen through the polarizers at 0, 45, 90 and 135 degrees:

    >>> import numpy as np
    >>> import polcam
    >>> stack = np.array([0.7, 0.3, 0.1, 0.5]).reshape(4, 1, 1)
    >>> polcam.stokes(stack)
    Stokes(s0=array([[0.8]]), s1=array([[0.6]]), s2=array([[-0.2]]))
    """
    m = maps(stack, ("s0", "s1", "s2"))
    return Stokes(m["s0"], m["s1"], m["s2"])


def _one(stack_or_stokes: np.ndarray | Stokes, name: str) -> np.ndarray:
    if isinstance(stack_or_stokes, Stokes):
        return _from_stokes(stack_or_stokes, (name,))[name]
    return maps(stack_or_stokes, (name,))[name]


def dolp(stack_or_stokes: np.ndarray | Stokes) -> np.ndarray:
    """Degree of linear polarization in [0, 1] (0 where S0 <= 0).

    Accepts a (4, ...) stack or a :class:`Stokes` tuple.

    Examples
    --------
    >>> import numpy as np
    >>> import polcam
    >>> stack = np.array([0.7, 0.3, 0.1, 0.5]).reshape(4, 1, 1)
    >>> polcam.dolp(stack)  # sqrt(S1**2 + S2**2) / S0 = sqrt(0.4) / 0.8
    array([[0.79056942]])
    """
    return _one(stack_or_stokes, "dolp")


def aolp(stack_or_stokes: np.ndarray | Stokes) -> np.ndarray:
    """Angle of linear polarization in radians, in [0, pi).

    Accepts a (4, ...) stack or a :class:`Stokes` tuple.

    Examples
    --------
    >>> import numpy as np
    >>> import polcam
    >>> s = polcam.stokes(np.array([0.7, 0.3, 0.1, 0.5]).reshape(4, 1, 1))
    >>> polcam.aolp(s)  # atan2(S2, S1) / 2 = atan2(-0.2, 0.6) / 2, wrapped into [0, pi)
    array([[2.98071738]])
    """
    return _one(stack_or_stokes, "aolp")


def fit_sinusoid(stack: np.ndarray, *, dtype: Any = None) -> Sinusoid:
    """Least-squares fit of ``I(t) = Ic + Isv cos(2t - 2 phi)`` to the four angles.

    ``dtype``: as :func:`maps` (default the stack's float dtype).

    Returns
    -------
    Sinusoid
        ``ic`` = S0 / 2, ``isv`` = sqrt(S1^2 + S2^2) / 2 >= 0, ``phi`` = AoLP in [0, pi).
    """
    m = maps(stack, ("ic", "isv", "aolp"), dtype=dtype)
    return Sinusoid(m["ic"], m["isv"], m["aolp"])


def imin(stack: np.ndarray) -> np.ndarray:
    """Polarization minimum ``Ic - Isv``: the light that no polarizer angle removes."""
    return maps(stack, ("imin",))["imin"]


def imax(stack: np.ndarray) -> np.ndarray:
    """Polarization maximum ``Ic + Isv``."""
    return maps(stack, ("imax",))["imax"]


def fit_residual(stack: np.ndarray) -> np.ndarray:
    """The quality map ``(I0 + I90) - (I45 + I135)`` (zero for ideal data)."""
    return maps(stack, ("residual",))["residual"]


def synthesize(ic: np.ndarray, isv: np.ndarray, phi: np.ndarray,
               angles_deg: np.ndarray | tuple[float, ...] = (0, 45, 90, 135)) -> np.ndarray:
    """Intensities ``Ic + Isv cos(2t - 2 phi)`` at the given polarizer angles.

    Parameters
    ----------
    ic, isv, phi
        Arrays of one (broadcastable) shape; ``phi`` in radians.
    angles_deg
        Polarizer angles in degrees.

    Returns
    -------
    numpy.ndarray
        (len(angles_deg), ...) stack.
    """
    ic, isv, phi = np.broadcast_arrays(np.asarray(ic), np.asarray(isv), np.asarray(phi))
    t = np.deg2rad(np.asarray(angles_deg, dtype=np.float64)).reshape((-1,) + (1,) * ic.ndim)
    out = ic[None] + isv[None] * np.cos(2 * t - 2 * phi[None])
    dtype = np.result_type(ic.dtype, np.float32)
    return out.astype(dtype, copy=False)
