"""The tensor method's driver: one pipeline for the numpy and PyTorch backends.

Steps (docs/methods/tensor.md states each as implemented):

1. the illuminant chromaticity Gamma (:func:`.operators.illuminant`) and the
   normalisation ``I / (3 Gamma)`` to a white illuminant, scaled into [0, 1];
2. the polarization chromaticity (eq. 3) and the representations (similar
   pixels of a block around each pixel);
3. the initial diffuse of every representation by a single-image method
   (Yang'10): on the four angle images, moved like the representations
   (``shared_init``), or on every representation image (the paper);
4. tau, and per tile the tensor problem D = L + S by the IALM
   (:func:`.ialm.solve_tiles`), the tiles blended (:func:`.tiling.blend`);
5. the diffuse: representation 1 of L, mean over the angles, back to the
   input's illuminant and scale; with ``imin_bound=True`` (polcam's option, off
   by default) clipped to [0, Imin] of the input (unpolarized light never
   exceeds the minimum of the polarization sinusoid, but polarized diffuse
   light does).

Only where the work runs differs between backends: numpy runs the initial
diffuse, the tiles, and one tile's Fourier slices in threads of this process
(:mod:`polcam.parallel`: no worker processes, so a call works from any caller),
with BLAS at one thread for the whole call; PyTorch runs every step on its
device and the tiles in batches.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.parallel import blas_limit, map_workers, submit_workers
from polcam.polarimetry import imin
from polcam.separation._common import finish_diffuse
from polcam.separation._registry import method_spec
from polcam.separation.tensor.ialm import solve_tiles
from polcam.separation.tensor.operators import (
    gather,
    illuminant,
    polarization_chromaticity,
    representations,
    tau_weights,
    white_divisor,
)
from polcam.separation.tensor.options import DEVICE_BATCH, INIT_PARALLEL_PIXELS, Plan, default_lam, resolve
from polcam.separation.tensor.tiling import blend, tile_batch, tile_spans
from polcam.separation.tensor.torch_backend import device_batch

__all__ = ["separate_tensor", "initial_diffuse", "warm_up"]

#: The single-image methods written over the array namespace (:mod:`polcam._xp`): with
#: ``device=`` they compute the initial diffuse on the device; any other ``init`` runs
#: in numpy on the host and is copied over.
DEVICE_INITS = ("yang10",)


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
        Any key of :data:`~polcam.separation.tensor.options.DEFAULTS`.
        ``solver``: ``"fast"`` (default) or ``"exact"`` (the reference);
        ``tile``/``overlap``: tiles of that side (an int) or (height, width)
        sharing at least that many pixels, each its own tensor problem, blended
        (``tile=None``: one tile for the exact solver; for the fast one, one tile
        up to ``AUTO_UNTILED_PIXELS`` pixels, tiles of at most ``AUTO_TILE``
        above); ``workers``: threads for the initial diffuse, the tiles and
        the Fourier slices of one tile (the answer does not depend on it); ``device``: None
        (numpy) or a PyTorch device such as ``"cuda"`` or ``"cpu"`` (needs the
        ``torch`` extra): every step then runs on it (an ``init`` other than
        Yang'10 runs in numpy and is copied over), with the same answer to
        float32 rounding; ``precision``: the fast solver's working precision.

    Returns
    -------
    diffuse : numpy.ndarray
        (H, W, 3) float64 on the scale of one polarization image, at least 0; with
        ``imin_bound=True`` at most Imin of ``stack`` (``Imin = Ic - Isv``,
        :func:`polcam.polarimetry.imin`).
    info : dict
        Options used, illuminant, representation fill rate, timings, the share
        of values above Imin (``above_imin``, a diagnostic; ``clipped_to_imin``: the
        share clipped there, 0 without the bound) and the IALM record (iterations, converged, residual, residuals; over tiles:
        the most iterations, all converged, the largest residual, and the
        residuals of the tile that took longest).
    """
    plan = resolve(np.shape(stack), variant, options)
    if plan.opt["device"] is not None:
        return _separate(stack, plan)
    # one BLAS thread for the whole call, whose parts run in threads: OpenBLAS' threaded complex
    # SVD of these slice sizes was 12 times slower than the single-threaded one on the 2-core
    # machine (docs/benchmarks.md); the limit is process-wide, so it is held once, around it all
    with blas_limit(1):
        return _separate(stack, plan)


def _separate(stack: np.ndarray, plan: Plan) -> tuple[np.ndarray, dict[str, Any]]:
    """:func:`separate_tensor` with checked options."""
    opt = plan.opt
    h, w = plan.shape
    device = opt["device"]
    timings: dict[str, float] = {}
    t0 = time.perf_counter()

    # 1. illuminant, normalised to white and scaled into [0, 1]
    if device is None:
        x = np.asarray(stack, dtype=np.float64)
        sync = _no_sync
    else:
        import torch

        dev = torch.device(device)
        x = torch.as_tensor(np.ascontiguousarray(stack), device=dev).to(torch.float64)
        sync = torch.cuda.synchronize if dev.type == "cuda" else _no_sync
    xp = namespace(x)
    gam = illuminant(x, opt["illuminant"])
    x = x / xp.asarray(white_divisor(gam), like=x)
    scale = float(max(float(x.max()), 1.0))
    x = x / scale
    sync()
    timings["illuminant"] = time.perf_counter() - t0

    # the fast solver works in its precision from here: representation images and initial diffuse too
    work = opt["precision"] if opt["solver"] == "fast" else "float64"
    xw = xp.astype(x, xp.dtype_of(work))
    # threads only where the runs are long enough to outweigh the Python between numpy calls
    # (and not beyond INIT_PARALLEL_PIXELS: a Yang'10 run on a 5 Mpixel image held ~1.4 GB)
    init_workers = plan.workers if 256 * 256 <= h * w <= INIT_PARALLEL_PIXELS else 1
    # 3'. with a shared initial diffuse, the four Yang'10 runs start now (in threads)
    # while the representations are found, which they do not need
    pending = _Initial(xw[None], init=opt["init"], workers=init_workers) if plan.shared else None

    # 2. chromaticity and representations
    t = time.perf_counter()
    try:
        chro = polarization_chromaticity(x)
        offsets, filled = representations(chro, n4=opt["n4"], block=opt["block"], threshold=opt["threshold"],
                                          rng=np.random.default_rng(opt["seed"]))
    except BaseException:
        if pending is not None:
            pending.cancel()
        raise
    del x, chro
    if plan.shared:
        # Yang'10 filters with a spatial sigma of a quarter of the image, so moving pixels within a
        # 3 x 3 block among pixels of the same chromaticity before or after it changes its output
        # little (docs/methods/tensor.md, Fast solver)
        sync()
        timings["representations"] = time.perf_counter() - t
        t = time.perf_counter()
        d0 = gather(pending.result()[0], offsets)
    else:
        reps = gather(xw, offsets)                       # (n4, 4, H, W, 3)
        sync()
        timings["representations"] = time.perf_counter() - t
        t = time.perf_counter()
        d0 = _Initial(reps, init=opt["init"], workers=init_workers).result()
        del reps
    del xw, offsets
    sync()
    timings["init"] = time.perf_counter() - t

    # 4. tau, the tensor problem of every tile, blending
    t = time.perf_counter()
    tw = (tau_weights(d0[0], alpha=opt["alpha"], beta=opt["beta"], floor=opt["tau_floor"])[None]
          if plan.use_tau else None)                     # (1, 4, H, W, 3)
    diffuse_w, lam_t, records = _solve(d0, tw, plan)
    timings["ialm"] = time.perf_counter() - t
    return _finish(diffuse_w, gam=gam, scale=scale, filled=filled, lam_t=lam_t, records=records,
                   timings=timings, plan=plan, bound=imin(np.asarray(stack, dtype=np.float64)))


def _no_sync() -> None:
    return None


def _solve(d0: Any, tw: Any, plan: Plan) -> tuple[np.ndarray, float, list[dict[str, Any]]]:
    """Step 4 after tau: every tile's tensor problem, blended; (H, W, 3) float64 numpy, lambda, records."""
    opt = plan.opt
    h, w = plan.shape
    ys, xs = tile_spans(h, plan.tile[0], plan.overlap), tile_spans(w, plan.tile[1], plan.overlap)
    n4 = d0.shape[0]
    n1, n2 = ys[0][1] - ys[0][0], xs[0][1] - xs[0][0]
    lam_t = default_lam(opt["lam"], 4 * n1, 3 * n2, n4)
    kw = dict(n1=n1, n2=n2, lam=lam_t, gamma=plan.gamma, opt=opt, tol=plan.tol)

    def batch(part: list[tuple[int, int]], cols: list[tuple[int, int]]) -> tuple[Any, Any]:
        return tile_batch(d0, part, cols), None if tw is None else tile_batch(tw, part, cols)

    xp = namespace(d0)
    if xp.name == "torch":
        per_tile = n4 * 12 * n1 * n2 * d0.element_size()
        rows_per = max(1, device_batch(len(ys) * len(xs), per_tile, d0.device, DEVICE_BATCH) // len(xs))
        results, records = [], []
        for r0 in range(0, len(ys), rows_per):
            res, recs = solve_tiles(*batch(ys[r0:r0 + rows_per], xs), **kw)
            results.append(res)
            records += recs
        out = blend((h, w), plan.tile, plan.overlap, xp.torch.cat(results))
        return xp.to_numpy(out), lam_t, records
    if plan.one_tile:
        # the Fourier slices run in parallel threads
        res, records = solve_tiles(*batch(ys, xs), threads=plan.workers, **kw)
        return res[0], lam_t, records
    jobs = ((*batch([y], [x]), kw) for y in ys for x in xs)
    if plan.workers > 1:
        out = map_workers(_tile_job, jobs, plan.workers)
    else:
        out = [_tile_job(j) for j in jobs]
    records = [rec for _, rec in out]
    return blend((h, w), plan.tile, plan.overlap, [r for r, _ in out]), lam_t, records


def _tile_job(args: tuple[Any, Any, dict[str, Any]]) -> tuple[np.ndarray, dict[str, Any]]:
    """One tile's problem (in this thread or a worker thread): its diffuse in float32 and its record."""
    d, tau, kw = args
    res, recs = solve_tiles(d, tau, **kw)
    return np.asarray(res[0], dtype=np.float32), recs[0]


class _Initial:
    """The initial diffuse of (n, 4, H, W, 3) images, started now, collected by :meth:`result`.

    numpy with ``workers > 1``: the ``4 n`` single-image runs start at once in
    ``workers`` threads.  A torch tensor with ``init="yang10"``: Yang'10 on its
    device when collected.  Otherwise: :func:`initial_diffuse` when collected.
    """

    def __init__(self, images: Any, *, init: str, workers: int) -> None:
        self.images, self.init, self.workers = images, init, workers
        self.xp = namespace(images)
        self.background = None
        if self.xp.name == "numpy" and workers > 1 and init_jobs(images) > 1:
            n, na = images.shape[:2]
            self.background = submit_workers(
                _init_job, [(init, images[i, a], {}) for i in range(n) for a in range(na)], workers)

    def cancel(self) -> None:
        if self.background is not None:
            self.background[0].shutdown(cancel_futures=True)

    def result(self) -> Any:
        images, xp = self.images, self.xp
        if self.background is not None:
            out = np.empty_like(images)
            pool, futures = self.background
            n, na = images.shape[:2]
            with pool:
                for j, fut in enumerate(futures):
                    out[j // na, j % na] = fut.result()
            return out
        if xp.name == "torch":
            if self.init in DEVICE_INITS:
                return xp.stack([xp.stack([xp.astype(_init_job((self.init, im, {})), images.dtype) for im in rep])
                                 for rep in images])
            host = initial_diffuse(xp.to_numpy(images), init=self.init, workers=self.workers)
            return xp.astype(xp.asarray(host, like=images), images.dtype)
        return initial_diffuse(images, init=self.init, workers=1)


def init_jobs(images: Any) -> int:
    """Single-image runs of an (n, 4, H, W, 3) initial diffuse."""
    return int(images.shape[0] * images.shape[1])


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
        Threads running the ``4 n4`` independent single-image runs (the result
        does not depend on it).

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
        res = map_workers(_init_job, args, workers)
    else:
        res = map(_init_job, args)
    for (i, a), d in zip(jobs, res):
        out[i, a] = d
    return out


def _init_job(args: tuple[str, Any, dict[str, Any]]) -> Any:
    """One single-image run of the initial diffuse (in this thread, a worker thread or on a device).

    A numpy image gives float64 numpy; a tensor (a method of :data:`DEVICE_INITS`) a
    float64 tensor on its device.
    """
    init, rep, options = args
    img = namespace(rep).clip(rep, 0.0, 1.0)
    res = method_spec(init).fn(img, **options)
    return finish_diffuse(res[0] if isinstance(res, tuple) else res, img)


def _finish(diffuse_w: np.ndarray, *, gam: np.ndarray, scale: float, filled: float, lam_t: float,
            records: list[dict[str, Any]], timings: dict[str, float], plan: Plan, bound: np.ndarray
            ) -> tuple[np.ndarray, dict[str, Any]]:
    """Step 5 and the info dict; ``bound`` is the input's Imin (H, W, 3)."""
    opt = plan.opt
    h, w = plan.shape
    # 5. diffuse: representation 1, mean over angles, back to the input's illuminant; with the
    # option, at most the input's Imin (unpolarized light passes every polarizer angle)
    diffuse = diffuse_w * scale * (3.0 * gam)
    upper = np.maximum(bound, 0.0)
    above = diffuse > upper
    diffuse = np.clip(diffuse, 0.0, upper) if opt["imin_bound"] else np.maximum(diffuse, 0.0)
    slowest = max(records, key=lambda r: r["iterations"])
    counts: dict[str, int] = {}
    for rec in records:
        for k, v in rec.get("svt_counts", {}).items():
            counts[k] = counts.get(k, 0) + v
    info = {
        "variant": plan.variant,
        "options": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in opt.items()},
        "solver": opt["solver"],
        "device": opt["device"],
        "tol": plan.tol,
        "illuminant_chromaticity": gam.tolist(),
        "lambda": lam_t if len(records) == 1 else [lam_t] * len(records),
        "gamma": plan.gamma,
        "representations_filled": filled,
        "tensor_shape": [4 * h, 3 * w, opt["n4"]],
        "tile": None if plan.one_tile else [plan.tile[0], plan.tile[1], plan.overlap],
        "tiles": len(records),
        "timings": timings,
        "iterations": slowest["iterations"],
        "converged": all(r["converged"] for r in records),
        "residual": max(r["residual"] for r in records),
        "residuals": slowest["residuals"],
        "final_ranks": slowest["ranks"][-1] if slowest["ranks"] else [],
        "svt_counts": counts,
        "above_imin": float(above.mean()),
        "clipped_to_imin": float(above.mean()) if opt["imin_bound"] else 0.0,
    }
    if len(records) > 1:
        info["iterations_per_tile"] = [r["iterations"] for r in records]
    return diffuse, info


def warm_up(device: str) -> None:
    """Run a small separation on ``device`` so that a timed run that follows excludes the one-off start.

    The first call on a GPU creates the CUDA context and the cuSOLVER handle
    and loads kernels (about a second); a camera pipeline pays that once.
    """
    rng = np.random.default_rng(0)
    separate_tensor(rng.uniform(0.1, 0.6, (4, 100, 70, 3)), device=device, tile=(96, 32))
