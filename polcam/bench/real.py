"""``polcam bench real``: every colour separation method on real full-resolution colour stacks.

Real stacks (every pixel measured at every polarizer angle and colour) have no
ground-truth diffuse layer, so the layers are judged by physics and by eye.
For every scene the true stack is sampled in the IMX250MYR layout
(:func:`polcam.demosaicing.mosaic_stack`), demosaiced with polcam's default
demosaicing method and clipped to [0, 1] (what a camera gives polcam), and
every method separates that stack.  Per scene and method it reports:

``over_input``
    Share of pixels whose diffuse exceeds the polarization minimum ``Imin``
    (clipped at 0) of the stack the method was given by more than 3/255 in
    any channel.  Unpolarized diffuse light passes every polarizer, so a
    diffuse layer above ``Imin`` holds light that some polarizer removes.
``over_true``
    The same against the true stack's ``Imin`` (this adds the demosaicing's
    error, whatever the method).
``spread``
    Spread of the specular layer's chromaticity ``c = S / sum_RGB S``: the RMS
    distance to the mean chromaticity, both weighted by the specular
    magnitude ``sum_RGB S`` (one light: one specular colour, spread 0).
``top_removed``
    Share of the light of the brightest 1 % of pixels (by the input's mean
    intensity) that went into the specular layer.
``achromatic_kept``
    Over the nearly unpolarized achromatic pixels (true DoLP of the grey
    image < 0.03, saturation ``(max - min) / max`` of the true mean < 0.12,
    mean intensity > 0.08): the share of their light kept in the diffuse.
``seconds``
    Wall time of the separation.

Variants (``--exposure``, ``--light``): the true stack is relit before the
camera sees it, ``clip(true * light * exposure, 0, 1)``: a longer exposure
clips what was bright, a coloured light (or a camera that is not white
balanced) tints every surface.  The achromatic set is taken from the scene as
recorded (before relighting), so ``achromatic_kept`` counts the same white and
grey surfaces under every variant.

Outputs: a Markdown table (``table.md``), ``scores.csv`` and one montage PNG
per scene (``montage_<scene>.png``: rows of methods, columns input | diffuse |
specular, the specular shown at twice its value).

The real stacks under ``../shared/data`` are CC BY-NC: read them from there
for evaluation, never copy them into the product.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from polcam.demosaicing import demosaic, mosaic_stack
from polcam.errors import FrameReadError, PolcamError
from polcam.io.atomic import atomic_path, atomic_write
from polcam.polarimetry import dolp, imin
from polcam.separation import METHODS, method_spec, separate

__all__ = ["RealScore", "find_scenes", "load_stack", "prepare", "relight", "camera_stack", "achromatic_mask",
           "brightest", "metrics", "run", "format_table", "write_outputs", "default_data"]

#: Threshold of the Imin checks (one 8-bit step is 1/255).
OVER_IMIN = 3.0 / 255.0
_ANGLES = (0, 45, 90, 135)


@dataclass
class RealScore:
    """One method on one real scene (shares in [0, 1])."""

    scene: str
    method: str
    over_input: float
    over_true: float
    spread: float
    top_removed: float
    achromatic_kept: float
    seconds: float
    error: str | None = None


def find_scenes(data: Path) -> dict[str, list[Path]]:
    """The real colour stacks under ``data``: scene name -> the four angle files (0, 45, 90, 135).

    ``data/real-color-stack/{0,45,90,135}_1.png`` is the scene ``lmmse-1``;
    every ``data/real-color-stacks/<name>/{0,45,90,135}.png`` is the scene ``<name>``.
    """
    data = Path(data)
    found: dict[str, list[Path]] = {}
    one = [data / "real-color-stack" / f"{a}_1.png" for a in _ANGLES]
    if all(p.is_file() for p in one):
        found["lmmse-1"] = one
    many = data / "real-color-stacks"
    if many.is_dir():
        for d in sorted(p for p in many.iterdir() if p.is_dir()):
            files = [d / f"{a}.png" for a in _ANGLES]
            if all(p.is_file() for p in files):
                found[d.name] = files
    return found


def load_stack(files: Sequence[Path]) -> np.ndarray:
    """Four 8- or 16-bit RGB images as a (4, H, W, 3) float64 stack in [0, 1] (RGB order)."""
    imgs = []
    for f in files:
        a = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if a is None or a.ndim != 3 or a.shape[2] != 3 or a.dtype not in (np.uint8, np.uint16):
            raise FrameReadError(f"{f}: expected an 8- or 16-bit RGB image")
        imgs.append(a[..., ::-1].astype(np.float64) / np.iinfo(a.dtype).max)
    if len({i.shape for i in imgs}) != 1:
        raise FrameReadError(f"{files[0].parent}: the four angle images differ in size")
    return np.stack(imgs)


def prepare(stack: np.ndarray, *, crop: Sequence[int] | None = None, scale: float = 1.0) -> np.ndarray:
    """Crop ``(y, x, h, w)`` then resize by ``scale`` (area averaging), to sides that are multiples of 4.

    Raises
    ------
    PolcamError
        A crop outside the image, or a scale outside (0, 1], or a result under 8 x 8 pixels.
    """
    s = np.asarray(stack, dtype=np.float64)
    h, w = s.shape[1:3]
    if crop is not None:
        y, x, ch, cw = (int(v) for v in crop)
        if y < 0 or x < 0 or ch < 1 or cw < 1 or y + ch > h or x + cw > w:
            raise PolcamError(f"crop {tuple(crop)}: expected y, x, h, w inside the {w} x {h} image")
        s = s[:, y:y + ch, x:x + cw]
    if not 0 < scale <= 1:
        raise PolcamError(f"scale {scale!r}: expected a number in (0, 1]")
    if scale != 1:
        nh, nw = max(int(round(s.shape[1] * scale)), 1), max(int(round(s.shape[2] * scale)), 1)
        s = np.stack([cv2.resize(a, (nw, nh), interpolation=cv2.INTER_AREA) for a in s])
    h4, w4 = s.shape[1] // 4 * 4, s.shape[2] // 4 * 4
    if h4 < 8 or w4 < 8:
        raise PolcamError(f"a {s.shape[2]} x {s.shape[1]} stack after crop/scale: expected at least 8 x 8")
    return np.ascontiguousarray(s[:, :h4, :w4])


def relight(true_stack: np.ndarray, *, exposure: float = 1.0,
            light: Sequence[float] = (1.0, 1.0, 1.0)) -> np.ndarray:
    """The scene under another exposure and light colour: ``clip(true_stack * light * exposure, 0, 1)``.

    Parameters
    ----------
    true_stack
        (4, H, W, 3) float in [0, 1].
    exposure
        Gain, > 0 (1.5: half a stop more light; what was above 1 / 1.5 clips).
    light
        (3,) positive RGB multipliers: the light's colour relative to the recording's white
        balance (a raw IMX250MYR frame is green-heavy, about (0.55, 1, 0.7)).

    Returns
    -------
    numpy.ndarray
        (4, H, W, 3) float64 in [0, 1].  Samples the recording had clipped stay at their clipped
        value times the gain (their true value is not known).

    Raises
    ------
    PolcamError
        A non-positive or non-finite exposure or light.
    """
    e = float(exposure)
    if not np.isfinite(e) or e <= 0:
        raise PolcamError(f"exposure {exposure!r}: expected a number > 0")
    c = np.asarray(light, dtype=np.float64).reshape(-1)
    if c.size != 3 or not np.all(np.isfinite(c)) or np.any(c <= 0):
        raise PolcamError(f"light {tuple(np.asarray(light).reshape(-1))!r}: expected three numbers > 0 (R, G, B)")
    return np.clip(np.asarray(true_stack, np.float64) * (c * e), 0.0, 1.0)


def camera_stack(true_stack: np.ndarray, *, layout: str = "imx250myr") -> np.ndarray:
    """What a colour polarization camera gives: ``true_stack`` mosaicked, demosaiced (default method), clipped."""
    raw = mosaic_stack(true_stack.astype(np.float32), layout=layout)
    return np.clip(demosaic(raw, layout=layout), 0.0, 1.0).astype(np.float64)


def _imin(stack: np.ndarray) -> np.ndarray:
    return np.maximum(imin(stack), 0.0)


def achromatic_mask(true_stack: np.ndarray) -> np.ndarray:
    """The nearly unpolarized achromatic pixels of a true stack (``achromatic_kept``), (H, W) bool.

    True DoLP of the grey image < 0.03, saturation ``(max - min) / max`` of the true mean < 0.12,
    mean intensity > 0.08.
    """
    tmean = true_stack.mean(axis=0)
    tmax, tmin = tmean.max(-1), tmean.min(-1)
    sat = (tmax - tmin) / np.maximum(tmax, 1e-6)
    return (dolp(true_stack.mean(axis=-1)) < 0.03) & (sat < 0.12) & (tmean.mean(-1) > 0.08)


def brightest(given: np.ndarray) -> np.ndarray:
    """(H, W) bool: the brightest 1 % of pixels of ``given`` ((4, H, W, C)) by their mean intensity,
    the pixels ``top_removed`` is taken over."""
    lum = np.asarray(given).mean(axis=(0, 3))
    return lum >= np.quantile(lum, 0.99)


def metrics(diffuse: np.ndarray, specular: np.ndarray, given: np.ndarray,
            true_stack: np.ndarray, *, achromatic: np.ndarray | None = None) -> dict[str, float]:
    """The physics checks of one separation (see the module docstring).

    Parameters
    ----------
    diffuse, specular
        (H, W, 3) layers, ``diffuse + specular == given.mean(0)``.
    given
        (4, H, W, 3) the stack the method separated.
    true_stack
        (4, H, W, 3) the true stack.
    achromatic
        (H, W) bool, the pixels ``achromatic_kept`` is taken over; default
        :func:`achromatic_mask` of ``true_stack``.

    Returns
    -------
    dict
        ``over_input``, ``over_true``, ``spread``, ``top_removed``, ``achromatic_kept``.
    """
    d = np.asarray(diffuse, np.float64)
    s = np.asarray(specular, np.float64)
    over_in = float(np.mean(np.any(d - _imin(given) > OVER_IMIN, axis=-1)))
    over_tr = float(np.mean(np.any(d - _imin(true_stack) > OVER_IMIN, axis=-1)))
    sp = np.maximum(s, 0.0)
    mag = sp.sum(axis=-1)
    ok = mag > 1e-6
    if ok.sum() > 0:
        c = sp[ok] / mag[ok, None]
        wgt = mag[ok]
        mean_c = (c * wgt[:, None]).sum(0) / wgt.sum()
        spread = float(np.sqrt((((c - mean_c) ** 2).sum(1) * wgt).sum() / wgt.sum()))
    else:
        spread = 0.0
    inp = given.mean(axis=0)
    top = brightest(given)
    top_removed = float(s[top].sum() / max(inp[top].sum(), 1e-12))
    ach = achromatic_mask(true_stack) if achromatic is None else np.asarray(achromatic, bool)
    kept = float(d[ach].sum() / inp[ach].sum()) if ach.any() and inp[ach].sum() > 0 else float("nan")
    return {"over_input": over_in, "over_true": over_tr, "spread": spread, "top_removed": top_removed,
            "achromatic_kept": kept}


def _colour_methods() -> list[str]:
    return list(METHODS)


def run(data: Path, *, methods: Sequence[str] | None = None, scenes: Sequence[str] | None = None,
        crop: Sequence[int] | None = None, scale: float = 1.0,
        exposure: float = 1.0, light: Sequence[float] = (1.0, 1.0, 1.0),
        options: dict[str, dict[str, Any]] | None = None,
        progress: bool = True) -> tuple[list[RealScore], dict[str, dict[str, np.ndarray]]]:
    """Separate every real scene with every method and score it.

    Parameters
    ----------
    data
        Folder holding ``real-color-stack/`` and/or ``real-color-stacks/<scene>/``.
    methods
        Method names (default: every registered method; all of them take colour stacks).
    scenes
        Only these scenes (names from :func:`find_scenes`).
    crop, scale
        Applied to the true stack first (:func:`prepare`).
    exposure, light
        Then the scene is relit (:func:`relight`); ``achromatic_kept`` stays on the surfaces
        that are achromatic as recorded.
    options
        Per-method keyword options.

    Returns
    -------
    scores : list of RealScore
    layers : dict
        Per scene: ``input`` (H, W, 3) and ``<method>/diffuse``, ``<method>/specular``, for the montage.

    Raises
    ------
    PolcamError
        No real stack in ``data``, or an unknown scene name.
    MethodError
        An unknown method name.
    """
    found = _scenes(data, scenes)
    meths = list(methods or _colour_methods())
    for m in meths:
        method_spec(m)  # an unknown name is refused before any work
    relight(np.zeros((4, 1, 1, 3)), exposure=exposure, light=light)   # bad values refused before any work
    options = options or {}
    scores: list[RealScore] = []
    layers: dict[str, dict[str, np.ndarray]] = {}
    for name, files in found.items():
        recorded = prepare(load_stack(files), crop=crop, scale=scale)
        ach = achromatic_mask(recorded)
        true = relight(recorded, exposure=exposure, light=light)
        given = camera_stack(true)
        layers[name] = {"input": given.mean(axis=0)}
        for m in meths:
            score, res = _score(name, m, given, true, ach, options.get(m, {}))
            scores.append(score)
            if res is None:
                continue
            layers[name][f"{m}/diffuse"] = res.diffuse
            layers[name][f"{m}/specular"] = res.specular
            if progress:
                s = scores[-1]
                print(f"  {name:<9} {m:<19} >Imin {s.over_input:6.2%} (true {s.over_true:6.2%})  "
                      f"spread {s.spread:.3f}  top1% removed {s.top_removed:.3f}  "
                      f"achromatic kept {s.achromatic_kept:.3f}  {s.seconds:6.2f} s", flush=True)
    return scores, layers


def _scenes(data: Path, scenes: Sequence[str] | None) -> dict[str, Any]:
    """The real stacks under ``data`` (only ``scenes`` when given); PolcamError when none or one is unknown."""
    found = find_scenes(Path(data))
    if not found:
        raise PolcamError(f"--data {data}: no real colour stack found (expected real-color-stack/"
                          "{0,45,90,135}_1.png or real-color-stacks/<scene>/{0,45,90,135}.png)")
    if scenes:
        unknown = [s for s in scenes if s not in found]
        if unknown:
            raise PolcamError(f"scene(s) {', '.join(unknown)} not in {data}; found {', '.join(found)}")
        found = {k: v for k, v in found.items() if k in scenes}
    return found


def _score(name: str, m: str, given: np.ndarray, true: np.ndarray, ach: np.ndarray,
           options: dict[str, Any]) -> tuple[RealScore, Any]:
    """One method on one scene: its score and the separation (None when the method failed: the
    error is in the score, not fatal to the table)."""
    t0 = time.perf_counter()
    try:
        res = separate(given, method=m, **options)
    except Exception as exc:  # a failing method is reported, not fatal to the table
        return RealScore(name, m, *([float("nan")] * 5), time.perf_counter() - t0,
                         error=f"{type(exc).__name__}: {exc}"), None
    sec = float(res.info.get("seconds", time.perf_counter() - t0))
    mt = metrics(res.diffuse, res.specular, given, true, achromatic=ach)
    return RealScore(name, m, seconds=sec, **mt), res


def format_table(scores: Sequence[RealScore]) -> str:
    """Markdown: one row per scene and method."""
    lines = ["| scene | method | diffuse > Imin + 3/255 (given) | (true Imin) | specular colour spread | "
             "brightest 1 % removed | achromatic kept | seconds |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for s in scores:
        if s.error:
            lines.append(f"| {s.scene} | {s.method} | error: {s.error} | | | | | |")
            continue
        lines.append(f"| {s.scene} | {s.method} | {s.over_input:.2%} | {s.over_true:.2%} | {s.spread:.3f} | "
                     f"{s.top_removed:.3f} | {s.achromatic_kept:.3f} | {s.seconds:.2f} |")
    return "\n".join(lines)


def _tile(img: np.ndarray, width: int, label: str) -> np.ndarray:
    h, w = img.shape[:2]
    nh = max(int(round(h * width / w)), 1)
    t = cv2.resize(np.clip(img, 0, 1).astype(np.float32), (width, nh), interpolation=cv2.INTER_AREA)
    t = (t * 255 + 0.5).astype(np.uint8)[..., ::-1].copy()  # BGR for OpenCV
    cv2.putText(t, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(t, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return t


def montage(layers: dict[str, np.ndarray], methods: Sequence[str], *, width: int = 360) -> np.ndarray:
    """One scene's montage, BGR uint8: a row per method, input | diffuse | specular x 2."""
    rows = []
    for m in methods:
        if f"{m}/diffuse" not in layers:
            continue
        rows.append(np.concatenate([_tile(layers["input"], width, "input"),
                                    _tile(layers[f"{m}/diffuse"], width, f"{m}: diffuse"),
                                    _tile(2 * layers[f"{m}/specular"], width, f"{m}: specular x2")], axis=1))
    return np.concatenate(rows, axis=0) if rows else np.zeros((8, 3 * width, 3), np.uint8)


def write_outputs(scores: Sequence[RealScore], layers: dict[str, dict[str, np.ndarray]],
                  out_dir: Path) -> list[Path]:
    """``scores.csv``, ``table.md`` and ``montage_<scene>.png`` in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["scene", "method", "over_input", "over_true", "spread", "top_removed", "achromatic_kept",
                "seconds", "error"])
    for s in scores:
        w.writerow([s.scene, s.method, f"{s.over_input:.5f}", f"{s.over_true:.5f}", f"{s.spread:.5f}",
                    f"{s.top_removed:.5f}", f"{s.achromatic_kept:.5f}", f"{s.seconds:.3f}", s.error or ""])
    written = []
    with atomic_write(out_dir / "scores.csv", "w") as fh:
        fh.write(buf.getvalue())
    written.append(out_dir / "scores.csv")
    with atomic_write(out_dir / "table.md", "w") as fh:
        fh.write(format_table(scores) + "\n")
    written.append(out_dir / "table.md")
    methods = list(dict.fromkeys(s.method for s in scores))
    for scene, lay in layers.items():
        path = out_dir / f"montage_{scene}.png"
        ok, enc = cv2.imencode(".png", montage(lay, methods))
        if not ok:  # pragma: no cover - OpenCV failure
            raise PolcamError(f"{path}: PNG encoding failed")
        with atomic_path(path) as tmp:
            tmp.write_bytes(enc.tobytes())
        written.append(path)
    return written


def default_data() -> Path | None:
    """The shared data folder holding the real stacks (``../shared/data`` from the working folder or
    the checkout), or None when neither holds one."""
    for cand in (Path("../shared/data"), Path(__file__).resolve().parents[2].parent / "shared" / "data"):
        if find_scenes(cand):
            return cand
    return None
