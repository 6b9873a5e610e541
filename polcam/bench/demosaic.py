"""Demosaicing benchmark: quality against ground truth, and speed.

Ground truth is a full-resolution polarization stack (every angle, and every
colour for RGB, at every pixel).  Each stack is mosaicked in a sensor layout
(:func:`polcam.demosaicing.mosaic_stack`), quantised to 16 bits (the same uint16 raw
goes to every method), demosaicked, and compared with the stack it came from.

Scenes: the real colour stacks of ``<data_dir>`` when a data folder is given
(:data:`REAL_SCENES`: ``real-color-stack`` and ``real-color-stacks/{cpd-61,jcpd-15}``,
four 8-bit RGB PNGs at 0, 45, 90, 135 degrees each; evaluation only, never
training data), and the synthetic scenes of :mod:`polcam.synth.patterns`.  A
colour layout gets the RGB stacks; a mono layout gets each stack's luminance
(Rec. 709 weights) and mono synthetic scenes.

Metrics, over the pixels at least :data:`BORDER` pixels from every edge:

* PSNR of each angle image I0..I135 (data range 1) and of
  ``S0 = (I0 + I45 + I90 + I135) / 2`` (data range 2), over all channels
  together for colour;
* PSNR of the DoLP (data range 1), DoLP computed per channel;
* mean absolute AoLP error in degrees, the difference taken modulo 180 and
  folded into [0, 90], over the pixels (and channels) where the ground truth
  has DoLP >= :data:`AOLP_MIN_DOLP` and S0 >= :data:`AOLP_MIN_S0` (elsewhere the
  angle is dominated by noise or undefined).

Speed: frames per second on a 2448 x 2048 uint16 raw of random values (the cost
of these methods does not depend on the content), median wall time of
``repeats`` runs after one warm-up, every method in the same process; the CPU
time of the process (all threads) is reported too, since it depends much less on
what else the machine is running.

``polanalyser`` (the common Python tool, https://github.com/elerac/polanalyser)
is measured through ``polanalyser.demosaicing(raw, COLOR_PolarMono /
COLOR_PolarRGB)``: OpenCV bilinear Bayer interpolation, IMX250 layouts only.
Its output order of angles and of colour channels is not taken on trust: it is
measured on a uniform synthetic scene of known AoLP and colour
(:func:`polanalyser_order`), and the benchmark fails if it is not a clean
permutation.

Run as ``polcam bench demosaic --data DIR``.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from polcam.demosaicing import demosaic, mosaic_stack
from polcam.demosaicing import methods as demosaic_methods
from polcam.errors import FrameReadError, MethodError
from polcam.mosaic import parse_layout
from polcam.polarimetry import aolp, dolp, stokes
from polcam.synth.patterns import SCENES, make_scene, stack_from_stokes

__all__ = [
    "AOLP_MIN_DOLP",
    "AOLP_MIN_S0",
    "BORDER",
    "DEFAULT_METHODS",
    "format_markdown",
    "load_real_stack",
    "load_real_stacks",
    "polanalyser_order",
    "quality",
    "run",
]

#: Pixels excluded from the metrics at every image edge.
BORDER = 8
#: AoLP error is measured where the ground truth has at least this DoLP ...
AOLP_MIN_DOLP = 0.1
#: ... and at least this S0 (S0 of a white unpolarized pixel is 1).
AOLP_MIN_S0 = 0.1
#: Methods measured by default: polcam's and polanalyser's bilinear.
DEFAULT_METHODS: tuple[str, ...] = ("bilinear", "eari", "lmmse", "lmmse-eari", "polanalyser")
#: Layouts measured by default (polanalyser knows only these two).
DEFAULT_LAYOUTS: tuple[str, ...] = ("imx250mzr", "imx250myr")
#: Size of the raw frame timed for the speed figures (H, W).
SPEED_SHAPE: tuple[int, int] = (2048, 2448)

_REAL_DIR = "real-color-stack"
_REAL_FILES = ("0_1.png", "45_1.png", "90_1.png", "135_1.png")
#: The real scenes: name -> (folder under the data folder, the files at 0, 45, 90, 135 degrees).
REAL_SCENES: dict[str, tuple[str, tuple[str, ...]]] = {
    "real": (_REAL_DIR, _REAL_FILES),
    "real-cpd61": ("real-color-stacks/cpd-61", ("0.png", "45.png", "90.png", "135.png")),
    "real-jcpd15": ("real-color-stacks/jcpd-15", ("0.png", "45.png", "90.png", "135.png")),
}
#: Rec. 709 luminance weights: the mono version of a real colour stack.
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


# ---------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------

def load_real_stack(data_dir: Path) -> np.ndarray:
    """The real full-resolution colour stack.

    Parameters
    ----------
    data_dir
        The shared data folder (holding ``real-color-stack/``).

    Returns
    -------
    numpy.ndarray
        (4, H, W, 3) float32 RGB in [0, 1], angles 0, 45, 90, 135.

    Raises
    ------
    FrameReadError
        A file is missing or unreadable, or the four differ in size.
    """
    return _load_stack(Path(data_dir) / _REAL_DIR, _REAL_FILES)


def load_real_stacks(data_dir: Path) -> list[tuple[str, np.ndarray]]:
    """Every real stack of :data:`REAL_SCENES` found under ``data_dir``: [(scene name, (4, H, W, 3)
    float32 RGB in [0, 1])]; scenes whose folder is absent are left out."""
    out = []
    for name, (folder, files) in REAL_SCENES.items():
        if (Path(data_dir) / folder).is_dir():
            out.append((name, _load_stack(Path(data_dir) / folder, files)))
    return out


def _load_stack(folder: Path, files: Sequence[str]) -> np.ndarray:
    images = []
    for name in files:
        path = folder / name
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None or img.ndim != 3 or img.shape[2] != 3:
            raise FrameReadError("cannot read an RGB image (expected an 8-bit RGB PNG)", path=path)
        scale = float(np.iinfo(img.dtype).max)
        images.append(img[..., ::-1].astype(np.float32) / np.float32(scale))
    if len({im.shape for im in images}) != 1:
        raise FrameReadError(f"the four angle images differ in size: {[im.shape for im in images]}",
                             path=folder)
    return np.stack(images)


def _crop(stack: np.ndarray, size: int | None) -> np.ndarray:
    """Centre crop to ``size`` x ``size`` (or the whole), sides cut to multiples of 4."""
    h, w = stack.shape[1:3]
    th = min(h, size) if size else h
    tw = min(w, size) if size else w
    th -= th % 4
    tw -= tw % 4
    y0, x0 = (h - th) // 2, (w - tw) // 2
    return np.ascontiguousarray(stack[:, y0:y0 + th, x0:x0 + tw])


def _scenes(data_dir: Path | None, size: int | None, seed: int,
            color: bool) -> list[tuple[str, np.ndarray]]:
    out = []
    for name, stack in (load_real_stacks(Path(data_dir)) if data_dir is not None else []):
        real = _crop(stack, size)
        out.append((name, real if color else np.tensordot(real, LUMA, axes=([3], [0])).astype(np.float32)))
    n = size or 512
    n -= n % 4
    for name in SCENES:
        out.append((name, make_scene(name, height=n, width=n, seed=seed, color=color).stack))
    return out


# ---------------------------------------------------------------------------
# polanalyser
# ---------------------------------------------------------------------------

def _polanalyser() -> Any | None:
    try:
        import polanalyser  # noqa: PLC0415 - optional, dev-only dependency
    except ImportError:
        return None
    return polanalyser


def polanalyser_order(pa: Any) -> dict[str, list[int]]:
    """Measure the order of polanalyser's outputs on a scene of known polarization.

    A uniform scene with AoLP 30 degrees, DoLP 0.8 (distinct intensities at
    the four angles) and, for colour, distinct R, G, B levels is mosaicked in
    the IMX250MZR and IMX250MYR layouts and demosaicked by polanalyser.

    Returns
    -------
    dict
        ``angles``: for polcam's angle index j (0, 45, 90, 135), the index of
        polanalyser's output list that holds it; ``channels``: for R, G, B the
        index of polanalyser's colour axis that holds it.

    Raises
    ------
    MethodError
        If the outputs are not a clean permutation of the expected images.
    """
    h = w = 16
    rgb = np.array([0.2, 0.5, 0.8])
    mono = stack_from_stokes(np.full((h, w), 0.9), np.float64(0.8), np.deg2rad(30.0))
    color = stack_from_stokes(np.broadcast_to(rgb, (h, w, 3)), np.float64(0.8), np.deg2rad(30.0))
    raw = np.round(mosaic_stack(mono, layout="imx250mzr") * 65535).astype(np.uint16)
    outs = pa.demosaicing(raw, pa.COLOR_PolarMono)
    got = np.array([np.median(np.asarray(o, np.float64)[4:-4, 4:-4]) / 65535 for o in outs])
    want = mono[:, 0, 0].astype(np.float64)
    angles = [int(np.argmin(np.abs(got - v))) for v in want]
    if sorted(angles) != [0, 1, 2, 3] or np.max(np.abs(got[angles] - want)) > 1e-3:
        raise MethodError(f"polanalyser mono outputs {got.round(4)} do not match the angles {want.round(4)}")
    raw = np.round(mosaic_stack(color, layout="imx250myr") * 65535).astype(np.uint16)
    outs = pa.demosaicing(raw, pa.COLOR_PolarRGB)
    first = np.asarray(outs[angles[0]], np.float64)[6:-6, 6:-6]
    got_c = np.median(first.reshape(-1, 3), axis=0) / 65535
    want_c = color[0, 0, 0].astype(np.float64)
    channels = [int(np.argmin(np.abs(got_c - v))) for v in want_c]
    if sorted(channels) != [0, 1, 2] or np.max(np.abs(got_c[channels] - want_c)) > 1e-3:
        raise MethodError(f"polanalyser colour outputs {got_c.round(4)} do not match R, G, B {want_c.round(4)}")
    return {"angles": angles, "channels": channels}


def _polanalyser_method(pa: Any, order: dict[str, list[int]], is_color: bool) -> Callable[[np.ndarray], np.ndarray]:
    code = pa.COLOR_PolarRGB if is_color else pa.COLOR_PolarMono

    def fn(raw: np.ndarray) -> np.ndarray:
        outs = pa.demosaicing(raw, code)
        stack = np.stack([outs[i] for i in order["angles"]])
        if is_color:
            stack = stack[..., order["channels"]]
        return stack.astype(np.float32) / np.float32(np.iinfo(raw.dtype).max)

    return fn


def _method_fn(method: str, layout: str, pa: Any, order: dict[str, list[int]] | None
               ) -> Callable[[np.ndarray], np.ndarray]:
    if method == "polanalyser":
        if pa is None or order is None:
            raise MethodError("polanalyser is not installed (pip install polanalyser matplotlib)")
        if layout not in DEFAULT_LAYOUTS:
            raise MethodError(f"polanalyser only knows the IMX250 layouts, not {layout!r}")
        return _polanalyser_method(pa, order, parse_layout(layout).is_color)
    known = demosaic_methods()
    if method not in known:
        raise MethodError(
            f"benchmark method {method!r} is unknown; expected one of {', '.join((*known, 'polanalyser'))}"
        )
    return lambda raw: demosaic(raw, layout=layout, method=method)


# ---------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------

def _psnr(est: np.ndarray, ref: np.ndarray, data_range: float) -> float:
    mse = float(np.mean((est.astype(np.float64) - ref.astype(np.float64)) ** 2))
    if mse == 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range**2 / mse))


def quality(gt: np.ndarray, est: np.ndarray, *, border: int = BORDER) -> dict[str, float]:
    """Quality of a demosaicked stack against its ground truth.

    Parameters
    ----------
    gt, est
        (4, H, W) or (4, H, W, 3) stacks, angles 0, 45, 90, 135, in [0, 1].
    border
        Pixels left out at every edge.

    Returns
    -------
    dict
        ``psnr_i0``, ``psnr_i45``, ``psnr_i90``, ``psnr_i135`` (dB, range 1),
        ``psnr_s0`` (dB, range 2), ``psnr_dolp`` (dB, range 1), ``aolp_mae_deg``
        (mean absolute AoLP error in degrees over the masked pixels) and
        ``aolp_fraction`` (the fraction of pixels in that mask).
    """
    if gt.shape != est.shape:
        raise MethodError(f"stacks of shapes {gt.shape} and {est.shape} cannot be compared")
    sl = (slice(None), slice(border, gt.shape[1] - border), slice(border, gt.shape[2] - border))
    g = gt[sl].astype(np.float32)
    e = est[sl].astype(np.float32)
    out: dict[str, float] = {}
    for k, angle in enumerate((0, 45, 90, 135)):
        out[f"psnr_i{angle}"] = _psnr(e[k], g[k], 1.0)
    sg, se = stokes(g), stokes(e)
    out["psnr_s0"] = _psnr(se.s0, sg.s0, 2.0)
    dg = dolp(sg)
    out["psnr_dolp"] = _psnr(dolp(se), dg, 1.0)
    mask = (dg >= AOLP_MIN_DOLP) & (sg.s0 >= AOLP_MIN_S0)
    diff = np.degrees(aolp(se).astype(np.float64) - aolp(sg).astype(np.float64))
    diff = np.abs((diff + 90.0) % 180.0 - 90.0)
    out["aolp_mae_deg"] = float(diff[mask].mean()) if mask.any() else float("nan")
    out["aolp_fraction"] = float(mask.mean())
    return out


# ---------------------------------------------------------------------------
# the benchmark
# ---------------------------------------------------------------------------

def _time(fn: Callable[[np.ndarray], np.ndarray], raw: np.ndarray,
          repeats: int) -> tuple[list[float], list[float]]:
    """Wall-clock and CPU (all threads of the process) seconds of ``repeats`` runs."""
    fn(raw)  # warm-up
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn(raw)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return wall, cpu


def run(
    *,
    data_dir: Path | None,
    size: int | None,
    seed: int,
    methods: Sequence[str] = DEFAULT_METHODS,
    layouts: Sequence[str] = DEFAULT_LAYOUTS,
    measure_quality: bool = True,
    speed: bool = True,
    speed_shape: tuple[int, int] = SPEED_SHAPE,
    repeats: int = 5,
) -> list[dict[str, Any]]:
    """Measure demosaicing quality and speed.

    Parameters
    ----------
    data_dir
        Shared data folder holding the real stacks of :data:`REAL_SCENES`; ``None``
        (or a folder without them) runs the synthetic scenes only.
    size
        Side of the scenes in pixels: the real stacks are centre-cropped to it
        (``None``: whole), the synthetic scenes are built at it (``None``: 512).
    seed
        Seed of the synthetic scenes.
    methods
        polcam method names and/or ``"polanalyser"``.
    layouts
        Layout names; the scenes are mono for mono layouts, RGB for colour ones.
    measure_quality
        Measure the quality (``False``: speed only).
    speed
        Also time every method on a ``speed_shape`` raw.
    speed_shape
        (H, W) of the timed raw.
    repeats
        Timed runs per method (after one warm-up).

    Returns
    -------
    list of dict
        ``kind="quality"`` rows (layout, scene, method, the metrics of
        :func:`quality`), ``kind="speed"`` rows (layout, method, height, width,
        seconds (median wall time), seconds_min, fps = 1 / median,
        cpu_seconds (median CPU time of all the process's threads)) and one
        ``kind="polanalyser_order"`` row when polanalyser is measured.
    """
    pa = _polanalyser() if "polanalyser" in methods else None
    order = polanalyser_order(pa) if pa is not None else None
    rows: list[dict[str, Any]] = []
    if order is not None:
        rows.append({"kind": "polanalyser_order", **order})
    for layout in layouts:
        lay = parse_layout(layout)
        fns = {m: _method_fn(m, layout, pa, order) for m in methods}
        scenes = _scenes(data_dir, size, seed, lay.is_color) if measure_quality else []
        for scene, gt in scenes:
            raw = np.round(np.clip(mosaic_stack(gt, layout=lay), 0, 1) * 65535).astype(np.uint16)
            for method, fn in fns.items():
                rows.append({"kind": "quality", "layout": layout, "scene": scene, "method": method,
                             "height": int(gt.shape[1]), "width": int(gt.shape[2]),
                             **quality(gt, fn(raw))})
        if speed:
            rng = np.random.default_rng(seed)
            raw = rng.integers(0, 65536, size=speed_shape, dtype=np.uint16)
            for method, fn in fns.items():
                wall, cpu = _time(fn, raw, repeats)
                med = statistics.median(wall)
                rows.append({"kind": "speed", "layout": layout, "method": method,
                             "height": speed_shape[0], "width": speed_shape[1],
                             "seconds": med, "seconds_min": min(wall), "fps": 1.0 / med,
                             "cpu_seconds": statistics.median(cpu)})
    return rows


# ---------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------

_COLUMNS = (("psnr_i0", "I0"), ("psnr_i45", "I45"), ("psnr_i90", "I90"), ("psnr_i135", "I135"),
            ("psnr_s0", "S0"), ("psnr_dolp", "DoLP"), ("aolp_mae_deg", "AoLP err (deg)"))


def format_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown tables of :func:`run`'s rows: quality per layout (with the mean
    over scenes per method), then speed."""
    lines: list[str] = []
    quality_rows = [r for r in rows if r["kind"] == "quality"]
    for layout in dict.fromkeys(r["layout"] for r in quality_rows):
        sel = [r for r in quality_rows if r["layout"] == layout]
        sizes = sorted({f"{r['width']}x{r['height']}" for r in sel})
        lines += [f"Layout `{layout}` (scenes {', '.join(sizes)}; PSNR in dB):", ""]
        lines.append("| scene | method | " + " | ".join(c for _, c in _COLUMNS) + " |")
        lines.append("|---|---|" + "---:|" * len(_COLUMNS))
        for r in sel:
            lines.append(f"| {r['scene']} | {r['method']} | "
                         + " | ".join(f"{r[k]:.2f}" for k, _ in _COLUMNS) + " |")
        groups = [("", sel)]
        real = [r for r in sel if r["scene"] in REAL_SCENES]
        if real and len(real) < len(sel):
            groups += [(" real", real), (" synthetic", [r for r in sel if r["scene"] not in REAL_SCENES])]
        for label, group in groups:
            for method in dict.fromkeys(r["method"] for r in group):
                ms = [r for r in group if r["method"] == method]
                means = [float(np.mean([r[k] for r in ms])) for k, _ in _COLUMNS]
                lines.append(f"| **mean of {len(ms)}{label}** | **{method}** | "
                             + " | ".join(f"**{v:.2f}**" for v in means) + " |")
        lines.append("")
    speed_rows = [r for r in rows if r["kind"] == "speed"]
    if speed_rows:
        lines += ["Speed (one frame; wall time: median of the timed runs, min in brackets; "
                  "CPU time: all threads, median):", "",
                  "| layout | method | frame | wall ms | frames per second | CPU ms |",
                  "|---|---|---|---:|---:|---:|"]
        for r in speed_rows:
            lines.append(f"| {r['layout']} | {r['method']} | {r['width']}x{r['height']} | "
                         f"{1000 * r['seconds']:.0f} ({1000 * r['seconds_min']:.0f}) | {r['fps']:.2f} | "
                         f"{1000 * r['cpu_seconds']:.0f} |")
        lines.append("")
    for r in rows:
        if r["kind"] == "polanalyser_order":
            names = ("0", "45", "90", "135")
            ang = ", ".join(f"I{names[j]} = output[{i}]" for j, i in enumerate(r["angles"]))
            ch = ", ".join(f"{c} = channel {i}" for c, i in zip("RGB", r["channels"], strict=True))
            lines.append(f"polanalyser output order, measured: {ang}; {ch}.")
            lines.append("")
    return "\n".join(lines)
