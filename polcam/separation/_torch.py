"""Optional PyTorch backend of the fast tensor solver (``device="cpu"``, ``"cuda"``, ...).

Install with the ``torch`` extra (``pip install polcam[torch]``, pinned to
``torch==2.13.0``: an unpinned install pulls a multi-GB CUDA build).  Chosen at
run time by the ``device`` option of the tensor methods; numpy stays the
default backend and the reference of this one.

:func:`ialm_tensors` runs the IALM of :func:`polcam.separation.tensor.ialm_fast`
(the same scaled form) on a batch of equally sized tiles at once (one tensor
problem per tile, each with its own mu, threshold, residual and stopping
iteration; a tile that stops leaves the batch), which is what a GPU needs to be
busy; :func:`ialm_batch` is its numpy-in, numpy-out form.  The t-SVT of every
Fourier slice is computed from all eigenpairs of its Gram matrix, one batched
decomposition per slice (:func:`polcam.separation._cusolver.eigh`: cuSOLVER's
batched solver on CUDA, ``torch.linalg.eigh`` elsewhere), the same operator as
the numpy solver's full path; the phase projection is
:func:`polcam.separation.tensor.phase_project_slices` in torch.  The steps
before and after the IALM run on the device too
(:mod:`polcam.separation._torch_prep`, driven by
``polcam.separation.tensor._separate_device``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam.errors import MethodError
from polcam.separation import _cusolver
from polcam.separation._tsvt import packed_dft

__all__ = ["available", "check_device", "ialm_batch", "ialm_tensors", "phase_project_batch", "warm_up"]


def available() -> bool:
    """True if PyTorch can be imported."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def check_device(device: str) -> None:
    """Raise :class:`~polcam.errors.MethodError` unless ``device`` can run the backend."""
    try:
        import torch
    except ImportError:
        raise MethodError(
            f"device {device!r} needs PyTorch, which is not installed: "
            "pip install 'polcam[torch]' (torch==2.13.0), or leave device=None for numpy"
        ) from None
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise MethodError(f"device {device!r}: not a torch device name ({exc})") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise MethodError(f"device {device!r}: PyTorch sees no CUDA GPU on this machine")


def warm_up(device: str) -> None:
    """Run a small separation on ``device`` so that a timed run that follows excludes the one-off start.

    The first call on a GPU creates the CUDA context and the cuSOLVER handle
    and loads kernels (about a second); a camera pipeline pays that once.
    """
    from polcam.separation import separate

    rng = np.random.default_rng(0)
    stack = rng.uniform(0.1, 0.6, (4, 100, 70, 3))
    separate(stack, method="tensor", device=device, tile=(96, 32))


def phase_project_batch(z: Any, n1: int, n2: int) -> Any:
    """Phase projection of slice-first tensors (B, n4, 4 n1, 3 n2), in torch.

    The operator of :func:`polcam.separation.tensor.phase_project_slices`.
    """
    import torch

    b, n4 = z.shape[:2]
    v = z.reshape(b, n4, 4, n1, 3, n2)
    s0h = 0.25 * v.sum(dim=2)
    s1 = v[:, :, 0] - v[:, :, 2]
    s2 = v[:, :, 1] - v[:, :, 3]
    amp = torch.hypot(s1, s2)
    pos = amp > 0
    inv = torch.where(pos, 1.0 / torch.where(pos, amp, torch.ones_like(amp)), torch.zeros_like(amp))
    c = (s1 * inv).sum(dim=3, keepdim=True)
    s = (s2 * inv).sum(dim=3, keepdim=True)
    nz = torch.hypot(c, s)
    ok = nz > 0
    safe = torch.where(ok, nz, torch.ones_like(nz))
    c = torch.where(ok, c / safe, torch.ones_like(c))
    s = torch.where(ok, s / safe, torch.zeros_like(s))
    isv = 0.5 * amp
    ac, as_ = isv * c, isv * s
    out = torch.stack([s0h + ac, s0h + as_, s0h - ac, s0h - as_], dim=2)
    return out.reshape(z.shape)


def _svt_gram(a: Any, t: Any) -> tuple[Any, Any]:
    """Batched SVT of matrices a (B, k, m) at thresholds t (B,), from the Gram matrices' eigenpairs."""
    import torch

    tall = a.shape[-2] >= a.shape[-1]
    b = a if tall else a.mH
    g = b.mH @ b
    lam, v = _cusolver.eigh(g)
    lam = lam.clamp_min(0)
    t2 = (t * t)[:, None]
    keep = lam > t2
    s = torch.sqrt(torch.where(keep, lam, torch.ones_like(lam)))
    f = torch.where(keep, 1.0 - t[:, None] / s, torch.zeros_like(s)).to(b.real.dtype)
    x = ((b @ v) * f[:, None, :].to(b.dtype)) @ v.mH
    return (x if tall else x.mH), keep.sum(dim=-1)


def ialm_batch(D: np.ndarray, *, tau: np.ndarray | None, lam: float | np.ndarray, gamma: float,
               shape: tuple[int, int], device: str, rho: float = 1.5, mu0: float | None = None,
               mu_max: float = 1e7, tol: float = 1e-5, max_iter: int = 200,
               dtype: str = "float32") -> tuple[np.ndarray, list[dict[str, Any]]]:
    """IALM of a batch of slice-first tile tensors, in PyTorch.

    Parameters
    ----------
    D
        (B, n4, k, m) data tensors, or one (n4, k, m) tensor.
    tau
        Weights broadcastable to D (e.g. (B, 1, k, m)), or None for 1.
    lam
        Sparse weight, one for all or (B,) per tile.
    gamma
        Phase weight (gamma_t = gamma mu_t); 0 skips the phase term.
    shape
        (n1, n2), the tiles' height and width (k = 4 n1, m = 3 n2).
    device
        A torch device name.
    rho, mu0, mu_max, tol, max_iter
        As :func:`polcam.separation.tensor.ialm` (mu0 None: 1.25 / ||D_b||_2 per tile).
    dtype
        ``"float32"`` or ``"float64"``.

    Returns
    -------
    L : numpy.ndarray
        Same shape as D, float32 or float64.
    records : list of dict
        Per tile: iterations, converged, residual, residuals, ranks, mu0.
    """
    import torch

    single = D.ndim == 3
    Dn = D[None] if single else D
    tdt = {"float32": torch.float32, "float64": torch.float64}[dtype]
    dev = torch.device(device)
    Dt = torch.as_tensor(np.ascontiguousarray(Dn), device=dev).to(tdt)
    Wt = None if tau is None else torch.as_tensor(np.ascontiguousarray(tau), device=dev).to(tdt)
    L, records = ialm_tensors(Dt, tau=Wt, lam=lam, gamma=gamma, shape=shape, rho=rho, mu0=mu0,
                              mu_max=mu_max, tol=tol, max_iter=max_iter)
    out = L.cpu().numpy()
    return (out[0] if single else out), records


def ialm_tensors(Dt: Any, *, tau: Any, lam: float | np.ndarray, gamma: float, shape: tuple[int, int],
                 rho: float = 1.5, mu0: float | None = None, mu_max: float = 1e7, tol: float = 1e-5,
                 max_iter: int = 200) -> tuple[Any, list[dict[str, Any]]]:
    """:func:`ialm_batch` on torch tensors: Dt (B, n4, k, m), tau (B or 1, 1, k, m) or None.

    The iteration of :func:`polcam.separation.tensor.ialm_fast` in its scaled
    form (P = Y / mu), per tile, with every t-SVT of the batch in one batched
    eigendecomposition per Fourier slice.  A tile leaves the batch when it
    stops, so the work shrinks as tiles converge.

    Returns L, a tensor like Dt, and the per-tile records.
    """
    import torch

    dev, tdt = Dt.device, Dt.dtype
    B, n4, k, m = Dt.shape
    n1, n2 = shape
    f, finv, slices = packed_dft(n4)
    F = torch.as_tensor(f, device=dev, dtype=tdt)
    Finv = torch.as_tensor(finv, device=dev, dtype=tdt)

    def mix(mat: Any, x: Any) -> Any:         # (n4, n4) along the second axis, one pass
        return (mat @ x.reshape(x.shape[0], n4, k * m)).reshape(x.shape)

    def slice_of(z: Any, rows: tuple[int, ...]) -> Any:
        return z[:, rows[0]] if len(rows) == 1 else torch.complex(z[:, rows[0]], z[:, rows[1]])

    def col(x: Any) -> Any:                   # per-tile scalars broadcast over a tile
        return x.to(tdt)[:, None, None, None]

    norm_d = torch.linalg.vector_norm(Dt.reshape(B, -1), dim=1).to(torch.float64)
    if mu0 is None:
        zd = mix(F, Dt)
        spec = torch.zeros(B, dtype=torch.float64, device=dev)
        for rows in slices:
            a = slice_of(zd, rows)
            b = a if k >= m else a.mH
            top = _cusolver.eigh(b.mH @ b, vectors=False)[0][:, -1].clamp_min(0).sqrt().to(torch.float64)
            spec = torch.maximum(spec, top)
        del zd
        mu = torch.where(spec > 0, 1.25 / torch.where(spec > 0, spec, torch.ones_like(spec)),
                         torch.ones_like(spec))
    else:
        mu = torch.full((B,), float(mu0), dtype=torch.float64, device=dev)
    mu_start = mu.tolist()
    mu_cap = mu * mu_max
    lam_t = torch.as_tensor(np.broadcast_to(np.asarray(lam, dtype=np.float64), (B,)).copy(), device=dev)
    W = (torch.ones((1, 1, k, m), device=dev, dtype=tdt) if tau is None else tau.to(tdt))
    W = (W * lam_t.to(tdt)[:, None, None, None]).expand(B, 1, k, m)
    c1, c2 = 1.0 / (1.0 + 2.0 * gamma), 2.0 * gamma / (1.0 + 2.0 * gamma)

    out = torch.zeros_like(Dt)
    iterations = [0] * B
    converged = [True] * B
    residuals: list[list[float]] = [[] for _ in range(B)]
    ranks: list[list[list[int]]] = [[] for _ in range(B)]
    ids = torch.nonzero(norm_d > 0).reshape(-1)
    for i in ids.tolist():
        converged[i] = False
    D, Wp, mu, mu_cap, nd = Dt[ids], W[ids], mu[ids], mu_cap[ids], norm_d[ids]
    Wn = -Wp
    L = torch.zeros_like(D)
    P = torch.zeros_like(D)
    E = D.clone()
    Q = phase_project_batch(D, n1, n2) if gamma > 0 else None
    id_list = ids.tolist()
    for it in range(1, max_iter + 1):
        if not id_list:
            break
        T = torch.add(E.mul(c1), Q, alpha=c2) if Q is not None else E
        Z = mix(F, T)
        del T
        t = (1.0 / (mu * (1.0 + 2.0 * gamma))).to(tdt)
        Zr = torch.empty_like(Z)
        rk = []
        for rows in slices:
            x, r = _svt_gram(slice_of(Z, rows), t)
            if len(rows) == 1:
                Zr[:, rows[0]] = x
            else:
                Zr[:, rows[0]] = x.real
                Zr[:, rows[1]] = x.imag
            rk.append(r.to(torch.float64))
        del Z, x
        L = mix(Finv, Zr)
        del Zr
        V = torch.sub(D, L).add_(P)                         # V = D - L + P
        C = V.mul_(col(mu))                                 # mu C = clip(mu V, -w, w), in V's memory
        torch.maximum(C, Wn, out=C)
        torch.minimum(C, Wp, out=C)
        R = torch.mul(C, col(1.0 / mu)).sub_(P)            # R = C - P = D - L - S
        res = torch.linalg.vector_norm(R.reshape(R.shape[0], -1), dim=1).to(torch.float64) / nd
        stats = torch.cat([res[:, None], torch.stack(rk, dim=1)], dim=1).tolist()
        done = []
        for j, i in enumerate(id_list):
            iterations[i] = it
            residuals[i].append(stats[j][0])
            ranks[i].append([int(v) for v in stats[j][1:]])
            if stats[j][0] < tol:
                converged[i] = True
                done.append(j)
            elif it == max_iter:
                done.append(j)
        if done:
            jd = torch.tensor(done, device=dev)
            out[torch.tensor([id_list[j] for j in done], device=dev)] = L[jd]
            keep = [j for j in range(len(id_list)) if j not in set(done)]
            if not keep:
                break
            jk = torch.tensor(keep, device=dev)
            D, Wp, Wn, mu, mu_cap, nd = D[jk], Wp[jk], Wn[jk], mu[jk], mu_cap[jk], nd[jk]
            L, P, C, R = L[jk], P[jk], C[jk], R[jk]
            id_list = [id_list[j] for j in keep]
        mu_next = torch.minimum(rho * mu, mu_cap)
        P = C.mul_(col(1.0 / mu_next))                      # P_new = mu C / mu_next, in C's memory
        E = torch.add(L, R).add_(P)                         # E = L + (C - P) + P_new
        del R
        if gamma > 0:
            Q = phase_project_batch(L, n1, n2)
        mu = mu_next
    records = [{"iterations": iterations[i], "converged": converged[i],
                "residual": residuals[i][-1] if residuals[i] else 0.0, "residuals": residuals[i],
                "ranks": ranks[i], "mu0": mu_start[i]} for i in range(B)]
    return out, records
