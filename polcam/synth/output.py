"""What a rendered scene becomes: the raw mosaics a polarization sensor would read, and the files.

:func:`mosaic` samples a full-resolution stack the way a division-of-focal-plane sensor does;
:func:`write_scene` writes a :class:`polcam.synth.render.Rendered` scene, its ground truth and its
raw mosaics to a folder.
"""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from polcam.errors import FrameWriteError, LayoutError, PolcamError
from polcam.frame import Frame
from polcam.io import atomic_path, atomic_write, write_frame, write_image
from polcam.mosaic import ANGLES, Layout, parse_layout

if TYPE_CHECKING:
    from polcam.synth.render import Rendered

__all__ = ["RAW_LAYOUTS", "mosaic", "write_scene"]

#: Layouts :func:`write_scene` writes raw mosaics for.
RAW_LAYOUTS: tuple[str, ...] = ("imx250mzr", "imx250myr")


def mosaic(stack: np.ndarray, layout: str | Layout) -> np.ndarray:
    """Sample a full-resolution stack the way a polarization sensor does.

    Parameters
    ----------
    stack
        (4, H, W, 3) RGB or (4, H, W) mono stack, angles 0, 45, 90, 135.
    layout
        A polcam layout (``imx250mzr``, ``imx250myr``, ``mono:...``,
        ``color:...``) or :class:`polcam.mosaic.Layout`.

    Returns
    -------
    numpy.ndarray
        (H, W) float32 raw mosaic: pixel (r, c) holds
        ``stack[angle_index[r, c], r, c, channel_index[r, c]]`` for a colour
        layout; for a mono layout the stack's value at that angle, where an
        RGB stack is first reduced to the mean of R, G and B (a flat
        spectral response).

    Raises
    ------
    LayoutError
        A bad layout name, or a colour layout given a mono stack.
    PolcamError
        A stack that is not (4, H, W) or (4, H, W, 3).
    """
    lay = parse_layout(layout)
    arr = np.asarray(stack)
    rgb = arr.ndim == 4 and arr.shape[0] == 4 and arr.shape[3] == 3
    if not (rgb or (arr.ndim == 3 and arr.shape[0] == 4)):
        raise PolcamError(f"stack of shape {arr.shape}: expected (4, H, W, 3) or (4, H, W)")
    _, hh, ww = arr.shape[:3]
    a = lay.angle_index(hh, ww)
    rr, cc = np.indices((hh, ww))
    if lay.is_color:
        if not rgb:
            raise LayoutError(f"colour layout {lay} needs an RGB stack (4, H, W, 3), got shape {arr.shape}")
        ch = lay.channel_index(hh, ww)
        raw = arr[a, rr, cc, ch]
    else:
        mono = arr.mean(axis=-1, dtype=np.float64) if rgb else arr
        raw = mono[a, rr, cc]
    return np.asarray(raw, dtype=np.float32)


def _to_counts(raw: np.ndarray, bit_depth: int) -> np.ndarray:
    top = 2**bit_depth - 1
    counts = np.round(np.clip(raw, 0.0, 1.0) * top)
    return counts.astype(np.uint8 if bit_depth <= 8 else np.uint16)


def write_scene(rendered: Rendered, out_dir: str | PathLike[str], *, bit_depth: int = 12) -> dict[str, Path]:
    """Write a rendered scene and its ground truth to a folder.

    Files (every one written atomically):

    ``angle_000.exr``, ``angle_045.exr``, ``angle_090.exr``, ``angle_135.exr``
        the four polarizer images, float32 RGB (exact stack values);
    ``diffuse.exr``, ``specular.exr``
        the ground truth, float32 RGB (``diffuse + specular`` = the mean of
        the angle images);
    ``aolp_true.exr``, ``dolp_spec.exr``
        specular AoLP (radians) and DoLP, float32 one channel;
    ``mask.png``
        object mask, 8-bit, 255 on the object;
    ``preview.png``
        the mean of the four images, 8-bit sRGB-encoded, for viewing;
    ``raw_imx250mzr.png`` + ``raw_imx250mzr.json``, ``raw_imx250myr.png`` + ``raw_imx250myr.json``
        the raw sensor mosaics (:func:`mosaic`) as ``round(value * (2**bit_depth - 1))``
        counts in a 16-bit PNG (8-bit PNG for ``bit_depth <= 8``), with the
        sidecar every raw frame may carry (layout, width, height, bit_depth, msb_aligned=false,
        black_level=0, white_level=2**bit_depth - 1);
    ``scene.json``
        the scene spec and ``rendered.info``, and the file list.

    Parameters
    ----------
    rendered
        The output of :func:`render`.
    out_dir
        Folder to write into (created if missing).
    bit_depth
        Bits of the raw mosaics, 8 to 16.

    Returns
    -------
    dict
        File role -> path written.

    Raises
    ------
    FrameWriteError
        A bad ``bit_depth`` or an unwritable folder.
    """
    out = Path(out_dir)
    if not (isinstance(bit_depth, (int, np.integer)) and 8 <= bit_depth <= 16):
        raise FrameWriteError(f"bit_depth {bit_depth!r}: expected an integer in 8..16", path=out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FrameWriteError(f"cannot create the output folder: {exc.strerror or exc}", path=out) from exc
    stack = np.asarray(rendered.stack, dtype=np.float32)
    written: dict[str, Path] = {}
    meta = {"source": "polcam.synth.render", "scene": rendered.info.get("scene"), "seed": rendered.info.get("seed")}
    for k, ang in enumerate(ANGLES):
        written[f"angle_{ang:03d}"] = write_image(out / f"angle_{ang:03d}.exr", stack[k],
                                                  metadata={**meta, "polarizer_deg": ang})
    written["diffuse"] = write_image(out / "diffuse.exr", rendered.diffuse, metadata=meta)
    written["specular"] = write_image(out / "specular.exr", rendered.specular, metadata=meta)
    written["aolp_true"] = write_image(out / "aolp_true.exr", rendered.aolp_true, metadata=meta)
    written["dolp_spec"] = write_image(out / "dolp_spec.exr", rendered.dolp_spec, metadata=meta)

    written.update(_write_pngs(out, rendered.mask, stack))
    written.update(_write_raw(out, stack, int(bit_depth)))
    doc = {
        "info": rendered.info,
        "files": {k: p.name for k, p in written.items()},
        "raw_bit_depth": int(bit_depth),
    }
    target = out / "scene.json"
    with atomic_write(target, "w") as fh:
        fh.write(json.dumps(doc, indent=2, default=_json_default) + "\n")
    written["scene"] = target
    return written


def _write_pngs(out: Path, mask: np.ndarray, stack: np.ndarray) -> dict[str, Path]:
    """``mask.png`` (255 on the object) and ``preview.png`` (the mean over angles, sRGB-encoded), 8-bit."""
    import cv2

    def _png(name: str, img: np.ndarray) -> Path:
        target = out / name
        with atomic_path(target) as tmp:
            if not cv2.imwrite(str(tmp), img):
                raise FrameWriteError("OpenCV could not write the PNG", path=target)
        return target

    written = {"mask": _png("mask.png", np.where(mask, 255, 0).astype(np.uint8))}
    srgb = _srgb_encode(np.clip(stack.mean(axis=0), 0.0, 1.0))
    written["preview"] = _png("preview.png", cv2.cvtColor((srgb * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR))
    return written


def _srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) of linear values in [0, 1]: a line near black, then a power 1/2.4."""
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def _write_raw(out: Path, stack: np.ndarray, bit_depth: int) -> dict[str, Path]:
    """``raw_<layout>.png`` and its sidecar for each of :data:`RAW_LAYOUTS`: the mosaic in counts of ``bit_depth`` bits."""
    written = {}
    for name in RAW_LAYOUTS:
        lay = parse_layout(name)
        counts = _to_counts(mosaic(stack, lay), bit_depth)
        frame = Frame(counts, layout=lay, bit_depth=bit_depth, black_level=0.0,
                      white_level=float(2 ** bit_depth - 1), metadata={"msb_aligned": False})
        written[f"raw_{name}"] = write_frame(out / f"raw_{name}.png", frame)
    return written


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
