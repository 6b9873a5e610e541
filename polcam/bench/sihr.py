"""Fidelity of the single-image highlight-removal methods on Shen & Zheng's images.

Data: the four images of Shen & Zheng (Applied Optics 2013) with their
ground-truth diffuse layers, ``animals``, ``cups``, ``fruit``, ``masks``
(``<name>.png`` and ``<name>_gt.png``, 8-bit RGB; ``--data`` names that folder
or a folder holding it as ``shen2013/``).

Each method runs through :func:`polcam.separation.separate` on the image as
float64 in [0, 1] (8-bit values / 255).  Metrics, whole image, all channels:

* PSNR in dB with data range 1, the diffuse layer clipped to [0, 1]:
  ``10 log10(1 / MSE)``;
* SSIM from :func:`skimage.metrics.structural_similarity` with
  ``channel_axis=-1, data_range=1, gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False`` (Wang et al. 2004's Gaussian window and
  constants): the mean over the three channels of the 2-D SSIM.  MATLAB's
  ``ssim``, used for the reference figures, treats an M x N x 3 array as a
  volume (a 3-D Gaussian window that also mixes neighbouring colour planes),
  so the SSIM columns are comparable between methods here, but only roughly
  with the reference SSIM;
* seconds per image: wall time of ``separate`` after one warm-up call of the
  method, mean over the four images, and the time on ``cups`` (640 x 480).

Reference: the PSNR table of the SIHR toolbox's reproduction of each method
(V. S. Ramos, SIHR, Zenodo 3381328, README "Performance"; MATLAB psnr/ssim),
as quoted in ``shen2013/SOURCES.md`` of the project data; published figures,
kept here as an independent reference.  The deviation column is the mean over
the four images of ``|PSNR - reference PSNR|``.

Run as ``polcam bench sihr --data DIR [--methods yang10 shen13 ...]``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from skimage.metrics import structural_similarity

from polcam.errors import FrameReadError, MethodError
from polcam.separation import method_spec, separate
from polcam.separation import methods as registered

__all__ = [
    "IMAGES",
    "REFERENCE_PSNR",
    "REFERENCE_SSIM",
    "REFERENCE_SECONDS",
    "REFERENCE_SOURCE",
    "default_methods",
    "format_table",
    "load_pair",
    "mean_abs_deviation",
    "psnr",
    "run",
    "ssim",
]

#: Image names, in the reference table's column order.
IMAGES: tuple[str, ...] = ("animals", "cups", "fruit", "masks")

REFERENCE_SOURCE = (
    "SIHR toolbox reproduction (V. S. Ramos, Zenodo 3381328, README 'Performance'; "
    "MATLAB psnr/ssim), quoted in shared/data/shen2013/SOURCES.md"
)

#: Published PSNR (dB) per method and image (animals, cups, fruit, masks).
REFERENCE_PSNR: dict[str, tuple[float, float, float, float]] = {
    "tan05": (30.4, 31.6, 30.4, 25.8),
    "yoon06": (32.9, 33.3, 36.6, 34.1),
    "shen08": (34.2, 37.5, 38.0, 32.1),
    "shen09": (34.9, 37.6, 36.7, 34.0),
    "yang10": (36.5, 37.5, 36.2, 33.5),
    "shen13": (37.5, 38.3, 38.2, 32.7),
    "akashi16": (32.7, 35.9, 34.8, 34.0),
}

#: Published SSIM (MATLAB ssim on RGB volumes), same order.
REFERENCE_SSIM: dict[str, tuple[float, float, float, float]] = {
    "tan05": (0.928, 0.895, 0.907, 0.821),
    "yoon06": (0.980, 0.961, 0.961, 0.953),
    "shen08": (0.975, 0.962, 0.961, 0.943),
    "shen09": (0.985, 0.970, 0.962, 0.961),
    "yang10": (0.952, 0.937, 0.916, 0.896),
    "shen13": (0.985, 0.964, 0.958, 0.935),
    "akashi16": (0.734, 0.919, 0.901, 0.871),
}

#: Published mean runtime per image in seconds (MATLAB R2019b, i5-8250U).
REFERENCE_SECONDS: dict[str, float] = {
    "tan05": 160.0,
    "yoon06": 2.6,
    "shen08": 4.7,
    "shen09": 0.26,
    "yang10": 0.16,
    "shen13": 0.063,
    "akashi16": 180.0,
}

#: Methods without a reference row that the benchmark also runs by default.
EXTRA_METHODS: tuple[str, ...] = ("yamamoto19",)


def psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    """PSNR in dB with data range 1 over the whole array.

    Parameters
    ----------
    estimate, truth
        Arrays of one shape, values in [0, 1] (``estimate`` is clipped).

    Returns
    -------
    float
        ``10 log10(1 / MSE)``; ``inf`` when identical.
    """
    est = np.clip(np.asarray(estimate, dtype=np.float64), 0.0, 1.0)
    mse = float(np.mean((est - np.asarray(truth, dtype=np.float64)) ** 2))
    return float("inf") if mse == 0.0 else float(10.0 * np.log10(1.0 / mse))


def ssim(estimate: np.ndarray, truth: np.ndarray) -> float:
    """SSIM of two (H, W, 3) images in [0, 1]: mean of the per-channel 2-D SSIM.

    Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03, population
    covariances (Wang et al. 2004), via :func:`skimage.metrics.structural_similarity`.
    """
    est = np.clip(np.asarray(estimate, dtype=np.float64), 0.0, 1.0)
    return float(
        structural_similarity(
            np.asarray(truth, dtype=np.float64),
            est,
            channel_axis=-1,
            data_range=1.0,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
        )
    )


def mean_abs_deviation(values: Sequence[float], reference: Sequence[float]) -> float:
    """Mean of ``|values - reference|`` (dB), element by element."""
    v = np.asarray(values, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if v.shape != r.shape:
        raise ValueError(f"{v.shape} values against {r.shape} reference values")
    return float(np.mean(np.abs(v - r)))


def _data_folder(data_dir: Path) -> Path:
    data_dir = Path(data_dir)
    if (data_dir / "shen2013").is_dir() and not (data_dir / f"{IMAGES[0]}.png").exists():
        return data_dir / "shen2013"
    return data_dir


def _read_rgb(path: Path) -> np.ndarray:
    if not path.is_file():
        raise FrameReadError("file not found: expected an 8-bit RGB image", path=path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8:
        desc = "unreadable" if img is None else f"shape {img.shape}, dtype {img.dtype}"
        raise FrameReadError(f"{desc}: expected an 8-bit RGB image", path=path)
    return img[..., 2::-1].astype(np.float64) / 255.0


def load_pair(data_dir: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Input image and ground-truth diffuse layer of one test image.

    Parameters
    ----------
    data_dir
        Folder with ``<name>.png`` and ``<name>_gt.png`` (or its parent,
        holding it as ``shen2013/``).
    name
        Image name, e.g. ``"cups"``.

    Returns
    -------
    image, truth : numpy.ndarray
        (H, W, 3) float64 RGB in [0, 1].

    Raises
    ------
    FrameReadError
        Missing or unreadable file, or the two images differ in shape.
    """
    folder = _data_folder(data_dir)
    image = _read_rgb(folder / f"{name}.png")
    truth = _read_rgb(folder / f"{name}_gt.png")
    if image.shape != truth.shape:
        raise FrameReadError(
            f"ground truth of shape {truth.shape} for an image of shape {image.shape}: expected equal shapes",
            path=folder / f"{name}_gt.png",
        )
    return image, truth


def default_methods() -> list[str]:
    """Registered methods of the reference table (canonical order), then the extras."""
    known = registered()
    return [m for m in known if m in REFERENCE_PSNR] + [m for m in EXTRA_METHODS if m in known]


def run(data_dir: Path, methods: list[str] | None = None) -> list[dict[str, Any]]:
    """Run the methods on the four images and score them.

    Parameters
    ----------
    data_dir
        Folder of the Shen & Zheng images (see :func:`load_pair`).
    methods
        Method names (None: :func:`default_methods`, i.e. whatever is
        registered among the reference table's methods, plus ``yamamoto19``).

    Returns
    -------
    list of dict
        One row per method: ``method``, ``psnr`` and ``ssim`` (dicts image ->
        value), ``mean_psnr``, ``mean_ssim``, ``seconds`` (image -> s),
        ``mean_seconds``, ``seconds_640x480`` (the time on ``cups``),
        ``reference_psnr``/``reference_ssim`` (image -> value, or None),
        ``reference_seconds`` (or None), ``deviation`` (mean absolute PSNR
        deviation from the reference in dB, or None), ``info`` (image -> the
        method's own info dict: without the dispatcher's ``method``, ``seconds``,
        ``input_range`` and ``input_clipped``).

    Raises
    ------
    MethodError
        An unknown or non-single-image method name.
    FrameReadError
        Missing or unreadable images.
    """
    names = default_methods() if methods is None else list(methods)
    for m in names:
        if method_spec(m).kind != "single":
            raise MethodError(f"method {m!r} needs a polarization stack; the SIHR benchmark takes single-image methods")
    pairs = {name: load_pair(data_dir, name) for name in IMAGES}
    rows: list[dict[str, Any]] = []
    for m in names:
        separate(pairs[IMAGES[0]][0][:32, :32], method=m)  # warm-up (imports, caches)
        row: dict[str, Any] = {"method": m, "psnr": {}, "ssim": {}, "seconds": {}, "info": {}}
        for name in IMAGES:
            image, truth = pairs[name]
            t0 = time.perf_counter()
            res = separate(image, method=m)
            row["seconds"][name] = time.perf_counter() - t0
            diffuse = res.diffuse.astype(np.float64)
            row["psnr"][name] = psnr(diffuse, truth)
            row["ssim"][name] = ssim(diffuse, truth)
            row["info"][name] = {k: v for k, v in res.info.items()
                                 if k not in ("seconds", "method", "input_range", "input_clipped")}
        row["mean_psnr"] = float(np.mean([row["psnr"][n] for n in IMAGES]))
        row["mean_ssim"] = float(np.mean([row["ssim"][n] for n in IMAGES]))
        row["mean_seconds"] = float(np.mean([row["seconds"][n] for n in IMAGES]))
        row["seconds_640x480"] = row["seconds"]["cups"] if pairs["cups"][0].shape[:2] == (480, 640) else None
        ref = REFERENCE_PSNR.get(m)
        row["reference_psnr"] = dict(zip(IMAGES, ref)) if ref else None
        ref_ssim = REFERENCE_SSIM.get(m)
        row["reference_ssim"] = dict(zip(IMAGES, ref_ssim)) if ref_ssim else None
        row["reference_seconds"] = REFERENCE_SECONDS.get(m)
        row["deviation"] = (
            mean_abs_deviation([row["psnr"][n] for n in IMAGES], ref) if ref else None
        )
        rows.append(row)
    return rows


def _f(x: float | None, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown tables of :func:`run`'s rows: measured, reference, deviation, time.

    Returns
    -------
    str
        A PSNR table (per image, mean, the reference per image, the mean
        absolute deviation), an SSIM table (measured and reference) and a
        time table (mean seconds per image, seconds at 640 x 480, the
        reference's MATLAB seconds), each preceded by a line saying how it
        was computed.
    """
    lines = ["PSNR (dB), whole image, data range 1; reference: " + REFERENCE_SOURCE, ""]
    names = " / ".join(IMAGES)
    head = "| method | " + " | ".join(IMAGES) + f" | mean | reference ({names}) | mean abs. deviation |"
    lines += [head, "|" + "---|" * (len(IMAGES) + 4)]
    for r in rows:
        ref = r.get("reference_psnr")
        ref_txt = " / ".join(f"{ref[n]:.1f}" for n in IMAGES) if ref else "-"
        lines.append(
            f"| {r['method']} | " + " | ".join(f"{r['psnr'][n]:.2f}" for n in IMAGES)
            + f" | {r['mean_psnr']:.2f} | {ref_txt} | {_f(r.get('deviation'), '.2f')} |"
        )
    lines += ["", "SSIM (skimage, mean of per-channel SSIM; the reference is MATLAB's volumetric ssim)", ""]
    lines += ["| method | " + " | ".join(IMAGES) + " | mean | reference (" + " / ".join(IMAGES) + ") |",
              "|" + "---|" * (len(IMAGES) + 3)]
    for r in rows:
        ref = r.get("reference_ssim")
        ref_txt = " / ".join(f"{ref[n]:.3f}" for n in IMAGES) if ref else "-"
        lines.append(
            f"| {r['method']} | " + " | ".join(f"{r['ssim'][n]:.3f}" for n in IMAGES)
            + f" | {r['mean_ssim']:.3f} | {ref_txt} |"
        )
    lines += ["", "Time (s)", "", "| method | mean per image | 640 x 480 (cups) | reference (MATLAB, mean) |",
              "|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['method']} | {r['mean_seconds']:.3f} | {_f(r.get('seconds_640x480'), '.3f')} | "
            f"{_f(r.get('reference_seconds'), 'g')} |"
        )
    return "\n".join(lines) + "\n"
