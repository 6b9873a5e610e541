"""Shakeri & Zhang's tensor low-rank + sparse separation guided by polarimetric cues.

M. Shakeri and H. Zhang, "Highlight specular reflection separation based on
tensor low-rank and sparse decomposition using polarimetric cues" (section 3).
Three registered variants:

``tensor``
    The full formulation (paper eq. 4)::

        min ||L||_* + lambda ||tau (.) S||_1 + gamma ||Phi^-1(Phi(L)) - L||_F^2   s.t. D = L + S

``tensor-tau``
    Without the phase term (eq. 10, gamma = 0).
``tensor-plain``
    Without the phase term and without tau (eq. 11, tau = 1).

The package, in data-flow order (docs/methods/tensor.md):

:mod:`.options`
    Defaults, option checks and the tile plan.
:mod:`.operators`
    The paper's operators: illuminant, polarization chromaticity,
    representations, tau, unfolding, phase projection.
:mod:`.tiling`
    Overlapping tiles and their blending.
:mod:`.ialm`
    The one IALM loop, for every backend and t-SVT.
:mod:`.numpy_backend`, :mod:`.torch_backend`
    What differs between backends: the t-SVT (exact: full SVD, the float64
    reference; fast: warm-started Gram eigenpairs; torch: batched Gram
    eigenpairs on a device), the spectral norm, the threads.
:mod:`.driver`
    :func:`separate_tensor`, the one pipeline.

Every step is written once over an array namespace (:mod:`polcam._xp`): numpy
arrays, or PyTorch tensors with ``device=`` (the ``torch`` extra).
"""

from __future__ import annotations

import functools
from typing import Any

from polcam.separation._registry import register
from polcam.separation.tensor.driver import initial_diffuse, separate_tensor, warm_up
from polcam.separation.tensor.ialm import ialm, solve_tiles
from polcam.separation.tensor.operators import (
    estimate_illuminant,
    fold,
    gather,
    illuminant,
    normalize_illuminant,
    phase_project,
    polarization_chromaticity,
    representations,
    tau_weights,
    unfold,
)
from polcam.separation.tensor.options import (
    AUTO_TILE,
    AUTO_UNTILED_PIXELS,
    DEFAULTS,
    DEVICE_BATCH,
    EXACT_TOL,
    FAST_TOL,
    INIT_PARALLEL_PIXELS,
    MAX_AUTO_WORKERS,
    OPTION_TYPES,
    VARIANTS,
)
from polcam.separation.tensor.tiling import blend, tile_spans, tile_windows, tiled

__all__ = [
    "DEFAULTS",
    "REFERENCE",
    "illuminant",
    "estimate_illuminant",
    "normalize_illuminant",
    "polarization_chromaticity",
    "representations",
    "gather",
    "initial_diffuse",
    "unfold",
    "fold",
    "tau_weights",
    "phase_project",
    "ialm",
    "solve_tiles",
    "tile_spans",
    "tile_windows",
    "blend",
    "tiled",
    "separate_tensor",
    "warm_up",
    "EXACT_TOL",
    "FAST_TOL",
    "AUTO_UNTILED_PIXELS",
    "AUTO_TILE",
    "DEVICE_BATCH",
    "MAX_AUTO_WORKERS",
    "INIT_PARALLEL_PIXELS",
]

REFERENCE = (
    "M. Shakeri and H. Zhang, Highlight specular reflection separation based on tensor "
    "low-rank and sparse decomposition using polarimetric cues"
)

for _variant in VARIANTS:
    register(_variant, kind="stack", reference=REFERENCE, options={k: OPTION_TYPES.get(k, Any) for k in DEFAULTS})(
        functools.partial(separate_tensor, variant=_variant)
    )
