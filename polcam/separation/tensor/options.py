"""Options of the tensor methods: defaults, checks, and the tile plan.

:func:`resolve` turns the keyword options of one call into a checked
:class:`Plan` (every refusal is a :class:`~polcam.errors.MethodError` naming
the option and what was expected), before any work is done.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional, Union

import numpy as np

from polcam.errors import MethodError
from polcam.parallel import MAX_AUTO_WORKERS, default_workers
from polcam.separation._option_types import describe, matches
from polcam.separation._tsvt import SOLVERS
from polcam.separation.tensor.torch_backend import check_device

__all__ = [
    "DEFAULTS",
    "OPTION_TYPES",
    "EXACT_TOL",
    "FAST_TOL",
    "AUTO_UNTILED_PIXELS",
    "AUTO_TILE",
    "DEVICE_BATCH",
    "MAX_AUTO_WORKERS",
    "INIT_PARALLEL_PIXELS",
    "VARIANTS",
    "Plan",
    "resolve",
    "tile_plan",
    "fit_side",
    "default_lam",
]

#: Defaults of the tensor methods, with where each comes from (docs/methods/tensor.md).
DEFAULTS: dict[str, Any] = {
    "n4": 4,            # representations per pixel (open in the paper; third-party 4)
    "block": 3,         # block side for candidate pixels (open; third-party 3x3)
    "threshold": 0.03,  # chromaticity similarity T (open; third-party 0.03)
    "alpha": 2.0,       # tau exponent scale (paper: alpha = 2)
    "beta": 0.25,       # tau gradient exponent (paper: beta = 0.25)
    "tau_floor": 1e-3,  # tau kept positive where 1 - I <= 0 (saturated); polcam's choice
    "gamma": 0.1,       # phase weight, gamma_t = gamma * mu_t (increasing with mu); polcam's choice
    "lam": None,        # None: 1 / sqrt(max(k, m) n4) (TRPCA's choice; the paper's formula is ambiguous)
    "rho": 1.5,         # mu growth (Lin, Chen & Ma's inexact ALM)
    "mu0": None,        # None: 1.25 / ||D||_2 (Lin, Chen & Ma)
    "mu_max": 1e7,      # mu cap relative to mu0
    "tol": None,        # stop at ||D - L - S||_F / ||D||_F < tol; None: EXACT_TOL (the paper's
                        # 1e-5) for the exact solver, FAST_TOL for the fast one (docs/benchmarks.md)
    "max_iter": 200,
    "init": "yang10",   # initial diffuse of every representation (paper: Yang'10)
    "illuminant": "polarization",  # "polarization", "white" or an RGB triple
    "solver": "fast",   # "fast" or "exact" (the reference; docs/methods/tensor.md, Fast solver)
    "tile": None,       # None: exact solver one tile; fast: one tile up to AUTO_UNTILED_PIXELS
                        # pixels, tiles of at most AUTO_TILE (height, width) above; an int
                        # (square) or a (height, width) pair asks for tiles of that size
    "overlap": 6,       # least overlap of neighbouring tiles (pixels), blended linearly; 2 left
                        # visible seams on real stacks (docs/methods/tensor.md, Tiling)
    "workers": None,    # threads for the initial diffuse, the tiles and the slices;
                        # None: polcam.parallel.default_workers() (the CPU count, at most 8)
    "device": None,     # None: numpy; "cpu", "cuda", ...: the PyTorch backend (torch extra)
    "precision": "float32",  # working precision of the fast solver: "float32" or "float64"
    "shared_init": None,  # True: Yang'10 on the 4 angle images, moved to the representations;
                          # False: on each of the 4 n4 representation images (the paper);
                          # None: True for the fast solver, False for the exact one
    "seed": 0,
    "imin_bound": False,  # True: clip the diffuse to [0, Imin] of the input (polcam's option, not the
                          # paper's; it costs dB where diffuse light is polarized: docs/benchmarks.md)
}

#: The type of each option (checked by ``polcam.separate`` before any work).
OPTION_TYPES: dict[str, Any] = {
    "n4": int, "block": int, "threshold": float, "alpha": float, "beta": float, "tau_floor": float,
    "gamma": float, "lam": Optional[float], "rho": float, "mu0": Optional[float], "mu_max": float,
    "tol": Optional[float], "max_iter": int, "init": str,
    "illuminant": Union[str, tuple[float, float, float]], "solver": str,
    "tile": Union[int, tuple[int, int], None], "overlap": int, "workers": Optional[int],
    "device": Optional[str], "precision": str, "shared_init": Optional[bool], "seed": int,
    "imin_bound": bool,
}

#: The paper's stopping tolerance, kept by the exact solver.
EXACT_TOL = 1e-5
#: Stopping tolerance of the fast solver: on the ten synthetic scenes at 256 x 256 it kept the
#: diffuse PSNR within 0.04 dB of the exact solver's (3e-4: 0.015 dB, 1e-3: 0.09 dB;
#: docs/decisions/tensor-fast-solver.md).
FAST_TOL = 5e-4
#: Images up to this many pixels are one tensor problem (the answer of the exact solver).
AUTO_UNTILED_PIXELS = 256 * 256
#: Largest tile (height, width) used above that size; each side is shrunk to the smallest that
#: needs no more tiles (:func:`fit_side`).  Narrow tiles make the Gram side of a slice small
#: (3 x 32 = 96 columns: eigenproblems of 96 instead of 192 for 64 x 64 tiles) at the same
#: quality (docs/decisions/tensor-fast-solver.md).
AUTO_TILE = (96, 32)
#: Tiles per IALM call of the PyTorch backend on a CPU (on a GPU: as many as fit in a third of
#: its free memory).
DEVICE_BATCH = 64
#: Largest image whose initial diffuse runs in parallel threads (the 1224 x 1024 cell-resolution
#: frame does; a 2448 x 2048 full-resolution one runs its Yang'10 runs one at a time to bound memory).
INIT_PARALLEL_PIXELS = 2_500_000
#: The registered variants: (tau weights used, phase term used).
VARIANTS: dict[str, tuple[bool, bool]] = {
    "tensor": (True, True),          # eq. 4
    "tensor-tau": (True, False),     # eq. 10
    "tensor-plain": (False, False),  # eq. 11
}


@dataclass(frozen=True)
class Plan:
    """The checked options of one call.

    Attributes
    ----------
    variant
        ``tensor``, ``tensor-tau`` or ``tensor-plain``.
    opt
        Every option (:data:`DEFAULTS` updated with the call's).
    tol
        Stopping tolerance in force.
    gamma
        Phase weight in force (0 without the phase term).
    use_tau
        Whether the sparse term is weighted by tau.
    shared
        Whether the initial diffuse is computed once on the angle images.
    workers
        Threads.
    tile
        (height, width) of the tiles; the image's shape for one tile.
    overlap
        Least overlap of neighbouring tiles (0 for one tile).
    shape
        (H, W) of the image.
    """

    variant: str
    opt: dict[str, Any]
    tol: float
    gamma: float
    use_tau: bool
    shared: bool
    workers: int
    tile: tuple[int, int]
    overlap: int
    shape: tuple[int, int]

    @property
    def one_tile(self) -> bool:
        """True when the image is one tensor problem."""
        return self.tile == self.shape


def resolve(shape: tuple[int, ...], variant: str, options: dict[str, Any]) -> Plan:
    """Check the options of one call on a (4, H, W, 3) stack and plan it.

    Raises
    ------
    MethodError
        An unknown option, or a value outside what the option takes.
    """
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise MethodError(
            f"unknown option(s) {', '.join(sorted(unknown))} for method {variant!r}; "
            f"expected: {', '.join(DEFAULTS)}"
        )
    for key, value in options.items():
        if key in OPTION_TYPES and not matches(value, OPTION_TYPES[key]):
            raise MethodError(f"option {key}={value!r} of method {variant!r}: "
                              f"expected {describe(OPTION_TYPES[key])}")
    opt = {**DEFAULTS, **options}
    if opt["solver"] not in SOLVERS:
        raise MethodError(f"solver {opt['solver']!r}: expected one of {', '.join(SOLVERS)}")
    if opt["device"] is not None:
        if not isinstance(opt["device"], str):
            raise MethodError(f"device {opt['device']!r}: expected None (numpy) or a torch device name")
        if opt["solver"] != "fast":
            raise MethodError(f"device {opt['device']!r} runs the fast solver; got solver={opt['solver']!r}")

        check_device(opt["device"])
    if not isinstance(opt["imin_bound"], (bool, np.bool_)):
        raise MethodError(f"imin_bound {opt['imin_bound']!r}: expected True or False")
    if opt["precision"] not in ("float32", "float64"):
        raise MethodError(f"precision {opt['precision']!r}: expected 'float32' or 'float64'")
    workers = opt["workers"]
    if workers is None:
        workers = default_workers()
    if not isinstance(workers, (int, np.integer)) or isinstance(workers, bool) or workers < 1:
        raise MethodError(f"workers = {workers!r}: expected None or a positive integer")
    tol = opt["tol"]
    if tol is None:
        tol = EXACT_TOL if opt["solver"] == "exact" else FAST_TOL
    h, w = int(shape[1]), int(shape[2])
    tile, overlap = tile_plan(h, w, opt["tile"], opt["overlap"], opt["solver"])
    use_tau, use_phase = VARIANTS[variant]
    shared = opt["shared_init"] if opt["shared_init"] is not None else opt["solver"] == "fast"
    return Plan(variant=variant, opt=opt, tol=float(tol),
                gamma=float(opt["gamma"]) if use_phase else 0.0, use_tau=use_tau, shared=bool(shared),
                workers=int(workers), tile=tile, overlap=overlap, shape=(h, w))


def fit_side(n: int, side: int, overlap: int) -> int:
    """The smallest tile side up to ``side`` that covers ``n`` pixels with as few tiles as ``side`` does.

    :func:`polcam.separation.tensor.tiling.tile_spans` spreads a fixed number of
    tiles evenly, so a side larger than needed only widens the overlaps (1024
    rows in tiles of 96 overlapping by at least 4 need 12 tiles; 89 rows each do
    it with overlaps of 4, 96 with overlaps of 12, work spent twice).
    """
    if n <= side:
        return n
    count = math.ceil((n - overlap) / (side - overlap))
    return min(side, math.ceil((n - overlap) / count) + overlap)


def tile_plan(h: int, w: int, tile: int | tuple[int, int] | None, overlap: int, solver: str
              ) -> tuple[tuple[int, int], int]:
    """Tile (height, width) and overlap for an (h, w) image; a tile covering the image means one tile.

    ``tile=None``: the exact solver always solves one problem; the fast one up to
    :data:`AUTO_UNTILED_PIXELS` pixels, tiles of :data:`AUTO_TILE` above.  An
    integer asks for square tiles, a pair for (height, width).  A side at least
    the image's is that whole side (one tile along it).
    """
    auto = tile is None
    if auto:
        if solver == "exact" or h * w <= AUTO_UNTILED_PIXELS:
            return (h, w), 0
        tile = AUTO_TILE
    pair = tuple(tile) if isinstance(tile, (tuple, list)) else (tile,) * 2
    if len(pair) != 2 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 8
                                 for v in pair):
        raise MethodError(f"tile = {tile!r}: expected None (automatic), a tile side of at least 8 pixels, "
                          "or a (height, width) pair of such sides")
    small = min(int(v) for v in pair)
    if (not isinstance(overlap, (int, np.integer)) or isinstance(overlap, bool) or overlap < 0
            or overlap >= small // 2):
        raise MethodError(f"overlap = {overlap!r}: expected an integer in 0 .. {small // 2 - 1} for tile {tile!r}")
    if auto:  # the smallest sides that need no more tiles than AUTO_TILE
        th, tw = fit_side(h, int(pair[0]), overlap), fit_side(w, int(pair[1]), overlap)
    else:
        th, tw = min(int(pair[0]), h), min(int(pair[1]), w)
    if th >= h and tw >= w:
        return (h, w), 0
    return (th, tw), int(overlap)


def default_lam(lam: float | None, k: int, m: int, n4: int) -> float:
    """``lam``, or TRPCA's ``1 / sqrt(max(k, m) n4)`` for a (k, m, n4) tensor when it is None."""
    return lam if lam is not None else 1.0 / math.sqrt(max(k, m) * n4)
