"""The registry of separation methods and the ``separate`` dispatcher."""

from __future__ import annotations

import inspect
import time
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from polcam._names import lookup, ordered
from polcam.errors import MethodError
from polcam.separation._option_types import describe, matches

__all__ = ["Separation", "MethodSpec", "register", "separate", "methods", "method_spec",
           "default_method", "input_form", "takes_illuminant", "estimated_illuminant"]


@dataclass
class Separation:
    """Result of :func:`separate`.

    Attributes
    ----------
    diffuse, specular
        float32, (H, W, 3) for colour input, (H, W) for mono; ``diffuse +
        specular`` equals the input mean (over the four angles for a stack)
        and ``0 <= diffuse <= that mean``.
    info
        At least ``method`` and ``seconds``; iterative methods add
        ``iterations`` and ``converged``.
    """

    diffuse: np.ndarray
    specular: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class MethodSpec:
    """How a method is called.

    Attributes
    ----------
    name
        Registry name.
    fn
        ``single`` methods: ``fn(image (H, W, 3) float64 in [0, 1], **options)``;
        ``stack`` methods: ``fn(stack (4, H, W[, 3]) float64, **options)``.
        Either returns the diffuse layer (same shape as ``image`` / one angle
        image) or a tuple ``(diffuse, info_dict)``.
    kind
        ``"single"`` (one RGB image; applied to the mean of a stack) or
        ``"stack"`` (needs the four polarization angles).
    mono
        True if the method also accepts monochrome input.
    reference
        Citation of the method's paper.
    options
        The option names of a method whose function takes ``**options``
        (checked before a run); None: read from the function's signature.
    option_types
        Their types (typing expressions, :mod:`polcam.separation._option_types`)
        where declared; a signature's annotations otherwise.
    """

    name: str
    fn: Callable[..., Any]
    kind: str
    mono: bool = False
    reference: str = ""
    options: tuple[str, ...] | None = None
    option_types: Mapping[str, Any] | None = None


_METHODS: dict[str, MethodSpec] = {}

# The order polcam.METHODS lists methods in (registered methods not listed here follow).
_ORDER = ("polarized-residual", "tensor", "tensor-tau", "tensor-plain", "imin", "wen21", "tan05", "yoon06",
          "shen08", "shen09", "yang10", "shen13", "akashi16", "yamamoto19")


def register(name: str, *, kind: str, mono: bool = False, reference: str = "",
             options: Sequence[str] | Mapping[str, Any] | None = None
             ) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator registering a separation function under ``name``.

    ``options``: for a function that takes ``**options``, the option names, or
    a mapping of each name to its type (then checked before a run too).
    """
    if kind not in ("single", "stack"):
        raise ValueError(f"method kind {kind!r}: expected 'single' or 'stack'")
    types = dict(options) if isinstance(options, Mapping) else None

    def deco(fn: Callable[..., Any]) -> Callable[..., Any]:
        _METHODS[name] = MethodSpec(name, fn, kind, mono, reference,
                                    None if options is None else tuple(options), types)
        return fn

    return deco


#: The method ``separate`` runs when none is named, per input form (see :func:`input_form`).
#: Stacks: the one the default-method rule picks (docs/benchmarks.md, "Default method rule";
#: polcam.bench.default_rule) from the recorded table tests/separation/default_rule_table.json.
_DEFAULTS = {"stack": "wen21", "mono-stack": "imin", "image": "yang10"}


def default_method(form: str) -> str:
    """The method :func:`separate` uses without ``method=`` for an input of ``form``.

    ``form``: ``"stack"`` ((4, H, W, 3) colour stack), ``"mono-stack"`` ((4, H, W))
    or ``"image"`` ((H, W, 3) RGB image); process, capture and the demo use the same.
    """
    try:
        return _DEFAULTS[form]
    except KeyError:
        raise MethodError(f"input form {form!r}: expected one of {', '.join(_DEFAULTS)}") from None


def input_form(shape: Sequence[int]) -> str:
    """``"stack"``, ``"mono-stack"`` or ``"image"`` for an input of ``shape``; MethodError otherwise."""
    shape = tuple(shape)
    if len(shape) == 4 and shape[0] == 4 and shape[-1] == 3:
        return "stack"
    if len(shape) == 3 and shape[0] == 4 and shape[-1] != 3:
        return "mono-stack"
    if len(shape) == 3 and shape[-1] == 3:
        return "image"
    raise MethodError(
        f"input of shape {shape}: expected a (4, H, W, 3) colour polarization stack, "
        "a (4, H, W) mono stack or an (H, W, 3) RGB image"
    )


def methods() -> tuple[str, ...]:
    """Registered method names, in polcam's canonical order."""
    return ordered(_METHODS, _ORDER)


def method_spec(name: str) -> MethodSpec:
    """The :class:`MethodSpec` of ``name``; :class:`MethodError` if unknown."""
    return lookup(_METHODS, name, what="separation method", order=_ORDER)


def _as_input(images: Any) -> tuple[np.ndarray, str, dict[str, Any]]:
    """The input as float64 clipped to [0, 1], its form, and what the clipping did (for ``info``)."""
    arr = np.asarray(images)
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise MethodError(f"input of dtype {arr.dtype}: expected linear floats")
    if np.issubdtype(arr.dtype, np.integer):
        raise MethodError(
            f"input of integer dtype {arr.dtype}: expected linear floats in [0, 1] "
            "(normalise raw counts by the white level first)"
        )
    form = input_form(arr.shape)
    # one pass each: NaN propagates through min and max, and an infinity is the min or the max
    lo, hi = (float(arr.min()), float(arr.max())) if arr.size else (0.0, 0.0)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise MethodError("input contains NaN or infinite values: expected finite floats")
    out = np.clip(arr, 0.0, 1.0, out=np.empty(arr.shape, dtype=np.float64))
    clipped = 0.0
    if lo < 0.0 or hi > 1.0:
        clipped = float(np.count_nonzero((arr < 0.0) | (arr > 1.0))) / arr.size
    return out, form, {"input_range": [lo, hi], "input_clipped": clipped}


def takes_illuminant(method: str) -> bool:
    """Whether ``method`` takes an RGB ``illuminant`` option (so an estimate can be passed back to it)."""
    try:
        check_options(method, {"illuminant": [1.0, 1.0, 1.0]}, types=False)
    except MethodError:
        return False
    return True


def estimated_illuminant(info: dict[str, Any]) -> list[float] | None:
    """The illuminant a separation estimated, from its ``info`` (RGB, positive), or None.

    ``polarized-residual`` reports ``illuminant`` (and ``illuminant_source`` ``"given"`` when it
    was passed one: not an estimate), the tensor method ``illuminant_chromaticity``.
    """
    if info.get("illuminant_source") == "given":
        return None
    est = info.get("illuminant", info.get("illuminant_chromaticity"))
    if est is None or isinstance(est, str) or len(est) != 3 or not all(float(v) > 0 for v in est):
        return None
    return [float(v) for v in est]


def check_options(method: str, options: dict[str, Any], *, types: bool = True) -> None:
    """Refuse options ``method`` does not take, or (``types``) values not of the option's type.

    Raises
    ------
    MethodError
        Naming the option, and the options the method takes or the type expected.
    """
    _check_options(method_spec(method), options, types=types)


def _option_types(spec: MethodSpec) -> Mapping[str, Any]:
    """The declared types of a method's options, else its function's annotations ({} if unknown)."""
    if spec.option_types is not None:
        return spec.option_types
    try:
        return typing.get_type_hints(spec.fn)
    except Exception:  # noqa: BLE001 - annotations that do not evaluate: no type checks
        return {}


def _check_options(spec: MethodSpec, options: dict[str, Any], *, types: bool = True) -> None:
    """Refuse keyword options the method does not take (its declared ``options``, else its signature),
    and values that are not of an option's type."""
    if spec.options is not None:
        accepted = list(spec.options)
    else:
        try:
            params = inspect.signature(spec.fn).parameters
        except (TypeError, ValueError):  # pragma: no cover - builtins without a signature
            return
        if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            return
        accepted = [n for n, p in list(params.items())[1:]
                    if p.kind in (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)]
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise MethodError(
            f"method {spec.name!r} takes no option {', '.join(map(repr, unknown))}; "
            f"its options: {', '.join(accepted) if accepted else 'none'}"
        )
    if not types:
        return
    hints = _option_types(spec)
    for key, value in options.items():
        if key in hints and not matches(value, hints[key]):
            raise MethodError(f"option {key}={value!r} of method {spec.name!r}: expected {describe(hints[key])}")


def separate(images: Any, *, method: str | None = None, **options: Any) -> Separation:
    """Separate diffuse and specular reflection.

    Parameters
    ----------
    images
        (4, H, W, 3) polarization stack (angles 0, 45, 90, 135; RGB; linear
        float); (4, H, W) mono stack (methods that accept mono); or (H, W, 3)
        RGB image (single-image methods only).  Any finite values: they are
        clipped to [0, 1] here (the one place polcam enforces that range), so
        what :func:`polcam.demosaic` returns, whose interpolation overshoots
        [0, 1] near edges, is taken as it is.
    method
        A name from :data:`polcam.METHODS`; None (the default): the best method for
        the input's form, :func:`default_method`.
    **options
        Keyword options of the method (see its module).

    Returns
    -------
    Separation
        ``diffuse`` and ``specular`` float32 of one angle image's shape, with
        ``diffuse + specular == mean over angles`` of the clipped input (or the
        clipped image) and ``0 <= diffuse <= that mean``.  ``info`` records
        ``input_range`` ([min, max] of the input as given) and
        ``input_clipped`` (the share of its values outside [0, 1]).

    Raises
    ------
    MethodError
        Unknown method; an input the method does not accept (its shape, an
        integer dtype, NaN or infinite values).

    Examples
    --------
    A matte orange surface with a white highlight polarized along 0 degrees:

    >>> import numpy as np
    >>> import polcam
    >>> matte = np.tile([0.4, 0.2, 0.1], (8, 8, 1))
    >>> shine = np.zeros((8, 8, 1))
    >>> shine[2:4, 2:4] = 0.3
    >>> angles = np.deg2rad([0, 45, 90, 135]).reshape(4, 1, 1, 1)
    >>> stack = matte + shine * (1 + np.cos(2 * angles))  # (4, 8, 8, 3)
    >>> res = polcam.separate(stack, method="imin")
    >>> res.diffuse.shape, res.diffuse.dtype
    ((8, 8, 3), dtype('float32'))
    >>> res.diffuse[3, 3], res.specular[3, 3]
    (array([0.4, 0.2, 0.1], dtype=float32), array([0.3, 0.3, 0.3], dtype=float32))
    >>> bool(np.allclose(res.diffuse + res.specular, stack.mean(axis=0)))
    True
    >>> polcam.separate(stack).info["method"]  # the default for a colour stack
    'wen21'
    """
    spec = None if method is None else method_spec(method)
    arr, form, clipping = _as_input(images)
    if spec is None:
        spec = method_spec(default_method(form))
        method = spec.name
    if form == "mono-stack" and not spec.mono:
        raise MethodError(
            f"method {method!r} needs colour: got a mono stack of shape {arr.shape}; "
            f"mono stacks are accepted by {', '.join(m for m in methods() if _METHODS[m].mono)}"
        )
    if form == "image" and spec.kind == "stack":
        raise MethodError(
            f"method {method!r} needs a (4, H, W, 3) polarization stack; got an image of "
            f"shape {arr.shape}. Single-image methods: "
            f"{', '.join(m for m in methods() if _METHODS[m].kind == 'single')}"
        )
    _check_options(spec, options)
    reference = arr if form == "image" else arr.mean(axis=0)
    t0 = time.perf_counter()
    out = spec.fn(reference if spec.kind == "single" else arr, **options)
    seconds = time.perf_counter() - t0
    diffuse, info = out if isinstance(out, tuple) else (out, {})
    diffuse = np.asarray(diffuse, dtype=np.float64)
    if diffuse.shape != reference.shape:
        raise RuntimeError(
            f"method {method!r} returned a diffuse layer of shape {diffuse.shape}, "
            f"expected {reference.shape}"
        )
    diffuse = np.clip(np.nan_to_num(diffuse, nan=0.0, posinf=0.0, neginf=0.0), 0.0, reference)
    specular = reference - diffuse
    full_info = {"method": method, "seconds": seconds, **clipping, **dict(info)}
    return Separation(diffuse.astype(np.float32), specular.astype(np.float32), full_info)
