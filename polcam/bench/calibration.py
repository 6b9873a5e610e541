"""Calibration benchmark: recovered maps against planted truth, and Stokes errors before and after.

``polcam bench calibration [--layouts imx250mzr imx250myr] [--size 128] [--seed 0]``

For each layout, a synthetic sensor (:class:`~polcam.synth.sensor.ImperfectSensor`)
gets planted imperfections: gain spread 5 %, extinction ratios uniform in
[50, 300], orientation offsets of +1.5, -2, +2.5 and -1 degrees for the 0, 45, 90
and 135-degree pixels plus 1 degree of scatter, dark offsets of 3 counts RMS
around a black level of 64, 0.3 % hot pixels (80 to 800 counts); 12-bit
counts, 20000 electrons full well, 4 electrons read noise.  Then:

1. **Precision.**  Dark from ``dark_frames`` capped frames, flat from
   ``flat_frames`` frames of unpolarized light at 70 % of the range, polarizer
   from ``angles`` angles x ``per_angle`` frames at a mean of 40 %; each stage
   uses the previous ones (dark -> flat -> polarizer).  Errors per pixel
   against the planted maps, over the pixels that are neither hot nor flagged:
   dark (counts), flat gain (relative, after normalising both to mean 1 per
   angle/colour class), total gain ``flat * gain`` (relative, per colour
   class), diattenuation (absolute) and orientation (degrees).  Maximum and
   99th percentile.
2. **Stokes errors on a new scene.**  A smooth scene (:func:`smooth_scene`,
   seed + 1) with DoLP from 0 to 0.95 and AoLP over the half circle,
   exposed ``scene_frames`` times and averaged (fixed-pattern
   errors are what calibration removes; averaging keeps temporal noise from
   hiding them), and once (a single frame).  Processed by bilinear
   demosaicing at cell and at full resolution:

   - ``uncalibrated``: the reported black level subtracted, nothing else;
   - ``dark+flat``: mosaic corrections only;
   - ``mosaic``: :func:`apply_calibration` with the per-super-pixel correction;
   - ``stack``: mosaic corrections, demosaicing, then :func:`correct_stack`;
   - ``ideal sensor``: the same scene through a perfect sensor with the same
     noise (the floor set by noise and demosaicing).

   DoLP error: mean absolute difference to the true DoLP over pixels with
   true S0 >= 0.1 (at least 4 pixels from the border; each channel for
   colour).  AoLP error: mean absolute difference in degrees, modulo 180,
   where also the true DoLP >= 0.1.  Truth at cell resolution: the Stokes
   parameters averaged over each 2x2 cell.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from polcam.calibration.apply import apply_calibration, correct_stack
from polcam.calibration.estimate import calibrate_dark, calibrate_flat, calibrate_polarizer, class_index
from polcam.calibration.store import Calibration
from polcam.demosaicing import demosaic
from polcam.errors import PolcamError
from polcam.frame import Frame
from polcam.polarimetry import aolp, dolp, stokes
from polcam.separation import separate
from polcam.synth.render import render
from polcam.synth.scenes import scene
from polcam.synth.sensor import ImperfectSensor

__all__ = [
    "VARIANTS", "format_markdown", "make_calibration", "precision", "run",
    "separation_rows", "smooth_scene", "stokes_errors",
]

VARIANTS: tuple[str, ...] = ("uncalibrated", "dark+flat", "mosaic", "stack", "ideal sensor")

_BORDER = 4


def _rng(seed: int, stream: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(stream)])


def make_calibration(sensor: ImperfectSensor, *, seed: int = 0, dark_frames: int = 128, flat_frames: int = 512,
                     angles: int = 16, per_angle: int = 32, flat_level: float = 0.7,
                     polarizer_level: float = 0.4) -> tuple[Calibration, dict[str, float]]:
    """Run dark -> flat -> polarizer on frames of ``sensor``; returns the calibration and stage times (s)."""
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    dark = calibrate_dark(sensor.frames((0.0, 0.0, 0.0), n=dark_frames, rng=_rng(seed, 1)))
    times["dark"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    s0 = 2.0 * flat_level
    flat = calibrate_flat(sensor.frames((s0, 0.0, 0.0), n=flat_frames, rng=_rng(seed, 2)), base=dark)
    times["flat"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    a = np.repeat(np.arange(angles) * 180.0 / angles, per_angle)
    s0 = 2.0 * polarizer_level
    gen = _rng(seed, 3)
    frames = []
    for ang in a:
        r = np.deg2rad(2.0 * ang)
        frames += sensor.frames((s0, s0 * np.cos(r), s0 * np.sin(r)), n=1, rng=gen)
    cal = calibrate_polarizer(frames, a, base=flat)
    times["polarizer"] = time.perf_counter() - t0
    return cal, times


def _normalised(ratio: np.ndarray, classes: np.ndarray, good: np.ndarray) -> np.ndarray:
    out = ratio.copy()
    for k in np.unique(classes):
        sel = (classes == k) & good
        out[classes == k] /= ratio[sel].mean()
    return out


def precision(sensor: ImperfectSensor, cal: Calibration) -> dict[str, Any]:
    """Per-pixel errors of the recovered maps against the planted truth (see module docstring)."""
    h, w = sensor.shape
    lay = sensor.layout
    good = ~(cal.defects() | sensor.hot)
    both = class_index(lay, h, w)
    colour = class_index(lay, h, w, angle=False)
    out: dict[str, Any] = {}

    def stat(name: str, err: np.ndarray) -> None:
        e = np.abs(err[good])
        out[f"{name}_max"] = float(e.max())
        out[f"{name}_p99"] = float(np.percentile(e, 99))

    non_hot = ~sensor.hot
    e = np.abs(cal.maps["dark"] - sensor.dark)[non_hot]
    out["dark_max"] = float(e.max())
    out["dark_p99"] = float(np.percentile(e, 99))
    stat("flat", _normalised(cal.maps["flat"] / sensor.gain, both, good) - 1.0)
    total = cal.maps["flat"].astype(np.float64) * cal.maps["gain"]
    stat("gain", _normalised(total / sensor.gain, colour, good) - 1.0)
    stat("diattenuation", cal.maps["diattenuation"] - sensor.diattenuation)
    stat("orientation", np.mod(cal.maps["orientation_deg"] - sensor.orientation_deg + 90.0, 180.0) - 90.0)
    out["hot_planted"] = int(sensor.hot.sum())
    out["hot_found"] = int((cal.maps["hot"] & sensor.hot).sum())
    out["hot_false"] = int((cal.maps["hot"] & ~sensor.hot).sum())
    out["flagged"] = int(cal.defects().sum())
    out["pixels"] = int(h * w)
    return out


def _truth(scene_s: tuple[np.ndarray, np.ndarray, np.ndarray], resolution: str) -> tuple[np.ndarray, ...]:
    if resolution == "full":
        return scene_s
    out = []
    for s in scene_s:
        h, w = s.shape[:2]
        out.append(s.reshape(h // 2, 2, w // 2, 2, *s.shape[2:]).mean(axis=(1, 3)))
    return tuple(out)


def stokes_errors(stack: np.ndarray, truth: tuple[np.ndarray, np.ndarray, np.ndarray], *,
                  border: int = _BORDER) -> tuple[float, float]:
    """(DoLP mean absolute error, AoLP mean absolute error in degrees) of a stack against true Stokes maps."""
    s0_t, s1_t, s2_t = truth
    dolp_t = np.hypot(s1_t, s2_t) / np.maximum(s0_t, 1e-12)
    aolp_t = np.mod(0.5 * np.arctan2(s2_t, s1_t), np.pi)
    est = stokes(stack.astype(np.float64))
    d = dolp(est)
    a = aolp(est)
    inner = np.zeros(s0_t.shape[:2], dtype=bool)
    inner[border:-border, border:-border] = True
    if s0_t.ndim == 3:
        inner = np.repeat(inner[..., None], s0_t.shape[2], axis=2)
    m = inner & (s0_t >= 0.1)
    ma = m & (dolp_t >= 0.1)
    e_d = float(np.mean(np.abs(d - dolp_t)[m]))
    diff = np.abs(np.rad2deg(a - aolp_t)) % 180.0
    e_a = float(np.mean(np.minimum(diff, 180.0 - diff)[ma]))
    return e_d, e_a


def _field(rng: np.random.Generator, h: int, w: int, wavelengths: tuple[float, float], n: int = 4) -> np.ndarray:
    """A smooth random field in [0, 1]: ``n`` plane cosines with wavelengths (pixels) in the given range.

    Normalised by the sum of the amplitudes (not by the field's own extremes), so
    its steepness does not depend on the size of the image.
    """
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    total = np.zeros((h, w))
    amps = rng.uniform(0.5, 1.0, n)
    for a in amps:
        k = 2 * np.pi / rng.uniform(*wavelengths)
        t = rng.uniform(0, np.pi)
        total += a * np.cos(k * (x * np.cos(t) + y * np.sin(t)) + rng.uniform(0, 2 * np.pi))
    return 0.5 + 0.5 * total / amps.sum()


def smooth_scene(height: int, width: int, *, seed: int, color: bool = False,
                 wavelengths: tuple[float, float] = (400.0, 1200.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stokes maps (S0, S1, S2) of a smooth scene, for measuring calibration (not demosaicing).

    S0 in [0.08, 0.72] (a sensor with 5 % gain spread stays below saturation),
    DoLP in [0, 0.95] and AoLP over [0, pi), each a sum of plane cosines with
    wavelengths of 400 to 1200 pixels: about 1 % change per pixel at most, so
    the error of sampling the four angles at four places (the floor the
    "ideal sensor" rows show) stays well below what miscalibration causes.
    Colour scenes share DoLP and AoLP across channels and tint S0 per channel.

    Returns
    -------
    tuple of numpy.ndarray
        (H, W) maps, or (H, W, 3) with ``color``, float64.
    """
    rng = np.random.default_rng([int(seed), 7])
    lum = 0.1 + 0.8 * _field(rng, height, width, wavelengths)
    p = 0.95 * _field(rng, height, width, wavelengths)
    a = np.mod(2.0 * np.pi * _field(rng, height, width, wavelengths), np.pi)
    s0 = 0.8 * lum
    if color:
        tint = np.stack([0.6 + 0.4 * _field(rng, height, width, wavelengths) for _ in range(3)], axis=-1)
        s0 = s0[..., None] * tint
        p, a = p[..., None], a[..., None]
    return s0, s0 * p * np.cos(2 * a), s0 * p * np.sin(2 * a)


def _scene(sensor: ImperfectSensor, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h, w = sensor.shape
    return smooth_scene(h, w, seed=seed, color=sensor.layout.is_color)


def _mean_frame(sensor: ImperfectSensor, counts: np.ndarray) -> Frame:
    mean = counts.astype(np.float64).mean(axis=0) if counts.ndim == 3 else counts.astype(np.float64)
    return sensor.frame(mean.astype(np.float32))


def _process(variant: str, frame: Frame, cal: Calibration, resolution: str) -> np.ndarray:
    if variant in ("uncalibrated", "ideal sensor"):
        return demosaic(frame, method="bilinear", resolution=resolution)
    if variant == "dark+flat":
        return demosaic(apply_calibration(frame, cal, polarimetric="none"), method="bilinear", resolution=resolution)
    if variant == "mosaic":
        return demosaic(apply_calibration(frame, cal), method="bilinear", resolution=resolution)
    if variant == "stack":
        st = demosaic(apply_calibration(frame, cal, polarimetric="none"), method="bilinear", resolution=resolution)
        return correct_stack(st, cal, resolution=resolution)
    raise ValueError(variant)


def separation_rows(sensor: ImperfectSensor, cal: Calibration, *, methods: Sequence[str], seed: int = 0,
                    scene_name: str = "Bunny4", level: float = 0.7) -> list[dict[str, Any]]:
    """Diffuse/specular separation on a rendered scene seen by the miscalibrated sensor, with and without
    calibration (and through the ideal sensor).

    The scene (:mod:`polcam.synth.scenes`, rendered noise-free at the sensor's
    size, scaled by ``level`` so the gain spread does not saturate it) is
    exposed once (shot and read noise), demosaiced bilinearly at cell
    resolution, clipped to [0, 1] and separated.  Score: PSNR (data range 1)
    of the diffuse layer against the renderer's ground-truth diffuse (averaged
    over each 2x2 cell, times ``level``; mean over RGB for a mono sensor), on
    the whole image and on the object.  The Bunny mesh comes from the shared
    data folder; without it a sphere is rendered (``scene`` in the rows says
    which).
    """
    import dataclasses

    h, w = sensor.shape
    if h != w:
        raise PolcamError(f"separation benchmark: sensor of {w}x{h}: expected a square sensor")
    spec = dataclasses.replace(scene(scene_name), full_well=None, read_noise=0.0, bit_depth=None)
    try:
        r = render(spec, size=h, seed=seed)
        name = scene_name
    except PolcamError:
        r = render(dataclasses.replace(spec, mesh="sphere"), size=h, seed=seed)
        name = f"{scene_name} (sphere)"
    st = r.stack.astype(np.float64) * level
    s = (0.5 * st.sum(axis=0), st[0] - st[2], st[1] - st[3])
    truth = r.diffuse.astype(np.float64) * level
    if not sensor.layout.is_color:
        s = tuple(x.mean(axis=-1) for x in s)
        truth = truth.mean(axis=-1)
    truth = truth.reshape(h // 2, 2, w // 2, 2, *truth.shape[2:]).mean(axis=(1, 3))
    mask = r.mask.reshape(h // 2, 2, w // 2, 2).all(axis=(1, 3))
    gen = _rng(seed, 5)
    frames = {"uncalibrated": sensor.frame(sensor.expose(s, n=1, rng=gen)[0]),
              "ideal sensor": sensor.ideal().frame(sensor.ideal().expose(s, n=1, rng=gen)[0])}
    frames["calibrated"] = apply_calibration(frames["uncalibrated"], cal)
    rows = []
    for method in methods:
        for variant in ("uncalibrated", "calibrated", "ideal sensor"):
            stack = np.clip(demosaic(frames[variant], method="bilinear", resolution="cell"), 0.0, 1.0)
            t0 = time.perf_counter()
            res = separate(stack, method=method)
            seconds = time.perf_counter() - t0
            diff = np.clip(res.diffuse.astype(np.float64), 0.0, 1.0)
            mse_all = float(np.mean((diff - truth) ** 2))
            mse_obj = float(np.mean((diff - truth)[mask] ** 2))
            rows.append({"layout": str(sensor.layout), "scene": name, "method": method, "variant": variant,
                         "psnr": 10 * np.log10(1 / mse_all), "psnr_object": 10 * np.log10(1 / mse_obj),
                         "seconds": seconds})
    return rows


def run(*, layouts: Sequence[str] = ("imx250mzr", "imx250myr"), size: int = 128, seed: int = 0,
        dark_frames: int = 128, flat_frames: int = 512, angles: int = 16, per_angle: int = 32,
        scene_frames: int = 16, separation: Sequence[str] = ()) -> dict[str, Any]:
    """Run the benchmark; returns ``{"precision": [...], "stokes": [...], "separation": [...], "settings": {...}}``.

    ``separation`` names the separation methods to score (:func:`separation_rows`);
    colour-only methods are skipped on mono layouts.
    """
    prec_rows: list[dict[str, Any]] = []
    stokes_rows: list[dict[str, Any]] = []
    sep_rows: list[dict[str, Any]] = []
    for li, layout in enumerate(layouts):
        sensor = ImperfectSensor.random(layout, size, size, seed=seed + 100 * li)
        cal, times = make_calibration(sensor, seed=seed + 100 * li, dark_frames=dark_frames,
                                      flat_frames=flat_frames, angles=angles, per_angle=per_angle)
        p = precision(sensor, cal)
        p.update({"layout": layout, **{f"seconds_{k}": v for k, v in times.items()}})
        prec_rows.append(p)
        s = _scene(sensor, seed + 1)
        ideal = sensor.ideal()
        gen = _rng(seed + 100 * li, 4)
        real_counts = sensor.expose(s, n=scene_frames, rng=gen)
        ideal_counts = ideal.expose(s, n=scene_frames, rng=gen)
        for resolution in ("cell", "full"):
            truth = _truth(s, resolution)
            for variant in VARIANTS:
                row: dict[str, Any] = {"layout": layout, "resolution": resolution, "variant": variant}
                src = ideal if variant == "ideal sensor" else sensor
                counts = ideal_counts if variant == "ideal sensor" else real_counts
                for tag, c in (("mean", counts), ("single", counts[0])):
                    st = _process(variant, _mean_frame(src, c), cal, resolution)
                    e_d, e_a = stokes_errors(st, truth, border=_BORDER if resolution == "full" else _BORDER // 2)
                    row[f"dolp_{tag}"] = e_d
                    row[f"aolp_{tag}"] = e_a
                stokes_rows.append(row)
        methods = [m for m in separation if sensor.layout.is_color or m == "imin"]
        if methods:
            sep_rows += separation_rows(sensor, cal, methods=methods, seed=seed + 100 * li)
    settings = {"layouts": list(layouts), "size": size, "seed": seed, "dark_frames": dark_frames,
                "flat_frames": flat_frames, "angles": angles, "per_angle": per_angle,
                "scene_frames": scene_frames, "separation": list(separation)}
    return {"precision": prec_rows, "stokes": stokes_rows, "separation": sep_rows, "settings": settings}


def format_markdown(result: dict[str, Any]) -> str:
    """The benchmark's two tables as Markdown."""
    st = result["settings"]
    lines = [
        f"Recovered maps ({st['size']} x {st['size']} pixels; dark {st['dark_frames']} frames, flat "
        f"{st['flat_frames']} frames, polarizer {st['angles']} angles x {st['per_angle']} frames; errors "
        "over pixels neither hot nor flagged):",
        "",
        "| layout | dark max / p99 (counts) | flat gain max / p99 | total gain max / p99 | D max / p99 "
        "| orientation max / p99 (deg) | hot found / planted (false) |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in result["precision"]:
        lines.append(
            f"| {p['layout']} | {p['dark_max']:.3f} / {p['dark_p99']:.3f} "
            f"| {100 * p['flat_max']:.3f}% / {100 * p['flat_p99']:.3f}% "
            f"| {100 * p['gain_max']:.3f}% / {100 * p['gain_p99']:.3f}% "
            f"| {p['diattenuation_max']:.4f} / {p['diattenuation_p99']:.4f} "
            f"| {p['orientation_max']:.3f} / {p['orientation_p99']:.3f} "
            f"| {p['hot_found']} / {p['hot_planted']} ({p['hot_false']}) |")
    lines += [
        "",
        f"Stokes errors on a new scene (mean of {st['scene_frames']} frames; single frame in brackets), "
        "bilinear demosaicing:",
        "",
        "| layout | resolution | processing | DoLP error | AoLP error (deg) | DoLP ratio | AoLP ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    base: dict[tuple[str, str], dict[str, Any]] = {}
    for r in result["stokes"]:
        if r["variant"] == "uncalibrated":
            base[(r["layout"], r["resolution"])] = r
    for r in result["stokes"]:
        b = base[(r["layout"], r["resolution"])]
        rd = b["dolp_mean"] / max(r["dolp_mean"], 1e-12)
        ra = b["aolp_mean"] / max(r["aolp_mean"], 1e-12)
        lines.append(
            f"| {r['layout']} | {r['resolution']} | {r['variant']} "
            f"| {r['dolp_mean']:.4f} ({r['dolp_single']:.4f}) | {r['aolp_mean']:.3f} ({r['aolp_single']:.3f}) "
            f"| {rd:.1f}x | {ra:.1f}x |")
    if result.get("separation"):
        lines += [
            "",
            "Separation on a rendered scene seen by the same sensor (one frame, cell resolution; "
            "PSNR of the diffuse layer in dB, whole image / object):",
            "",
            "| layout | scene | method | uncalibrated | calibrated | ideal sensor |",
            "|---|---|---|---|---|---|",
        ]
        groups: dict[tuple[str, str, str], dict[str, dict[str, Any]]] = {}
        for r in result["separation"]:
            groups.setdefault((r["layout"], r["scene"], r["method"]), {})[r["variant"]] = r
        for (lay, scene_name, method), g in groups.items():
            cells = [f"{g[v]['psnr']:.2f} / {g[v]['psnr_object']:.2f}" for v in
                     ("uncalibrated", "calibrated", "ideal sensor")]
            lines.append(f"| {lay} | {scene_name} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
