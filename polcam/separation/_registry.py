"""The registry of separation methods and the ``separate`` dispatcher."""

from __future__ import annotations

import inspect
import time
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from polcam.errors import MethodError
from polcam.mosaic import Layout, parse_layout
from polcam.registry import Registry
from polcam.separation._option_types import describe, matches

__all__ = ["Separation", "MethodSpec", "ResolvedSeparation", "register", "unregister", "separate", "methods",
           "method_spec", "default_method", "input_form", "layout_form", "resolve_separation", "check_options",
           "takes_illuminant", "estimated_illuminant"]


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

    def accepted(self) -> tuple[str, ...] | None:
        """The option names the method takes (its declared ``options``, else its signature's keyword
        parameters after the image); None: any (a signature with ``**options``)."""
        if self.options is not None:
            return tuple(self.options)
        try:
            params = inspect.signature(self.fn).parameters
        except (TypeError, ValueError):  # pragma: no cover - builtins without a signature
            return None
        if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            return None
        return tuple(n for n, p in list(params.items())[1:]
                     if p.kind in (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD))

    def takes(self, option: str) -> bool:
        """Whether the method takes the keyword option ``option``."""
        accepted = self.accepted()
        return accepted is None or option in accepted


#: The input forms :func:`separate` accepts (see :func:`input_form`).
FORMS: tuple[str, ...] = ("stack", "mono-stack", "image")

#: Every registered separation method.  Listing order: polcam.METHODS (registered methods not
#: listed follow).  Defaults: the method ``separate`` runs when none is named, per input form;
#: for stacks the one the default-method rule picks (docs/benchmarks.md, "Default method rule";
#: polcam.bench.default_rule) from the recorded table tests/separation/default_rule_table.json.
#: Plugins: the modules of other distributions' ``polcam.separation`` entry points.
REGISTRY: Registry[MethodSpec] = Registry(
    "separation method",
    order=("polarized-residual", "tensor", "tensor-tau", "tensor-plain", "imin", "wen21", "tan05", "yoon06",
           "shen08", "shen09", "yang10", "shen13", "akashi16", "yamamoto19"),
    defaults={"stack": "wen21", "mono-stack": "polarized-residual", "image": "yang10"},
    plugins="polcam.separation",
)


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
        REGISTRY.add(name, MethodSpec(name, fn, kind, mono, reference,
                                      None if options is None else tuple(options), types))
        return fn

    return deco


def unregister(name: str) -> MethodSpec:
    """Remove the method ``name`` from the registry (a method registered for a test or a session);
    returns its :class:`MethodSpec`.  :class:`MethodError` if it is not registered."""
    return REGISTRY.remove(name)


def default_method(form: str) -> str:
    """The method :func:`separate` uses without ``method=`` for an input of ``form``.

    ``form``: ``"stack"`` ((4, H, W, 3) colour stack), ``"mono-stack"`` ((4, H, W))
    or ``"image"`` ((H, W, 3) RGB image); process, capture and the demo use the same.
    """
    return REGISTRY.default(form)


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


def layout_form(layout: str | Layout) -> str:
    """The input form of what a sensor of ``layout`` demosaics into: ``"stack"`` (colour) or ``"mono-stack"``."""
    return "stack" if parse_layout(layout).is_color else "mono-stack"


def methods() -> tuple[str, ...]:
    """Registered method names, in polcam's canonical order."""
    return REGISTRY.names()


def method_spec(name: str) -> MethodSpec:
    """The :class:`MethodSpec` of ``name``; :class:`MethodError` if unknown."""
    return REGISTRY.get(name)


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


@dataclass(frozen=True)
class ResolvedSeparation:
    """A separation method resolved for one input form: the value that travels from a command to the method.

    Made by :func:`resolve_separation` (the one place a method name is looked up, the default for
    a form picked, the form checked against the method and the options checked against it) and
    taken by :func:`separate` (``method=``), :func:`polcam.pipeline.run_frame`, ``polcam process``
    and the live view of ``polcam capture`` as it is.

    Attributes
    ----------
    spec
        The method's registry entry.
    form
        The input form it runs on: ``"stack"``, ``"mono-stack"`` or ``"image"``.
    options
        Its keyword options (read-only), names and types checked.
    """

    spec: MethodSpec
    form: str
    options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def method(self) -> str:
        """The method's registry name."""
        return self.spec.name

    def takes(self, option: str) -> bool:
        """Whether the method takes the keyword option ``option``."""
        return self.spec.takes(option)

    def with_options(self, **options: Any) -> ResolvedSeparation:
        """This resolution with ``options`` added (or replaced), each checked against the method."""
        _check_options(self.spec, options)
        return ResolvedSeparation(self.spec, self.form, MappingProxyType({**self.options, **options}))

    def for_form(self, form: str, *, got: str | None = None) -> ResolvedSeparation:
        """The same method and options for inputs of ``form``; :class:`MethodError` if it does not take
        them (``got`` describes the input in the message)."""
        _check_form(self.spec, form, got)
        return ResolvedSeparation(self.spec, form, self.options)

    def __reduce__(self) -> tuple[Any, ...]:
        # to another process by name: the registry entry there is the same method
        return (resolve_separation, (self.method, self.form, dict(self.options)))


def resolve_separation(method: str | None, form: str, options: Mapping[str, Any] | None = None, *,
                       only_taken: bool = False, got: str | None = None) -> ResolvedSeparation:
    """Resolve a separation method for inputs of ``form``, once: what :func:`separate` then runs.

    Parameters
    ----------
    method
        A registered name; None: :func:`default_method` of ``form``.
    form
        ``"stack"``, ``"mono-stack"`` or ``"image"`` (:func:`input_form`, :func:`layout_form`).
    options
        The method's keyword options.
    only_taken
        Drop the options the method does not take instead of refusing them (options meant for
        whichever default method an input's form gets).
    got
        The input, for the message when the method does not take ``form`` (``"mono frames"``).

    Raises
    ------
    MethodError
        An unknown method or form; a method that does not take ``form``; an option it does not
        take, or a value not of the option's type.
    """
    if form not in FORMS:
        raise MethodError(f"input form {form!r}: expected one of {', '.join(FORMS)}")
    spec = REGISTRY.get(REGISTRY.default(form) if method is None else method)
    opts = dict(options or {})
    if only_taken:
        opts = {k: v for k, v in opts.items() if spec.takes(k)}
    _check_options(spec, opts)
    _check_form(spec, form, got)
    return ResolvedSeparation(spec, form, MappingProxyType(opts))


def _check_form(spec: MethodSpec, form: str, got: str | None) -> None:
    """Refuse an input form the method does not take (mono stacks; images for stack methods)."""
    if form == "mono-stack" and not spec.mono:
        mono = ", ".join(m for m in methods() if REGISTRY.get(m).mono)
        raise MethodError(f"method {spec.name!r} needs colour frames: got {got or 'a mono stack'}; "
                          f"mono stacks are accepted by {mono}")
    if form == "image" and spec.kind == "stack":
        single = ", ".join(m for m in methods() if REGISTRY.get(m).kind == "single")
        raise MethodError(f"method {spec.name!r} needs a (4, H, W, 3) polarization stack; got "
                          f"{got or 'an RGB image'}. Single-image methods: {single}")


def takes_illuminant(method: str | MethodSpec) -> bool:
    """Whether ``method`` takes an RGB ``illuminant`` option (so an estimate can be passed back to it)."""
    spec = method if isinstance(method, MethodSpec) else method_spec(method)
    return spec.takes("illuminant")


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


def check_options(method: str | MethodSpec, options: Mapping[str, Any], *, types: bool = True) -> None:
    """Refuse options ``method`` does not take, or (``types``) values not of the option's type.

    Raises
    ------
    MethodError
        Naming the option, and the options the method takes or the type expected.
    """
    _check_options(method if isinstance(method, MethodSpec) else method_spec(method), options, types=types)


def _option_types(spec: MethodSpec) -> Mapping[str, Any]:
    """The declared types of a method's options, else its function's annotations ({} if unknown)."""
    if spec.option_types is not None:
        return spec.option_types
    try:
        return typing.get_type_hints(spec.fn)
    except Exception:  # noqa: BLE001 - annotations that do not evaluate: no type checks
        return {}


def _check_options(spec: MethodSpec, options: Mapping[str, Any], *, types: bool = True) -> None:
    """Refuse keyword options the method does not take (its declared ``options``, else its signature),
    and values that are not of an option's type."""
    accepted = spec.accepted()
    if accepted is None:
        return
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


def separate(images: Any, *, method: str | ResolvedSeparation | None = None, **options: Any) -> Separation:
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
        the input's form, :func:`default_method`; or a :class:`ResolvedSeparation`
        of the input's form, run as it is (``options`` are added to its own).
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
    arr, form, clipping = _as_input(images)
    if isinstance(method, ResolvedSeparation):
        resolved = method.with_options(**options) if options else method
        if resolved.form != form:
            resolved = resolved.for_form(form, got=_describe(form, arr.shape))
    else:
        resolved = resolve_separation(method, form, options, got=_describe(form, arr.shape))
    return _run(arr, resolved, clipping)


def _describe(form: str, shape: tuple[int, ...]) -> str:
    """The input, for messages: ``"a mono stack of shape (4, 5, 5)"``."""
    what = {"mono-stack": "a mono stack", "image": "an image"}.get(form, "a stack")
    return f"{what} of shape {shape}"


def _run(arr: np.ndarray, resolved: ResolvedSeparation, clipping: dict[str, Any]) -> Separation:
    """Call the resolved method on the clipped input and hold its result to the scale contract."""
    spec, method = resolved.spec, resolved.method
    reference = arr if resolved.form == "image" else arr.mean(axis=0)
    t0 = time.perf_counter()
    out = spec.fn(reference if spec.kind == "single" else arr, **resolved.options)
    seconds = time.perf_counter() - t0
    diffuse, info = out if isinstance(out, tuple) else (out, {})
    diffuse = np.asarray(diffuse, dtype=np.float64)
    if diffuse.shape != reference.shape:
        raise RuntimeError(
            f"method {method!r} returned a diffuse layer of shape {diffuse.shape}, "
            f"expected {reference.shape}"
        )
    from polcam.separation._kernels import finish_layers  # numba: imported on first use

    # float32 clip(nan_to_num(diffuse, nan=0, posinf=0, neginf=0), 0, reference) and the rest
    d32, s32 = finish_layers(np.ascontiguousarray(diffuse).reshape(-1),
                             np.ascontiguousarray(reference, dtype=np.float64).reshape(-1))
    full_info = {"method": method, "seconds": seconds, **clipping, **dict(info)}
    return Separation(d32.reshape(reference.shape), s32.reshape(reference.shape), full_info)
