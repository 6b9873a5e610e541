"""``bilinear``: each (angle, colour) sample lattice interpolated on its own.

Normalised convolution of each lattice with its bilinear kernel: the separable
tent whose radius is the lattice period on the 2-periodic mono lattices and the
4-periodic R and B lattices of a colour sensor, and the tent product along both
diagonals on the G quincunx (which, unlike a square tent, vanishes at the other
G samples, so G samples are kept).  Mirrored borders (OpenCV BORDER_REFLECT).
At cell resolution the cell images of a colour sensor form one Bayer mosaic per
angle, interpolated with the same kernels at period 2.  The four angles run on
a thread pool (OpenCV releases the GIL).
"""

from __future__ import annotations

from functools import partial

import numpy as np

from polcam.demosaicing._lattice import bilinear_cells, bilinear_lattice, interleave_rgb, run_jobs, sublattices
from polcam.demosaicing._registry import register
from polcam.mosaic import Layout

__all__ = ["bilinear"]


@register("bilinear", cell=bilinear_cells,
          reference="Bilinear interpolation of each polarizer (and colour) sample lattice")
def bilinear(img: np.ndarray, lay: Layout) -> np.ndarray:
    """Bilinear demosaicing of a float32 (H, W) mosaic.

    Returns
    -------
    numpy.ndarray
        float32 (4, H, W) for a mono layout, (4, H, W, 3) for a colour one.
    """
    h, w = img.shape
    p = lay.period
    if not lay.is_color:
        out = np.empty((4, h, w), dtype=np.float32)

        def mono(k: int) -> None:
            bilinear_lattice(img, sublattices(lay, k, 0), p, out=out[k])

        run_jobs([partial(mono, k) for k in range(4)])
        return out
    out = np.empty((4, h, w, 3), dtype=np.float32)

    def colour(k: int) -> None:
        interleave_rgb([bilinear_lattice(img, sublattices(lay, k, c), p) for c in range(3)], out[k])

    run_jobs([partial(colour, k) for k in range(4)])
    return out
