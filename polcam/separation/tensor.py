"""Shakeri & Zhang's tensor low-rank + sparse separation guided by polarimetric cues.

M. Shakeri and H. Zhang, "Highlight specular reflection separation based on
tensor low-rank and sparse decomposition using polarimetric cues" (the paper in
``shared/seed``; section 3).  Three registered variants:

``tensor``
    The full formulation (paper eq. 4)::

        min ||L||_* + lambda ||tau (.) S||_1 + gamma ||Phi^-1(Phi(L)) - L||_F^2   s.t. D = L + S

``tensor-tau``
    Without the phase term (eq. 10, gamma = 0).
``tensor-plain``
    Without the phase term and without tau (eq. 11, tau = 1).

Steps, each a function of this module (docs/algorithm.md states the equations
as implemented and every departure from the paper):

1. :func:`estimate_illuminant` / :func:`normalize_illuminant`: the illuminant
   chromaticity Gamma and the normalisation ``I / (3 Gamma)`` to a white
   illuminant (the paper's pre-processing; its estimator is not specified:
   polcam estimates Gamma from the *polarized* light, which only specular
   reflection carries).
2. :func:`polcam.stokes.fit_sinusoid` per pixel and channel.
3. :func:`polarization_chromaticity` (eq. 3).
4. :func:`representations`: for every pixel, ``n4`` pixels of similar
   polarization chromaticity from the block around it (representation 1 is the
   pixel itself); :func:`gather` builds the representation images.
5. :func:`initial_diffuse`: Yang'10 (or another single-image method, ``init=``)
   on every representation and angle.
6. :func:`unfold` to D (4 n1, 3 n2, n4) and :func:`fold` back.
7. :func:`tau_weights`, :func:`phase_project` (Phi^-1 o Phi), and :func:`ialm`
   (eqs. 5-9 with the corrected L update, DESIGN.md section 4).
8. Diffuse = mean over the four angle blocks of representation 1 of L, clipped
   to [0, input mean]; specular = input mean - diffuse (the dispatcher).

Solvers: ``solver="exact"`` (:func:`ialm` with a full SVD of every Fourier
slice) is the reference; ``solver="fast"`` (the default: :func:`ialm_fast`,
float32, Gram eigenpairs on warm-started randomized subspaces, the shared
initial diffuse, and above :data:`AUTO_UNTILED_PIXELS` pixels overlapping
tiles in worker processes, :func:`blend`) gives the same diffuse layer within
0.04 dB of PSNR on the synthetic scenes at 256 x 256, 20 times faster
(docs/algorithm.md, section 4, "Fast solver"; docs/benchmarks.md); ``device=``
runs every step on PyTorch, for GPUs (:mod:`polcam.separation._torch`,
:mod:`polcam.separation._torch_prep`).
"""

from __future__ import annotations

import functools
import math
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from scipy.sparse.linalg import svds
from threadpoolctl import threadpool_limits

from polcam.errors import MethodError
from polcam.separation._registry import method_spec, register
from polcam.separation._tsvt import SOLVERS, FastTSVT, packed_dft, tsvt
from polcam.stokes import fit_sinusoid

__all__ = [
    "DEFAULTS",
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
    "unfold_slices",
    "fold_slices",
    "phase_project_slices",
    "ialm_fast",
    "tile_spans",
    "tile_windows",
    "start_workers",
    "blend",
    "tiled",
    "separate_tensor",
    "EXACT_TOL",
    "FAST_TOL",
    "AUTO_UNTILED_PIXELS",
    "AUTO_TILE",
    "DEVICE_BATCH",
    "MAX_AUTO_WORKERS",
    "INIT_PROCESS_PIXELS",
]

REFERENCE = (
    "M. Shakeri and H. Zhang, Highlight specular reflection separation based on tensor "
    "low-rank and sparse decomposition using polarimetric cues"
)

#: Defaults of the tensor methods, with where each comes from (docs/algorithm.md).
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
    "solver": "fast",   # "fast" or "exact" (the reference; docs/algorithm.md, Fast solver)
    "tile": None,       # None: exact solver one tile; fast: one tile up to AUTO_UNTILED_PIXELS
                        # pixels, tiles of at most AUTO_TILE (height, width) above; an int
                        # (square) or a (height, width) pair asks for tiles of that size
    "overlap": 2,       # least overlap of neighbouring tiles (pixels), blended linearly; 2 against
                        # 4: within 0.03 dB on the ten scenes at 512 x 512, 10-15 % fewer tiles
    "workers": None,    # processes/threads for the initial diffuse, the tiles and the slices;
                        # None: the CPU count, at most MAX_AUTO_WORKERS
    "device": None,     # None: numpy; "cpu", "cuda", ...: the PyTorch backend (torch extra)
    "precision": "float32",  # working precision of the fast solver: "float32" or "float64"
    "shared_init": None,  # True: Yang'10 on the 4 angle images, moved to the representations;
                          # False: on each of the 4 n4 representation images (the paper);
                          # None: True for the fast solver, False for the exact one
    "seed": 0,
}

#: The paper's stopping tolerance, kept by the exact solver.
EXACT_TOL = 1e-5
#: Stopping tolerance of the fast solver: on the ten synthetic scenes at 256 x 256 it kept the
#: diffuse PSNR within 0.04 dB of the exact solver's (3e-4: 0.015 dB, 1e-3: 0.09 dB; docs/benchmarks.md,
#: Tensor solver speed).
FAST_TOL = 5e-4
#: Images up to this many pixels are one tensor problem (the answer of the exact solver).
AUTO_UNTILED_PIXELS = 256 * 256
#: Largest tile (height, width) used above that size; each side is shrunk to the smallest that
#: needs no more tiles (:func:`_fit_side`).  Narrow tiles make the Gram side of a slice small
#: (3 x 32 = 96 columns: eigenproblems of 96 instead of 192 for 64 x 64 tiles) at the same
#: quality (docs/benchmarks.md, Tensor solver speed).
AUTO_TILE = (96, 32)
#: Tiles per IALM call of the PyTorch backend on a CPU (on a GPU: as many as fit in a third of
#: its free memory, :func:`_device_batch`).
DEVICE_BATCH = 64
#: Most worker processes chosen by ``workers=None`` (each holds a few hundred MB at most).
MAX_AUTO_WORKERS = 8
#: Largest image whose initial diffuse runs in worker processes (the 1224 x 1024 cell-resolution
#: frame does; a 2448 x 2048 full-resolution one runs in this process to bound memory).
INIT_PROCESS_PIXELS = 2_500_000


# ---------------------------------------------------------------------------
# 1. illuminant
# ---------------------------------------------------------------------------

def estimate_illuminant(stack: np.ndarray, *, significance: float = 5.0) -> np.ndarray:
    """Illuminant chromaticity from the polarized light.

    Diffuse reflection is (close to) unpolarized, so the linear polarization
    ``v_c = (S1_c, S2_c)`` of every channel comes from specular reflection,
    whose colour is the illuminant's (dichromatic model): at a pixel,
    ``v_c = rho S Gamma_c (cos 2 phi, sin 2 phi)``, one direction for R, G and B
    with lengths in the ratio of Gamma.  The estimate projects each channel's
    ``v_c`` onto the polarization direction of the pixel's neighbourhood
    (the channel-summed ``v`` of its 8 neighbours), so that zero-mean noise,
    independent between pixels, averages out instead of adding a positive bias
    in the colour of the brightest channel (as a sum of amplitudes ``Isv``
    would):

        Gamma_c  proportional to  sum_p  v_c(p) . n(p),   n(p) = sum_{q in N8(p)} sum_c v_c(q)

    over unsaturated pixels.  When the total is not ``significance`` times its
    own noise (estimated from the spread of the per-pixel terms), or a channel
    comes out non-positive, the estimate is white.

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1].
    significance
        How many standard deviations of the noise the signal must exceed.

    Returns
    -------
    numpy.ndarray
        (3,) chromaticity summing to 1 (white = 1/3 each).
    """
    import cv2

    x = np.asarray(stack, dtype=np.float64)
    v = np.stack([x[0] - x[2], x[1] - x[3]], axis=-1)          # (H, W, 3, 2)
    vs = v.sum(axis=2)                                          # (H, W, 2)
    nb = np.stack([cv2.boxFilter(vs[..., i], -1, (3, 3), normalize=False,
                                 borderType=cv2.BORDER_CONSTANT) for i in range(2)], axis=-1) - vs
    terms = np.einsum("hwcj,hwj->hwc", v, nb)                   # (H, W, 3)
    ok = x.max(axis=(0, 3)) < 0.98
    t = terms[ok]
    if t.size == 0:
        return np.full(3, 1 / 3)
    total = t.sum(axis=0)
    noise = np.sqrt(np.sum(t.sum(axis=1) ** 2))
    if total.sum() <= significance * noise or np.any(total <= 0):
        return np.full(3, 1 / 3)
    return total / total.sum()


def normalize_illuminant(stack: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """``I / (3 Gamma)`` per channel: the image under a white illuminant."""
    return stack / _white_divisor(gamma)


def _white_divisor(gamma: Any) -> np.ndarray:
    """``3 Gamma`` (Gamma normalised to sum 1), checked: what :func:`normalize_illuminant` divides by."""
    g = np.asarray(gamma, dtype=np.float64).reshape(3)
    if np.any(g <= 0):
        raise MethodError(f"illuminant chromaticity {g.tolist()}: expected three positive values")
    return 3.0 * (g / g.sum())


def _choose_illuminant(ill: Any, estimate: Callable[[], np.ndarray]) -> np.ndarray:
    """The ``illuminant`` option as a chromaticity: ``estimate()``, white, or the given RGB triple."""
    if isinstance(ill, str):
        if ill == "polarization":
            return estimate()
        if ill == "white":
            return np.full(3, 1 / 3)
        raise MethodError(f"illuminant {ill!r}: expected 'polarization', 'white' or an RGB triple")
    gam = np.asarray(ill, dtype=np.float64)
    return gam / gam.sum()


# ---------------------------------------------------------------------------
# 3-4. chromaticity and representations
# ---------------------------------------------------------------------------

def polarization_chromaticity(stack: np.ndarray) -> np.ndarray:
    """Polarization-based chromaticity image (paper eq. 3).

    ``I_rawS = 2 Isv``, ``I_rawD = max(Ic - I_rawS, 0)`` and
    ``I_chro = I_rawD / (sum_RGB I_rawD + mean_p min_RGB Ic)``.

    Parameters
    ----------
    stack
        (4, H, W, 3) float.

    Returns
    -------
    numpy.ndarray
        (H, W, 3), each channel in [0, 1).
    """
    fit = fit_sinusoid(stack)
    raw_d = np.maximum(fit.ic - 2.0 * fit.isv, 0.0)
    i_min_bar = float(np.mean(fit.ic.min(axis=-1)))
    denom = raw_d.sum(axis=-1, keepdims=True) + i_min_bar
    with np.errstate(divide="ignore", invalid="ignore"):
        chro = np.where(denom > 0, raw_d / np.where(denom > 0, denom, 1.0), 0.0)
    return chro


def representations(chro: np.ndarray, *, n4: int, block: int, threshold: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Offsets of ``n4`` similar pixels drawn from the block around every pixel.

    Representation 0 is the pixel itself.  Representations 1 .. n4-1 are drawn
    without replacement among the block's pixels q (q != p, inside the image)
    with ``||chro(p) - chro(q)|| < threshold``; where fewer pass, the missing
    ones are p itself.

    Parameters
    ----------
    chro
        (H, W, 3) chromaticity image.
    n4, block, threshold
        Representations, block side (odd), similarity threshold T.
    rng
        Seeded generator.

    Returns
    -------
    offsets : numpy.ndarray
        (n4, H, W, 2) int (dy, dx); ``offsets[0] == 0``.
    filled : float
        Share of representation slots filled by a similar neighbour (not p).
    """
    cand = _candidates(n4, block)
    h, w, _ = chro.shape
    r = block // 2
    offsets = np.zeros((n4, h, w, 2), dtype=np.intp)
    if n4 == 1 or not cand:
        return offsets, 0.0
    pad = np.pad(chro, ((r, r), (r, r), (0, 0)), mode="constant", constant_values=np.inf)
    keys = rng.random((len(cand), h, w))
    for j, (dy, dx) in enumerate(cand):
        q = pad[r + dy:r + dy + h, r + dx:r + dx + w]
        with np.errstate(invalid="ignore"):
            dist = np.sqrt(np.sum((q - chro) ** 2, axis=-1))
        keys[j][~(dist < threshold)] = np.inf
    take = min(n4 - 1, len(cand))
    order = np.argsort(keys, axis=0)[:take]
    picked = np.take_along_axis(keys, order, axis=0)
    cand_arr = np.array(cand, dtype=np.intp)
    for i in range(take):
        valid = np.isfinite(picked[i])
        offsets[i + 1][valid] = cand_arr[order[i][valid]]
    filled = float(np.isfinite(picked).mean()) * take / (n4 - 1)
    return offsets, filled


def _candidates(n4: int, block: int) -> list[tuple[int, int]]:
    """The (dy, dx) offsets of a block's pixels other than its centre, after checking n4 and block."""
    if n4 < 1:
        raise MethodError(f"n4 = {n4}: expected at least 1 representation")
    if block < 1 or block % 2 == 0:
        raise MethodError(f"block = {block}: expected an odd block side >= 1")
    r = block // 2
    return [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dy, dx) != (0, 0)]


def _default_lam(lam: float | None, k: int, m: int, n4: int) -> float:
    """``lam``, or TRPCA's ``1 / sqrt(max(k, m) n4)`` for a (k, m, n4) tensor when it is None."""
    return lam if lam is not None else 1.0 / np.sqrt(max(k, m) * n4)


def gather(images: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Representation images: ``out[i, ..., y, x, :] = images[..., y + dy_i, x + dx_i, :]``.

    Parameters
    ----------
    images
        (..., H, W, C).
    offsets
        (n4, H, W, 2).

    Returns
    -------
    numpy.ndarray
        (n4, ..., H, W, C).
    """
    h, w = offsets.shape[1:3]
    lead = images.shape[:-3]
    c = images.shape[-1]
    flat = images.reshape(*lead, h * w, c)
    base = np.arange(h * w, dtype=np.intp).reshape(h, w)
    out = np.empty((offsets.shape[0], *lead, h, w, c), dtype=images.dtype)
    for i, off in enumerate(offsets):
        idx = (base + off[..., 0] * w + off[..., 1]).ravel()   # flat index of (y + dy, x + dx)
        out[i] = np.take(flat, idx, axis=-2).reshape(*lead, h, w, c)
    return out


def initial_diffuse(reps: np.ndarray, *, init: str = "yang10", workers: int = 1,
                    **options: Any) -> np.ndarray:
    """Diffuse estimate of every representation and angle by a single-image method.

    Parameters
    ----------
    reps
        (n4, 4, H, W, 3) representation images of the four angles.
    init
        A registered single-image method (the paper: Yang'10).
    workers
        Worker processes running the ``4 n4`` independent single-image runs (the
        result does not depend on it).

    Returns
    -------
    numpy.ndarray
        (n4, 4, H, W, 3), each in [0, its input].
    """
    spec = method_spec(init)
    if spec.kind != "single":
        raise MethodError(f"init method {init!r} is not a single-image method")
    out = np.empty_like(reps)
    jobs = [(i, a) for i in range(reps.shape[0]) for a in range(reps.shape[1])]
    args = ((init, reps[i, a], options) for i, a in jobs)
    if workers > 1 and len(jobs) > 1:
        # processes: the single-image methods are numpy/OpenCV code that holds the GIL
        # often enough that threads did not run faster than one
        res = _map_processes(_init_job, args, workers)
    else:
        res = map(_init_job, args)
    for (i, a), d in zip(jobs, res):
        out[i, a] = d
    return out


def _init_job(args: tuple[str, np.ndarray, dict[str, Any]]) -> np.ndarray:
    """One single-image run of :func:`initial_diffuse` (here or in a worker process)."""
    init, rep, options = args
    img = np.clip(rep, 0.0, 1.0)
    res = method_spec(init).fn(img, **options)
    d = res[0] if isinstance(res, tuple) else res
    return np.clip(np.nan_to_num(np.asarray(d, dtype=np.float64)), 0.0, img)


# ---------------------------------------------------------------------------
# 6. unfolding
# ---------------------------------------------------------------------------

def unfold(d: np.ndarray) -> np.ndarray:
    """(n4, 4, n1, n2, 3) -> D of shape (4 n1, 3 n2, n4).

    Each angle's (n1, n2, 3) image becomes the (n1, 3 n2) matrix of column
    blocks [R | G | B]; the four angles are stacked as row blocks; the
    representations are the third mode.
    """
    n4, na, n1, n2, c = d.shape
    return np.ascontiguousarray(d.transpose(1, 2, 4, 3, 0).reshape(na * n1, c * n2, n4))


def fold(D: np.ndarray, n1: int, n2: int) -> np.ndarray:
    """Inverse of :func:`unfold`: (4 n1, 3 n2, n4) -> (n4, 4, n1, n2, 3)."""
    k, m, n4 = D.shape
    na, c = k // n1, m // n2
    return np.ascontiguousarray(D.reshape(na, n1, c, n2, n4).transpose(4, 0, 1, 3, 2))


# ---------------------------------------------------------------------------
# 7. tau, phase operator, IALM
# ---------------------------------------------------------------------------

def tau_weights(first: np.ndarray, *, alpha: float, beta: float, floor: float) -> np.ndarray:
    """Spatially variant weight ``tau = (1 - I) / exp(-alpha ||grad I||^beta)``.

    Parameters
    ----------
    first
        (4, n1, n2, 3) the first representation (I = D(:, :, 1) before unfolding).
    alpha, beta
        The paper's 2 and 0.25.
    floor
        Lower bound of ``1 - I`` so tau stays positive where I >= 1 (saturated).

    Returns
    -------
    numpy.ndarray
        (4, n1, n2, 3) tau > 0; the gradient is taken within each angle and
        channel image (central differences), never across block boundaries.
    """
    gy, gx = np.gradient(first, axis=(1, 2))
    grad = np.sqrt(gx**2 + gy**2)
    return np.maximum(1.0 - first, floor) * np.exp(alpha * grad**beta)


_ANG = np.deg2rad(np.array([0.0, 45.0, 90.0, 135.0]))


def phase_project(x: np.ndarray) -> np.ndarray:
    """``Phi^-1(Phi(x))``: one phase per pixel shared by R, G and B.

    Per pixel, channel and representation, the sinusoid
    ``Ic + Isv cos(2t - 2 phi_c)`` is fitted to the four angle images; the common
    phase is the mean of the three phases taken on doubled angles
    (``phi = arg(sum_c exp(2 i phi_c)) / 2``, so the mean respects the period pi);
    each channel is resynthesised with its own Ic and Isv and the common phase.

    Parameters
    ----------
    x
        (n4, 4, n1, n2, 3) folded tensor, angles 0, 45, 90, 135 on axis 1.

    Returns
    -------
    numpy.ndarray
        Same shape.
    """
    s0h = 0.25 * x.sum(axis=1)                       # Ic
    s1 = x[:, 0] - x[:, 2]
    s2 = x[:, 1] - x[:, 3]
    isv = 0.5 * np.hypot(s1, s2)
    # unit phasors of each channel's doubled phase; channels with no amplitude carry no phase
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(isv > 0, (s1 + 1j * s2) / np.where(isv > 0, 2 * isv, 1.0), 0.0)
    zc = z.sum(axis=-1, keepdims=True)
    two_phi = np.angle(zc)
    cos_t = np.cos(2 * _ANG)[None, :, None, None, None]
    sin_t = np.sin(2 * _ANG)[None, :, None, None, None]
    c, s = np.cos(two_phi)[:, None], np.sin(two_phi)[:, None]
    # cos(2t - 2phi) = cos 2t cos 2phi + sin 2t sin 2phi
    return s0h[:, None] + isv[:, None] * (cos_t * c + sin_t * s)


def _spectral_norm(D: np.ndarray) -> float:
    """||bcirc(D)||_2 = max over Fourier slices of the slice's spectral norm."""
    df = np.fft.rfft(D, axis=2)
    best = 0.0
    for i in range(df.shape[2]):
        a = df[:, :, i]
        if min(a.shape) <= 2:
            v = float(np.linalg.norm(a, 2))
        else:
            v = float(svds(a, k=1, return_singular_vectors=False, random_state=0)[0])
        best = max(best, v)
    return best


def ialm(D: np.ndarray, *, tau: np.ndarray | None, lam: float, gamma: float,
         project: Any = None, rho: float = 1.5, mu0: float | None = None,
         mu_max: float = 1e7, tol: float = 1e-5, max_iter: int = 200,
         solver: str = "exact") -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Inexact ALM for ``min ||L||_* + lam ||tau (.) S||_1 + gamma ||Q(L) - L||^2, D = L + S``.

    Updates per iteration t (mu_t grows by ``rho`` up to ``mu_max * mu0``,
    gamma_t = gamma * mu_t):

    * ``L = tsvt((2 gamma_t Q + mu_t (D - S) + Y) / (2 gamma_t + mu_t), 1 / (2 gamma_t + mu_t))``
      (the minimiser of the L-terms; the paper's eq. 6 swaps the weights of Q
      and D - S);
    * ``S = soft(D - L + Y / mu_t, lam tau / mu_t)``;
    * ``Q = project(L)`` (skipped when ``gamma == 0``);
    * ``Y = Y + mu_t (D - L - S)``.

    Parameters
    ----------
    D
        (k, m, n4) data tensor.
    tau
        (k, m, n4) positive weights, or None for 1.
    lam, gamma
        Weights of the sparse and phase terms.
    project
        Callable mapping a (k, m, n4) tensor to Phi^-1(Phi(.)); required if gamma > 0.
    rho, mu0, mu_max, tol, max_iter, solver
        Schedule, stopping rule and t-SVT solver: ``"exact"``, or ``"fast"``
        (:func:`ialm_fast` in float32 with :class:`~polcam.separation._tsvt.FastTSVT`;
        L and S come back as float64).

    Returns
    -------
    L, S : numpy.ndarray
        (k, m, n4).
    info : dict
        iterations, converged, residual (final), residuals (per iteration),
        ranks (per iteration, kept rank of each Fourier slice), mu0.
    """
    if gamma > 0 and project is None:
        raise ValueError("gamma > 0 needs a phase projection")
    if solver == "fast":
        return _ialm_fast_unfolded(D, tau=tau, lam=lam, gamma=gamma, project=project, rho=rho,
                                   mu0=mu0, mu_max=mu_max, tol=tol, max_iter=max_iter)
    norm_d = float(np.linalg.norm(D))
    if norm_d == 0:
        z = np.zeros_like(D)
        return z, z.copy(), {"iterations": 0, "converged": True, "residual": 0.0,
                             "residuals": [], "ranks": [], "mu0": 0.0}
    spec = _spectral_norm(D)
    mu = 1.25 / spec if mu0 is None else float(mu0)
    mu_cap = mu * mu_max
    mu_start = mu
    L = np.zeros_like(D)
    S = np.zeros_like(D)
    Y = np.zeros_like(D)
    Q = project(D) if gamma > 0 else None
    w = lam if tau is None else lam * tau
    residuals: list[float] = []
    ranks: list[list[int]] = []
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        g = gamma * mu
        if g > 0:
            target = (2 * g * Q + mu * (D - S) + Y) / (2 * g + mu)
        else:
            target = D - S + Y / mu
        L, r = tsvt(target, 1.0 / (2 * g + mu), solver=solver)
        ranks.append(r)
        v = D - L + Y / mu
        S = np.sign(v) * np.maximum(np.abs(v) - w / mu, 0.0)
        if g > 0:
            Q = project(L)
        resid_t = D - L - S
        Y += mu * resid_t
        res = float(np.linalg.norm(resid_t)) / norm_d
        residuals.append(res)
        if res < tol:
            converged = True
            break
        mu = min(rho * mu, mu_cap)
    return L, S, {"iterations": it, "converged": converged, "residual": residuals[-1],
                  "residuals": residuals, "ranks": ranks, "mu0": mu_start}


# ---------------------------------------------------------------------------
# 6-7 again, slice-first: the layout of the fast solver
# ---------------------------------------------------------------------------

def unfold_slices(d: np.ndarray) -> np.ndarray:
    """(n4, 4, n1, n2, 3) -> (n4, 4 n1, 3 n2): :func:`unfold` with the third mode first.

    ``unfold_slices(d)[i] == unfold(d)[:, :, i]``: each frontal slice is a
    contiguous matrix, which the fast solver's matrix products and its packed
    DFT along the first axis need.
    """
    n4, na, n1, n2, c = d.shape
    return np.ascontiguousarray(d.transpose(0, 1, 2, 4, 3).reshape(n4, na * n1, c * n2))


def fold_slices(z: np.ndarray, n1: int, n2: int) -> np.ndarray:
    """Inverse of :func:`unfold_slices`: (n4, 4 n1, 3 n2) -> (n4, 4, n1, n2, 3)."""
    n4, k, m = z.shape
    return np.ascontiguousarray(z.reshape(n4, k // n1, n1, m // n2, n2).transpose(0, 1, 2, 4, 3))


def phase_project_slices(z: np.ndarray, n1: int, n2: int, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`phase_project` on a slice-first unfolded tensor (n4, 4 n1, 3 n2).

    The same operator in real arithmetic: with ``s1 = I0 - I90``,
    ``s2 = I45 - I135`` per channel, the common doubled phase is the direction
    of ``sum_c (s1_c, s2_c) / |(s1_c, s2_c)|`` (the sum of unit phasors;
    direction (1, 0) where that sum is zero, as ``angle(0) = 0``), and with
    ``(c, s)`` its cosine and sine the four angle images are
    ``Ic + Isv c``, ``Ic + Isv s``, ``Ic - Isv c``, ``Ic - Isv s``
    (``cos 2t`` and ``sin 2t`` at t = 0, 45, 90, 135 degrees).

    Parameters
    ----------
    z
        (n4, 4 n1, 3 n2) real, angle row blocks 0, 45, 90, 135 and channel
        column blocks R, G, B.
    n1, n2
        Image height and width.
    out
        Optional array of z's shape and dtype to write into.

    Returns
    -------
    numpy.ndarray
        (n4, 4 n1, 3 n2), in ``out`` when given.
    """
    n4 = z.shape[0]
    v = z.reshape(n4, 4, n1, 3, n2)
    s1 = np.subtract(v[:, 0], v[:, 2])
    s2 = np.subtract(v[:, 1], v[:, 3])
    amp = np.multiply(s1, s1)
    amp += s2 * s2
    np.sqrt(amp, out=amp)                                # 2 Isv
    tiny = np.finfo(amp.dtype).tiny
    inv = np.maximum(amp, tiny)
    np.divide(1.0, inv, out=inv)                         # where amp = 0, s1 = s2 = 0: no phasor
    s1 *= inv
    s2 *= inv
    c = s1[:, :, 0] + s1[:, :, 1]                        # sum of unit phasors over RGB
    c += s1[:, :, 2]
    s = s2[:, :, 0] + s2[:, :, 1]
    s += s2[:, :, 2]
    nz = np.hypot(c, s)
    zero = nz == 0
    np.maximum(nz, tiny, out=nz)
    np.divide(0.5, nz, out=nz)                           # the 1/2 turns 2 Isv into Isv
    c *= nz
    s *= nz
    c[zero] = 0.5                                        # direction (1, 0) where the sum is zero
    amp_c = amp * c[:, :, None]                          # Isv cos 2phi
    amp_s = amp * s[:, :, None]                          # Isv sin 2phi
    s0h = np.add(v[:, 0], v[:, 1])
    s0h += v[:, 2]
    s0h += v[:, 3]
    s0h *= 0.25                                          # Ic
    res = np.empty_like(z) if out is None else out
    r = res.reshape(n4, 4, n1, 3, n2)
    np.add(s0h, amp_c, out=r[:, 0])
    np.add(s0h, amp_s, out=r[:, 1])
    np.subtract(s0h, amp_c, out=r[:, 2])
    np.subtract(s0h, amp_s, out=r[:, 3])
    return res


def _top_singular_value(a: np.ndarray, *, block: int = 4, rtol: float = 1e-13,
                        max_iter: int = 500) -> float:
    """Largest singular value of a matrix by block subspace iteration on its Gram matrix.

    ``block`` vectors (seeded), multiplied by ``A^H A`` and re-orthonormalised
    until the largest Rayleigh-Ritz value changes by less than ``rtol``
    relatively; its error then falls as ``(s_{block+1} / s_1)^(4 i)``, which for
    image data (a dominant first singular value) takes a few steps, each two
    thin products.
    """
    b = a if a.shape[0] >= a.shape[1] else a.conj().T
    n = b.shape[1]
    rng = np.random.default_rng(0)
    z = np.linalg.qr(rng.standard_normal((n, min(block, n))).astype(b.dtype))[0]
    prev = -1.0
    lam = 0.0
    for _ in range(max_iter):
        y = b @ z
        c = y.conj().T @ y
        lam = float(np.linalg.eigvalsh(0.5 * (c + c.conj().T))[-1])
        if lam <= 0 or abs(lam - prev) <= rtol * lam:
            break
        prev = lam
        z = np.linalg.qr(b.conj().T @ y)[0]
    return math.sqrt(max(lam, 0.0))


def _spectral_norm_slices(z: np.ndarray) -> float:
    """``||bcirc||_2`` of a slice-first tensor (n4, k, m), in float64.

    The largest singular value over the independent Fourier slices, each by
    :func:`_top_singular_value` (agrees with :func:`_spectral_norm`'s ARPACK to
    about 1e-13), visiting the slices by decreasing Frobenius norm and stopping
    when that bound falls below the best so far: for image data only the DC
    slice is decomposed (ARPACK over all slices took 0.5-1 s for a 256 x 256
    image).
    """
    z64 = np.asarray(z, dtype=np.float64)
    n4, k, m = z64.shape
    f, _, slices = packed_dft(n4)
    zf = (f @ z64.reshape(n4, -1)).reshape(n4, k, m)
    mats = [zf[rows[0]] if len(rows) == 1 else zf[rows[0]] + 1j * zf[rows[1]] for rows in slices]
    fro = [float(np.linalg.norm(a)) for a in mats]
    best = 0.0
    for i in np.argsort(fro)[::-1]:
        if fro[i] <= best:            # s_1 <= ||A||_F: this slice cannot hold the maximum
            break
        best = max(best, _top_singular_value(mats[i]))
    return best


def ialm_fast(D: np.ndarray, *, tau: np.ndarray | None, lam: float, gamma: float,
              project: Callable[[np.ndarray], np.ndarray] | None = None, rho: float = 1.5,
              mu0: float | None = None, mu_max: float = 1e7, tol: float = 1e-5,
              max_iter: int = 200, dtype: type = np.float32, svt_options: dict[str, Any] | None = None,
              chunks: int = 1, chunked_project: bool = False
              ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """:func:`ialm` on a slice-first tensor with the fast t-SVT.

    The same iteration as :func:`ialm` (same mu0, rho, gamma_t, updates and
    stopping rule), with the tensor laid out (n4, k, m), arithmetic in
    ``dtype`` (float32 by default), in-place updates, and the t-SVT of
    :class:`~polcam.separation._tsvt.FastTSVT`, whose per-slice subspaces and
    predicted ranks carry over from one iteration to the next (warm start).

    Parameters
    ----------
    D
        (n4, k, m) data tensor.
    tau
        Positive weights broadcastable to (n4, k, m) (e.g. (1, k, m) when they
        do not depend on the representation), or None for 1.
    lam, gamma, rho, mu0, mu_max, tol, max_iter
        As :func:`ialm`.
    project
        Callable mapping a slice-first tensor (n4, k, m) to Phi^-1(Phi(.)); required
        if gamma > 0.
    dtype
        Working precision: float32 or float64.
    svt_options
        Options of :class:`~polcam.separation._tsvt.FastTSVT` (``workers``) and
        :class:`~polcam.separation._tsvt.SliceSVT`.
    chunks
        Run the element-wise updates on this many groups of frontal slices in
        as many threads (numpy releases the GIL on large arrays).
    chunked_project
        ``project`` acts on each frontal slice alone and takes ``out=``: it then
        runs inside the chunks (as :func:`phase_project_slices` can).

    Returns
    -------
    L, S : numpy.ndarray
        (n4, k, m) in ``dtype``.
    info : dict
        As :func:`ialm`, plus ``svt_counts`` (how often each t-SVT path ran).
    """
    if gamma > 0 and project is None:
        raise ValueError("gamma > 0 needs a phase projection")
    dt = np.dtype(dtype)
    D = np.ascontiguousarray(D, dtype=dt)
    n4 = D.shape[0]
    flat = D.reshape(-1)
    norm_d = math.sqrt(float(np.dot(flat, flat)))
    if norm_d == 0:
        z = np.zeros_like(D)
        return z, z.copy(), {"iterations": 0, "converged": True, "residual": 0.0, "residuals": [],
                             "ranks": [], "mu0": 0.0, "svt_counts": {}}
    mu = 1.25 / _spectral_norm_slices(D) if mu0 is None else float(mu0)
    mu_cap = mu * mu_max
    mu_start = mu
    w = dt.type(lam) * (np.ones((1,) + D.shape[1:], dt) if tau is None else np.asarray(tau, dt))
    wb = np.broadcast_to(w, D.shape)
    wn = np.broadcast_to(np.negative(w), D.shape)
    # scaled form (Boyd et al. 2011, section 3.1.1): P = Y / mu.  With gamma_t = gamma mu_t the
    # target (2 g Q + mu (D - S) + Y) / (2 g + mu) is c1 E + c2 Q with E = D - S + P and constant
    # c1, c2; S = V - C and Y_new / mu_new = C mu / mu_new with V = D - L + P, C = clip(V, +-w / mu);
    # the residual D - L - S = C - P; and the next E = L + (C - P) + P_new (docs/algorithm.md)
    c1, c2 = dt.type(1.0 / (1.0 + 2.0 * gamma)), dt.type(2.0 * gamma / (1.0 + 2.0 * gamma))
    L = np.zeros_like(D)
    S = np.zeros_like(D)
    P = np.zeros_like(D)
    E = D.copy()
    T = np.empty_like(D)
    V = np.empty_like(D)
    R = np.empty_like(D)
    Q = project(D) if gamma > 0 else None
    svt = FastTSVT(n4, dtype=dt, **(svt_options or {}))
    # the element-wise updates, on chunks of the slices (threads when chunks > 1)
    nch = max(1, min(int(chunks), n4))
    bounds = np.linspace(0, n4, nch + 1).astype(int)
    parts = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
    pool = ThreadPoolExecutor(max_workers=nch) if nch > 1 else None

    def each(fn: Callable[[slice], Any]) -> list[Any]:
        if pool is None:
            return [fn(c) for c in parts]
        return list(pool.map(fn, parts))

    residuals: list[float] = []
    ranks: list[list[int]] = []
    converged = False
    it = 0
    try:
        for it in range(1, max_iter + 1):
            if gamma > 0:
                def target(c: slice) -> None:
                    np.multiply(E[c], c1, out=T[c])
                    np.multiply(Q[c], c2, out=V[c])
                    T[c] += V[c]

                each(target)
                Z = svt.forward(T)
            else:
                Z = svt.forward(E)
            ranks.append(svt.threshold_packed(Z, 1.0 / (mu * (1.0 + 2.0 * gamma))))
            L = svt.inverse(Z)
            mu_t, inv_mu = dt.type(mu), dt.type(1.0 / mu)

            def update(c: slice) -> float:
                v_, t_, r_ = V[c], T[c], R[c]
                np.subtract(D[c], L[c], out=v_)       # V = D - L + P
                v_ += P[c]
                np.multiply(v_, mu_t, out=t_)         # mu C = clip(mu V, -w, w)
                np.clip(t_, wn[c], wb[c], out=t_)
                np.multiply(t_, inv_mu, out=r_)       # R = C - P = D - L - S
                r_ -= P[c]
                rf = r_.reshape(-1)
                return float(np.dot(rf, rf))

            res = math.sqrt(sum(each(update))) / norm_d
            residuals.append(res)
            if res < tol or it == max_iter:
                converged = res < tol
                each(lambda c: (np.subtract(V[c], R[c], out=S[c]), np.subtract(S[c], P[c], out=S[c])))
                break
            mu_next = min(rho * mu, mu_cap)
            scale = dt.type(1.0 / mu_next)

            def advance(c: slice) -> None:
                np.add(L[c], R[c], out=E[c])         # E = L + (C - P) + P_new
                np.multiply(T[c], scale, out=P[c])   # P_new = Y_new / mu_next = mu C / mu_next
                E[c] += P[c]
                if gamma > 0 and chunked_project:
                    project(L[c], out=Q[c])

            each(advance)
            if gamma > 0 and not chunked_project:
                Q = project(L)
            mu = mu_next
    finally:
        if pool is not None:
            pool.shutdown()
    return L, S, {"iterations": it, "converged": converged, "residual": residuals[-1],
                  "residuals": residuals, "ranks": ranks, "mu0": mu_start, "svt_counts": svt.counts}


def _ialm_fast_unfolded(D: np.ndarray, *, tau: np.ndarray | None, project: Any, **kw: Any
                        ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """:func:`ialm_fast` for a tensor in :func:`unfold`'s layout (k, m, n4)."""
    z = np.moveaxis(D, 2, 0)
    tz = None if tau is None else np.moveaxis(np.broadcast_to(tau, D.shape), 2, 0)
    proj = None
    if project is not None:
        def proj(x: np.ndarray) -> np.ndarray:
            return np.moveaxis(np.asarray(project(np.moveaxis(x, 0, 2)), dtype=x.dtype), 2, 0)
    L, S, info = ialm_fast(z, tau=tz, project=proj, dtype=np.float64, **kw)
    return (np.ascontiguousarray(np.moveaxis(L, 0, 2)), np.ascontiguousarray(np.moveaxis(S, 0, 2)), info)


# ---------------------------------------------------------------------------
# tiling
# ---------------------------------------------------------------------------

def tile_spans(n: int, tile: int, overlap: int) -> list[tuple[int, int]]:
    """Start/stop of tiles of side ``tile`` covering ``0 .. n`` with at least ``overlap`` shared.

    One span ``(0, n)`` when ``n <= tile``; otherwise tiles of exactly ``tile``
    pixels, evenly spread so the first starts at 0 and the last stops at n.
    """
    if n <= tile:
        return [(0, n)]
    count = math.ceil((n - overlap) / (tile - overlap))
    starts = np.round(np.linspace(0, n - tile, count)).astype(int)
    return [(int(a), int(a) + tile) for a in starts]


def _ramps(spans: list[tuple[int, int]]) -> list[np.ndarray]:
    """Blending weight of each tile along one axis: a linear ramp over the parts it shares."""
    out = []
    for i, (a, b) in enumerate(spans):
        wt = np.ones(b - a)
        x = np.arange(a, b) + 0.5
        if i > 0 and spans[i - 1][1] > a:                    # rise over the part shared with the previous
            wt = np.minimum(wt, (x - a) / (spans[i - 1][1] - a))
        if i + 1 < len(spans) and spans[i + 1][0] < b:       # fall over the part shared with the next
            wt = np.minimum(wt, (b - x) / (b - spans[i + 1][0]))
        out.append(wt)
    return out


def _pair(tile: int | tuple[int, int]) -> tuple[int, int]:
    """(height, width) of a tile given as one side or a pair."""
    if isinstance(tile, (tuple, list)):
        return int(tile[0]), int(tile[1])
    return int(tile), int(tile)


def tile_windows(shape: tuple[int, int], tile: int | tuple[int, int], overlap: int
                 ) -> list[tuple[slice, slice]]:
    """(rows, cols) windows of the tiles of an (H, W) image, row by row (:func:`tile_spans`).

    ``tile`` is the side of square tiles or their (height, width).
    """
    th, tw = _pair(tile)
    ys = tile_spans(shape[0], th, overlap)
    xs = tile_spans(shape[1], tw, overlap)
    return [(slice(*y), slice(*x)) for y in ys for x in xs]


def blend(shape: tuple[int, int], tile: int | tuple[int, int], overlap: int,
          results: list[np.ndarray]) -> np.ndarray:
    """Blend per-tile results (in :func:`tile_windows` order) into one (H, W, C) image.

    Per pixel: the average of the tiles covering it, each weighted by a
    separable linear ramp that falls to zero across the part it shares with a
    neighbour (a tile's edge pixels count least), normalised by the sum of the
    weights, so overlapping constant results blend to that constant.
    """
    h, w = shape
    th, tw = _pair(tile)
    ys = tile_spans(h, th, overlap)
    xs = tile_spans(w, tw, overlap)
    if len(results) != len(ys) * len(xs):
        raise ValueError(f"{len(results)} tile results for {len(ys) * len(xs)} tiles")
    wy, wx = _ramps(ys), _ramps(xs)
    acc = np.zeros((h, w, results[0].shape[-1]))
    wsum = np.zeros((h, w, 1))
    for n, res in enumerate(results):
        i, j = divmod(n, len(xs))
        rows, cols = slice(*ys[i]), slice(*xs[j])
        wt = (wy[i][:, None] * wx[j][None, :])[..., None]
        acc[rows, cols] += wt * res
        wsum[rows, cols] += wt
    return acc / wsum


def tiled(shape: tuple[int, int], tile: int, overlap: int,
          solve: Callable[[slice, slice], np.ndarray], *, workers: int = 1) -> np.ndarray:
    """Run ``solve`` on overlapping tiles (in threads) and :func:`blend` the results.

    Parameters
    ----------
    shape
        (H, W) of the image.
    tile, overlap
        Tile side and the least overlap between neighbours (pixels).
    solve
        ``solve(rows, cols)`` returns the (h, w, C) result for that window.
    workers
        Threads running tiles at once.

    Returns
    -------
    numpy.ndarray
        (H, W, C) float64.
    """
    windows = tile_windows(shape, tile, overlap)
    if workers > 1 and len(windows) > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            results = list(pool.map(lambda rc: solve(*rc), windows))
    else:
        results = [solve(*rc) for rc in windows]
    return blend(shape, tile, overlap, results)


def _tile_job(args: tuple[Any, ...]) -> tuple[np.ndarray, float, dict[str, Any]]:
    """One tile's problem in a worker process (one BLAS thread)."""
    d0, tw, lam, gamma, opt, tol = args
    with threadpool_limits(limits=1, user_api="blas"):
        dl, lam_t, rec = _solve_tile(d0, tw, lam=lam, gamma=gamma, opt=opt, tol=tol)
    return np.asarray(dl, dtype=np.float32), lam_t, rec


def _process_context() -> Any:
    """The multiprocessing context of the worker pools.

    fork where it is safe and cheap: Python before 3.12 and no Python thread
    besides this one (the workers then share this process's pages, copy on
    write, and need nothing re-imported).  Otherwise forkserver (a clean
    process started once, with numpy, scipy and this module imported, that
    forks the workers): a process running threads (the live view of
    ``polcam capture``, a user's application) must not fork, since the child
    inherits locks those threads may hold, and Python 3.12 warns about it.
    Like spawn, forkserver workers import the caller's main script, which must
    then be guarded by ``if __name__ == "__main__":`` (``workers=1`` starts no
    process).  Platforms without either: spawn.
    """
    import multiprocessing
    import sys
    import threading

    methods = multiprocessing.get_all_start_methods()
    if sys.version_info < (3, 12) and threading.active_count() == 1 and "fork" in methods:
        return multiprocessing.get_context("fork")
    if "forkserver" not in methods:  # pragma: no cover - not Linux
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    from multiprocessing import forkserver

    if not getattr(forkserver._forkserver, "_forkserver_pid", None):  # not started yet: choose its preload
        ctx.set_forkserver_preload([__name__])
    return ctx


def start_workers() -> str:
    """Start the fork server now if the worker pools would use it; returns the start method.

    The fork server (:func:`_process_context`) is started on first use, which
    costs about 0.4 s (a fresh interpreter importing numpy, scipy and this
    module).  A program with threads that calls the tensor methods repeatedly
    (a live view, a benchmark) can pay it up front.
    """
    ctx = _process_context()
    method = ctx.get_start_method()
    if method == "forkserver":
        from multiprocessing import forkserver

        forkserver.ensure_running()
    return method


def _submit_processes(fn: Callable[[Any], Any], jobs: list[Any], workers: int) -> tuple[Any, list[Any]]:
    """Start ``fn(j)`` for every job in ``workers`` processes; returns the pool and the futures.

    The caller collects the results and shuts the pool down (``with pool:``).
    """
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=_process_context())
    try:
        return pool, [pool.submit(fn, job) for job in jobs]
    except BaseException:
        pool.shutdown(cancel_futures=True)
        raise


def _map_processes(fn: Callable[[Any], Any], jobs: Any, workers: int) -> list[Any]:
    """``[fn(j) for j in jobs]`` in ``workers`` processes, at most 2 jobs per worker in flight.

    Threads do not pay here: the tiles' many small numpy and LAPACK calls hold
    the GIL long enough that two threads ran only 1.2 times faster than one.
    """
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    out: dict[int, Any] = {}
    it = iter(enumerate(jobs))
    with ProcessPoolExecutor(max_workers=workers, mp_context=_process_context()) as pool:
        pending = {}
        for i, job in it:
            pending[pool.submit(fn, job)] = i
            if len(pending) >= 2 * workers:
                break
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                out[pending.pop(f)] = f.result()
                nxt = next(it, None)
                if nxt is not None:
                    pending[pool.submit(fn, nxt[1])] = nxt[0]
    return [out[i] for i in range(len(out))]


# ---------------------------------------------------------------------------
# the method
# ---------------------------------------------------------------------------

def _fit_side(n: int, side: int, overlap: int) -> int:
    """The smallest tile side up to ``side`` that covers ``n`` pixels with as few tiles as ``side`` does.

    :func:`tile_spans` spreads a fixed number of tiles evenly, so a side larger
    than needed only widens the overlaps (1024 rows in tiles of 96 overlapping
    by at least 4 need 12 tiles; 89 rows each do it with overlaps of 4, 96
    with overlaps of 12, work spent twice).
    """
    if n <= side:
        return n
    count = math.ceil((n - overlap) / (side - overlap))
    return min(side, math.ceil((n - overlap) / count) + overlap)


def _tile_plan(h: int, w: int, tile: int | tuple[int, int] | None, overlap: int, solver: str
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
        th, tw = _fit_side(h, int(pair[0]), overlap), _fit_side(w, int(pair[1]), overlap)
    else:
        th, tw = min(int(pair[0]), h), min(int(pair[1]), w)
    if th >= h and tw >= w:
        return (h, w), 0
    return (th, tw), int(overlap)


def _solve_tile(d0: np.ndarray, tw: np.ndarray | None, *, lam: float | None, gamma: float,
                opt: dict[str, Any], tol: float, threads: int = 1) -> tuple[np.ndarray, float, dict[str, Any]]:
    """The tensor problem of one tile: its diffuse (representation 1, mean over angles)."""
    n4, _, n1, n2, _ = d0.shape
    k, m = 4 * n1, 3 * n2
    lam_t = _default_lam(lam, k, m, n4)
    schedule = dict(rho=opt["rho"], mu0=opt["mu0"], mu_max=opt["mu_max"], tol=tol,
                    max_iter=opt["max_iter"])
    if opt["solver"] == "exact":
        D = unfold(d0)
        tau = None if tw is None else np.broadcast_to(unfold(tw[None])[..., :1], D.shape)

        def project(T: np.ndarray) -> np.ndarray:
            return unfold(phase_project(fold(T, n1, n2)))

        L, _S, rec = ialm(D, tau=tau, lam=lam_t, gamma=gamma, project=project if gamma > 0 else None,
                          solver="exact", **schedule)
        return fold(L, n1, n2)[0].mean(axis=0), lam_t, rec
    dt = np.dtype(opt["precision"])
    Z = unfold_slices(d0).astype(dt)
    tau = None if tw is None else unfold_slices(tw[None])

    def project_s(T: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        return phase_project_slices(T, n1, n2, out=out)

    L, _S, rec = ialm_fast(Z, tau=tau, lam=lam_t, gamma=gamma,
                           project=project_s if gamma > 0 else None, dtype=dt,
                           svt_options={"workers": threads}, chunks=threads, chunked_project=True,
                           **schedule)
    return (L[0].reshape(4, n1, 3, n2).mean(axis=0, dtype=np.float64).transpose(0, 2, 1), lam_t, rec)


def _device_batch(tiles: int, per_tile: int, device: Any) -> int:
    """Tiles per IALM call on a torch device: as many as fit in a third of its free memory.

    ``per_tile`` is the bytes of one tile's tensor; the IALM holds about 24 of
    them.  On the CPU, :data:`DEVICE_BATCH` tiles.
    """
    import torch

    if device.type != "cuda":
        return max(1, min(tiles, DEVICE_BATCH))
    free, _ = torch.cuda.mem_get_info(device)
    return max(1, min(tiles, int(free / 3 // (24 * per_tile))))


def _separate_device(stack: np.ndarray, *, opt: dict[str, Any], tile: tuple[int, int], overlap: int,
                     tol: float, gamma: float, use_tau: bool, shared: bool, workers: int
                     ) -> tuple[np.ndarray, np.ndarray, float, float, list[tuple[float, dict[str, Any]]],
                                dict[str, float]]:
    """Steps 1-7 of :func:`separate_tensor` on a PyTorch device (``device=`` option).

    Every step runs on the device (:mod:`polcam.separation._torch_prep`) except an
    initial diffuse other than Yang'10, which runs in numpy; the tiles go to the
    IALM in as few batches as the device's memory allows.

    Returns
    -------
    diffuse_w : numpy.ndarray
        (H, W, 3) float64, the blended diffuse of the white-balanced, scaled image.
    gam : numpy.ndarray
        (3,) illuminant chromaticity.
    scale : float
        The scale the white-balanced image was divided by.
    filled : float
        Share of representation slots filled (:func:`representations`).
    records : list
        (lambda, IALM record) per tile.
    timings : dict
        Seconds of each step (illuminant, representations, init, ialm).
    """
    import torch

    from polcam.separation import _torch, _torch_prep

    dev = torch.device(opt["device"])
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    _, h, w, _ = stack.shape
    x = torch.as_tensor(np.ascontiguousarray(stack), device=dev).to(torch.float64)
    gam = _choose_illuminant(opt["illuminant"], lambda: _torch_prep.estimate_illuminant(x))
    x = x / torch.as_tensor(_white_divisor(gam), device=dev)
    scale = float(max(float(x.max()), 1.0))
    x = x / scale
    sync()
    timings["illuminant"] = time.perf_counter() - t0

    t = time.perf_counter()
    wdt = torch.float32 if opt["precision"] == "float32" else torch.float64
    xw = x.to(wdt)
    chro = _torch_prep.polarization_chromaticity(x)
    rng = np.random.default_rng(opt["seed"])
    offsets, filled = _torch_prep.representations(chro, n4=opt["n4"], block=opt["block"],
                                                  threshold=opt["threshold"], rng=rng)
    del x, chro
    sync()
    timings["representations"] = time.perf_counter() - t

    t = time.perf_counter()
    images = xw[None] if shared else _torch_prep.gather(xw, offsets)     # (1 or n4, 4, H, W, 3)
    if opt["init"] == "yang10":
        first = torch.stack([torch.stack([_torch_prep.yang10(images[i, a]).to(wdt) for a in range(4)])
                             for i in range(images.shape[0])])
    else:
        host = images.cpu().numpy()
        first = torch.as_tensor(initial_diffuse(host, init=opt["init"], workers=workers), device=dev).to(wdt)
    d0 = _torch_prep.gather(first[0], offsets) if shared else first
    del images, first, offsets, xw
    sync()
    timings["init"] = time.perf_counter() - t

    t = time.perf_counter()
    tw = (_torch_prep.tau_weights(d0[0], alpha=opt["alpha"], beta=opt["beta"], floor=opt["tau_floor"])
          if use_tau else None)
    ys, xs = tile_spans(h, tile[0], overlap), tile_spans(w, tile[1], overlap)
    n4 = d0.shape[0]
    n1, n2 = ys[0][1] - ys[0][0], xs[0][1] - xs[0][0]
    lam_t = _default_lam(opt["lam"], 4 * n1, 3 * n2, n4)
    rows_per = max(1, _device_batch(len(ys) * len(xs), n4 * 12 * n1 * n2 * d0.element_size(), dev) // len(xs))
    results, records = [], []
    for r0 in range(0, len(ys), rows_per):
        part = ys[r0:r0 + rows_per]
        D = _torch_prep.tile_batch(d0, part, xs)
        tau = None if tw is None else _torch_prep.tile_batch(tw[None], part, xs)
        L, recs = _torch.ialm_tensors(D, tau=tau, lam=lam_t, gamma=gamma, shape=(n1, n2), rho=opt["rho"],
                                      mu0=opt["mu0"], mu_max=opt["mu_max"], tol=tol, max_iter=opt["max_iter"])
        del D, tau
        b = L.shape[0]
        results.append(L[:, 0].reshape(b, 4, n1, 3, n2).to(torch.float64).mean(dim=1).permute(0, 1, 3, 2))
        records += [(lam_t, rec) for rec in recs]
        del L
    diffuse_w = _torch_prep.blend((h, w), ys, xs, torch.cat(results)).cpu().numpy()
    timings["ialm"] = time.perf_counter() - t
    return diffuse_w, gam, scale, filled, records, timings


def separate_tensor(stack: np.ndarray, *, variant: str = "tensor", **options: Any
                    ) -> tuple[np.ndarray, dict[str, Any]]:
    """Diffuse layer of a colour polarization stack by the tensor method.

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1], angles 0, 45, 90, 135.
    variant
        ``tensor`` (eq. 4), ``tensor-tau`` (eq. 10) or ``tensor-plain`` (eq. 11).
    **options
        Any key of :data:`DEFAULTS`.  ``solver``: ``"fast"`` (default) or
        ``"exact"`` (the reference); ``tile``/``overlap``: tiles of that side
        (an int) or (height, width) sharing at least that many pixels, each its
        own tensor problem, blended by :func:`blend` (``tile=None``: one tile
        for the exact solver; for the fast one, one tile up to
        :data:`AUTO_UNTILED_PIXELS` pixels, tiles of at most :data:`AUTO_TILE`
        above, fitted to the image by :func:`_fit_side`);
        ``workers``: worker processes for the initial diffuse and the tiles,
        threads for the Fourier slices of one tile (None: the CPU count, at most
        :data:`MAX_AUTO_WORKERS`); ``device``: None (numpy) or a PyTorch device such as
        ``"cuda"`` or ``"cpu"`` (needs the ``torch`` extra): every step then runs on it
        (:func:`_separate_device`; an ``init`` other than Yang'10 runs in numpy and is
        copied over), with the same answer to float32 rounding; ``precision``: the fast
        solver's working precision (``"float32"``, or ``"float64"`` for agreement
        with the exact solver to about 1e-5).

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) on the scale of one polarization image.
    info : dict
        Options used, illuminant, representation fill rate, timings and the
        IALM record (iterations, converged, residual, residuals; over tiles:
        the most iterations, all converged, the largest residual, and the
        residuals of the tile that took longest).
    """
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise MethodError(
            f"unknown option(s) {', '.join(sorted(unknown))} for method {variant!r}; "
            f"expected: {', '.join(DEFAULTS)}"
        )
    opt = {**DEFAULTS, **options}
    if opt["solver"] not in SOLVERS:
        raise MethodError(f"solver {opt['solver']!r}: expected one of {', '.join(SOLVERS)}")
    if opt["device"] is not None:
        if not isinstance(opt["device"], str):
            raise MethodError(f"device {opt['device']!r}: expected None (numpy) or a torch device name")
        if opt["solver"] != "fast":
            raise MethodError(f"device {opt['device']!r} runs the fast solver; got solver={opt['solver']!r}")
        from polcam.separation import _torch

        _torch.check_device(opt["device"])
    if opt["precision"] not in ("float32", "float64"):
        raise MethodError(f"precision {opt['precision']!r}: expected 'float32' or 'float64'")
    workers = opt["workers"]
    if workers is None:
        workers = min(os.cpu_count() or 1, MAX_AUTO_WORKERS)
    if not isinstance(workers, (int, np.integer)) or workers < 1:
        raise MethodError(f"workers = {workers!r}: expected None or a positive integer")
    tol = opt["tol"]
    if tol is None:
        tol = EXACT_TOL if opt["solver"] == "exact" else FAST_TOL
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    _, h, w, _ = stack.shape
    tile, overlap = _tile_plan(h, w, opt["tile"], opt["overlap"], opt["solver"])
    n4 = opt["n4"]
    use_tau = variant in ("tensor", "tensor-tau")
    gamma = opt["gamma"] if variant == "tensor" else 0.0
    shared = opt["shared_init"] if opt["shared_init"] is not None else opt["solver"] == "fast"
    if opt["device"] is not None:
        diffuse_w, gam, scale, filled, records, timings = _separate_device(
            stack, opt=opt, tile=tile, overlap=overlap, tol=tol, gamma=gamma, use_tau=use_tau,
            shared=shared, workers=workers)
        return _finish(diffuse_w, gam=gam, scale=scale, filled=filled, records=records, timings=timings,
                       variant=variant, opt=opt, tol=tol, gamma=gamma, shape=(h, w),
                       tile=None if tile == (h, w) else (tile[0], tile[1], overlap))

    # 1. illuminant
    gam = _choose_illuminant(opt["illuminant"], lambda: estimate_illuminant(stack))
    x = normalize_illuminant(stack, gam)
    scale = float(max(x.max(), 1.0))
    x = x / scale  # keep the white-balanced stack in [0, 1]
    timings["illuminant"] = time.perf_counter() - t0

    # the fast solver works in float32: its representation images and initial diffuse too
    # (half the memory of a full frame; Yang'10 computes in float64 either way)
    single = opt["solver"] == "fast" and opt["precision"] == "float32"
    xw = x.astype(np.float32) if single else x
    # worker processes only where the runs are long enough to pay for starting them
    # (and not beyond INIT_PROCESS_PIXELS: a Yang'10 run on a 5 Mpixel image held ~1.4 GB)
    init_workers = workers if 256 * 256 <= h * w <= INIT_PROCESS_PIXELS else 1
    background = None
    if shared and init_workers > 1:
        # 5'. (below) started now: the four Yang'10 runs go on in worker processes while this
        # process finds the representations, which they do not need
        background = _submit_processes(_init_job, [(opt["init"], xw[a], {}) for a in range(4)],
                                       init_workers)

    # 3-4. chromaticity and representations
    t = time.perf_counter()
    try:
        chro = polarization_chromaticity(x)
        rng = np.random.default_rng(opt["seed"])
        offsets, filled = representations(chro, n4=opt["n4"], block=opt["block"],
                                          threshold=opt["threshold"], rng=rng)
    except BaseException:
        if background is not None:
            background[0].shutdown(cancel_futures=True)
        raise
    del x, chro
    if shared:
        # 5'. the initial diffuse of the four angle images, moved like the representations:
        # Yang'10 filters with a spatial sigma of a quarter of the image, so moving pixels
        # within a 3 x 3 block among pixels of the same chromaticity before or after it
        # changes its output little (docs/algorithm.md, Fast solver)
        timings["representations"] = time.perf_counter() - t
        t = time.perf_counter()
        if background is not None:
            first = np.empty_like(xw)
            pool, futures = background
            with pool:
                for a, fut in enumerate(futures):
                    first[a] = fut.result()
        else:
            first = initial_diffuse(xw[None], init=opt["init"], workers=init_workers)[0]
        d0 = gather(first, offsets)
        del first
    else:
        reps = gather(xw, offsets)                       # (n4, 4, H, W, 3)
        timings["representations"] = time.perf_counter() - t
        # 5. initial diffuse
        t = time.perf_counter()
        d0 = initial_diffuse(reps, init=opt["init"], workers=init_workers)
        del reps
    del xw, offsets
    timings["init"] = time.perf_counter() - t

    # 6-7. tensor and IALM, per tile
    t = time.perf_counter()
    tw = tau_weights(d0[0], alpha=opt["alpha"], beta=opt["beta"], floor=opt["tau_floor"]) if use_tau else None
    records: list[tuple[float, dict[str, Any]]] = []

    one_tile = tile == (h, w)
    # one BLAS thread: OpenBLAS' threaded complex SVD of these slice sizes was 12 times
    # slower than the single-threaded one on the 2-core machine (docs/benchmarks.md); the
    # Fourier slices (one tile) or the tiles (worker processes) run in parallel instead
    if one_tile:
        with threadpool_limits(limits=1, user_api="blas"):
            diffuse_w, lam_t, rec = _solve_tile(d0, tw, lam=opt["lam"], gamma=gamma, opt=opt, tol=tol,
                                                threads=workers)
        records.append((lam_t, rec))
    else:
        windows = tile_windows((h, w), tile, overlap)
        wdt = np.float32 if single else np.float64
        jobs = ((np.ascontiguousarray(d0[:, :, r, c], dtype=wdt),
                 None if tw is None else np.ascontiguousarray(tw[:, r, c], dtype=wdt),
                 opt["lam"], gamma, opt, tol) for r, c in windows)
        if workers > 1:
            out = _map_processes(_tile_job, jobs, workers)
        else:
            out = [_tile_job(j) for j in jobs]
        records = [(lam_t, rec) for _, lam_t, rec in out]
        diffuse_w = blend((h, w), tile, overlap, [o[0] for o in out])
    timings["ialm"] = time.perf_counter() - t

    return _finish(diffuse_w, gam=gam, scale=scale, filled=filled, records=records, timings=timings,
                   variant=variant, opt=opt, tol=tol, gamma=gamma, shape=(h, w),
                   tile=None if one_tile else (tile[0], tile[1], overlap))


def _finish(diffuse_w: np.ndarray, *, gam: np.ndarray, scale: float, filled: float,
            records: list[tuple[float, dict[str, Any]]], timings: dict[str, float], variant: str,
            opt: dict[str, Any], tol: float, gamma: float, shape: tuple[int, int],
            tile: tuple[int, int, int] | None) -> tuple[np.ndarray, dict[str, Any]]:
    """Step 8 of :func:`separate_tensor` and its info dict."""
    h, w = shape
    # 8. diffuse: representation 1, mean over angles, back to the input's illuminant
    diffuse = diffuse_w * scale * (3.0 * gam)
    slowest = max(records, key=lambda r: r[1]["iterations"])[1]
    counts: dict[str, int] = {}
    for _, rec in records:
        for k2, v in rec.get("svt_counts", {}).items():
            counts[k2] = counts.get(k2, 0) + v
    info = {
        "variant": variant,
        "options": {k2: (v.tolist() if isinstance(v, np.ndarray) else v) for k2, v in opt.items()},
        "solver": opt["solver"],
        "device": opt["device"],
        "tol": tol,
        "illuminant_chromaticity": gam.tolist(),
        "lambda": records[0][0] if len(records) == 1 else [r[0] for r in records],
        "gamma": gamma,
        "representations_filled": filled,
        "tensor_shape": [4 * h, 3 * w, opt["n4"]],
        "tile": None if tile is None else list(tile),
        "tiles": len(records),
        "timings": timings,
        "iterations": slowest["iterations"],
        "converged": all(r[1]["converged"] for r in records),
        "residual": max(r[1]["residual"] for r in records),
        "residuals": slowest["residuals"],
        "final_ranks": slowest["ranks"][-1] if slowest["ranks"] else [],
        "svt_counts": counts,
    }
    if len(records) > 1:
        info["iterations_per_tile"] = [r[1]["iterations"] for r in records]
    return diffuse, info


for _variant in ("tensor", "tensor-tau", "tensor-plain"):
    register(_variant, kind="stack", reference=REFERENCE, options=tuple(DEFAULTS))(
        functools.partial(separate_tensor, variant=_variant)
    )
