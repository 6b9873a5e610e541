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
"""

from __future__ import annotations

import functools
import time
from typing import Any

import numpy as np
from scipy.sparse.linalg import svds
from threadpoolctl import threadpool_limits

from polcam.errors import MethodError
from polcam.separation._registry import method_spec, register
from polcam.separation._tsvt import tsvt
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
    "separate_tensor",
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
    "tol": 1e-5,        # stop at ||D - L - S||_F / ||D||_F < tol (paper: 1e-5)
    "max_iter": 200,
    "init": "yang10",   # initial diffuse of every representation (paper: Yang'10)
    "illuminant": "polarization",  # "polarization", "white" or an RGB triple
    "solver": "exact",
    "seed": 0,
}


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
    g = np.asarray(gamma, dtype=np.float64).reshape(3)
    if np.any(g <= 0):
        raise MethodError(f"illuminant chromaticity {g.tolist()}: expected three positive values")
    g = g / g.sum()
    return stack / (3.0 * g)


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
    if n4 < 1:
        raise MethodError(f"n4 = {n4}: expected at least 1 representation")
    if block < 1 or block % 2 == 0:
        raise MethodError(f"block = {block}: expected an odd block side >= 1")
    h, w, _ = chro.shape
    r = block // 2
    cand = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dy, dx) != (0, 0)]
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
    yy, xx = np.mgrid[0:h, 0:w]
    out = []
    for off in offsets:
        out.append(images[..., yy + off[..., 0], xx + off[..., 1], :])
    return np.stack(out)


def initial_diffuse(reps: np.ndarray, *, init: str = "yang10", **options: Any) -> np.ndarray:
    """Diffuse estimate of every representation and angle by a single-image method.

    Parameters
    ----------
    reps
        (n4, 4, H, W, 3) representation images of the four angles.
    init
        A registered single-image method (the paper: Yang'10).

    Returns
    -------
    numpy.ndarray
        (n4, 4, H, W, 3), each in [0, its input].
    """
    spec = method_spec(init)
    if spec.kind != "single":
        raise MethodError(f"init method {init!r} is not a single-image method")
    out = np.empty_like(reps)
    for i in range(reps.shape[0]):
        for a in range(reps.shape[1]):
            img = np.clip(reps[i, a], 0.0, 1.0)
            res = spec.fn(img, **options)
            d = res[0] if isinstance(res, tuple) else res
            out[i, a] = np.clip(np.nan_to_num(np.asarray(d, dtype=np.float64)), 0.0, img)
    return out


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
        Schedule, stopping rule and t-SVT solver.

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
# the method
# ---------------------------------------------------------------------------

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
        Any key of :data:`DEFAULTS`.

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) on the scale of one polarization image.
    info : dict
        Options used, illuminant, representation fill rate, timings and the
        IALM record (iterations, converged, residual, residuals).
    """
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise MethodError(
            f"unknown option(s) {', '.join(sorted(unknown))} for method {variant!r}; "
            f"expected: {', '.join(DEFAULTS)}"
        )
    opt = {**DEFAULTS, **options}
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    _, h, w, _ = stack.shape

    # 1. illuminant
    ill = opt["illuminant"]
    if isinstance(ill, str):
        if ill == "polarization":
            gam = estimate_illuminant(stack)
        elif ill == "white":
            gam = np.full(3, 1 / 3)
        else:
            raise MethodError(f"illuminant {ill!r}: expected 'polarization', 'white' or an RGB triple")
    else:
        gam = np.asarray(ill, dtype=np.float64)
        gam = gam / gam.sum()
    x = normalize_illuminant(stack, gam)
    scale = float(max(x.max(), 1.0))
    x = x / scale  # keep the white-balanced stack in [0, 1]
    timings["illuminant"] = time.perf_counter() - t0

    # 3-4. chromaticity and representations
    t = time.perf_counter()
    chro = polarization_chromaticity(x)
    rng = np.random.default_rng(opt["seed"])
    offsets, filled = representations(chro, n4=opt["n4"], block=opt["block"],
                                      threshold=opt["threshold"], rng=rng)
    reps = gather(x, offsets)                            # (n4, 4, H, W, 3)
    timings["representations"] = time.perf_counter() - t

    # 5. initial diffuse
    t = time.perf_counter()
    d0 = initial_diffuse(reps, init=opt["init"])
    timings["init"] = time.perf_counter() - t

    # 6-7. tensor and IALM
    t = time.perf_counter()
    D = unfold(d0)
    k, m, n4 = D.shape
    lam = opt["lam"] if opt["lam"] is not None else 1.0 / np.sqrt(max(k, m) * n4)
    use_tau = variant in ("tensor", "tensor-tau")
    gamma = opt["gamma"] if variant == "tensor" else 0.0
    tau = None
    if use_tau:
        tw = tau_weights(d0[0], alpha=opt["alpha"], beta=opt["beta"], floor=opt["tau_floor"])
        tau = np.broadcast_to(unfold(tw[None])[..., :1], D.shape)

    def project(T: np.ndarray) -> np.ndarray:
        return unfold(phase_project(fold(T, h, w)))

    # one BLAS thread: OpenBLAS' threaded complex SVD of these slice sizes was 12 times
    # slower than the single-threaded one on the 2-core machine (docs/benchmarks.md)
    with threadpool_limits(limits=1, user_api="blas"):
        L, _S, rec = ialm(D, tau=tau, lam=lam, gamma=gamma, project=project if gamma > 0 else None,
                          rho=opt["rho"], mu0=opt["mu0"], mu_max=opt["mu_max"], tol=opt["tol"],
                          max_iter=opt["max_iter"], solver=opt["solver"])
    timings["ialm"] = time.perf_counter() - t

    # 8. diffuse: representation 1, mean over angles, back to the input's illuminant
    diffuse = fold(L, h, w)[0].mean(axis=0) * scale * (3.0 * gam)
    info = {
        "variant": variant,
        "options": {k2: (v.tolist() if isinstance(v, np.ndarray) else v) for k2, v in opt.items()},
        "illuminant_chromaticity": gam.tolist(),
        "lambda": lam,
        "gamma": gamma,
        "representations_filled": filled,
        "tensor_shape": [k, m, n4],
        "timings": timings,
        "iterations": rec["iterations"],
        "converged": rec["converged"],
        "residual": rec["residual"],
        "residuals": rec["residuals"],
        "final_ranks": rec["ranks"][-1] if rec["ranks"] else [],
    }
    return diffuse, info


for _variant in ("tensor", "tensor-tau", "tensor-plain"):
    register(_variant, kind="stack", reference=REFERENCE)(
        functools.partial(separate_tensor, variant=_variant)
    )
