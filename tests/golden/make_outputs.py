"""Write tests/golden/outputs.npz: every method's output on small fixed inputs.

Run from a checkout of the code whose outputs are to be pinned (the arrays in
the file were written by the main branch at commit c127ec1):

    PYTHONPATH=$PWD python tests/golden/make_outputs.py

Inputs (all from fixtures/raw, nothing random):

* ``colour``: the 64x64 mosaic of ``synthetic_bunny5.png`` at offset (88, 88)
  normalised by its white level, demosaiced by ``bilinear`` at the cell
  resolution: a (4, 32, 32, 3) float32 stack, stored as ``input/colour``.
* ``mono``: the 64x64 mosaic of ``fruits_crop.png`` at offset (256, 192),
  likewise: a (4, 32, 32) float32 stack, stored as ``input/mono``.
* ``bunny``: the central 160x160 mosaic of ``synthetic_bunny5.png`` (offset
  (48, 48)) at the cell resolution ((4, 80, 80, 3)), for ``wen21`` and ``polarized-residual`` only (their
  diffuse layers), stored as ``input/bunny``.

The ``live/aolp/*`` and ``live/dolp/*`` arrays were then rewritten deliberately: the live route
takes its DoLP and AoLP from the fused kernel of :mod:`polcam.polarimetry` (AoLP by atan2
instead of OpenCV's approximation, which was up to 1e-4 rad off; DoLP 0 where S0 is 0, where
OpenCV's 0/0 had given 1).  The ``sep/tensor*`` arrays were rewritten when the tensor method's
Imin bound became an option, off by default (the old arrays are those of ``imin_bound=True``,
checked equal), the ``sep/polarized-residual/*`` arrays when that method was rebuilt
(docs/methods/polarized-residual.md), and its ``mono`` arrays when mono stacks got their own
learned-stage weights and bound (docs/decisions/mono-learned-stage.md).  Entries are rewritten one family at a time: every other entry must still
match the file.

Outputs: ``sep/<method>/<form>/{diffuse,specular}`` for every separation
method and form it takes; ``demosaic/<method>/<form>/<resolution>`` for every
demosaicing method; ``maps/<fn>/<form>`` for the polarimetry functions;
``products/<name>/<form>`` for :func:`polcam.pipeline.products`;
``live/<field>/<form>`` for :func:`polcam.pipeline.live_maps`.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

import polcam
from polcam import pipeline
from polcam.frame import Frame
from polcam.io import read_frame
from polcam.separation import method_spec

HERE = pathlib.Path(__file__).resolve().parent
FIXTURES = HERE.parent.parent / "fixtures" / "raw"


def crops() -> dict[str, Frame]:
    """The two raw crops as frames (mosaic counts, layout, levels)."""
    out = {}
    for form, name, (y, x, n) in (("colour", "synthetic_bunny5.png", (88, 88, 64)),
                                  ("mono", "fruits_crop.png", (192, 256, 64))):
        frame = read_frame(FIXTURES / name)
        mosaic = np.ascontiguousarray(frame.mosaic[y:y + n, x:x + n])
        out[form] = Frame(mosaic=mosaic, layout=frame.layout, bit_depth=frame.bit_depth,
                          black_level=frame.black_level, white_level=frame.white_level)
    return out


def inputs(frames: dict[str, Frame]) -> dict[str, np.ndarray]:
    return {form: np.ascontiguousarray(pipeline.to_stack(f, demosaic="bilinear", resolution="cell"),
                                       dtype=np.float32)
            for form, f in frames.items()}


def compute() -> dict[str, np.ndarray]:
    frames = crops()
    stacks = inputs(frames)
    out: dict[str, np.ndarray] = {f"input/{k}": v for k, v in stacks.items()}
    for form, f in frames.items():
        for m in polcam.DEMOSAIC_METHODS:
            for res in ("full", "cell"):
                out[f"demosaic/{m}/{form}/{res}"] = np.asarray(
                    pipeline.to_stack(f, demosaic=m, resolution=res), dtype=np.float32)
        lm = pipeline.live_maps(f.mosaic, f.layout, black_level=f.black_level, white_level=f.white_level)
        for k in ("ic", "dolp", "aolp", "diffuse", "specular"):
            out[f"live/{k}/{form}"] = np.asarray(getattr(lm, k))
    for form, s in stacks.items():
        st = polcam.stokes(s)
        out[f"maps/s0/{form}"], out[f"maps/s1/{form}"], out[f"maps/s2/{form}"] = st
        for fn in ("dolp", "aolp", "imin", "imax"):
            out[f"maps/{fn}/{form}"] = getattr(polcam, fn)(s)
        for k, v in pipeline.products(s).items():
            out[f"products/{k}/{form}"] = np.asarray(v)
        for m in polcam.METHODS:
            spec = method_spec(m)
            if form == "mono" and not spec.mono:
                continue
            res = polcam.separate(s, method=m)
            out[f"sep/{m}/{form}/diffuse"] = res.diffuse
            out[f"sep/{m}/{form}/specular"] = res.specular
            print(m, form, f"{res.info.get('seconds', 0):.2f} s", file=sys.stderr)
    frame = read_frame(FIXTURES / "synthetic_bunny5.png")
    frame.mosaic = np.ascontiguousarray(frame.mosaic[48:208, 48:208])
    bunny = pipeline.to_stack(frame, demosaic="bilinear", resolution="cell")
    out["input/bunny"] = bunny = np.ascontiguousarray(bunny, dtype=np.float32)
    for m in ("wen21", "polarized-residual"):
        out[f"sep/{m}/bunny/diffuse"] = polcam.separate(bunny, method=m).diffuse
    return out


if __name__ == "__main__":
    np.savez_compressed(HERE / "outputs.npz", **compute())
