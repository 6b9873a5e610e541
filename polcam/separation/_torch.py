"""Optional PyTorch backend of the fast tensor solver (``device="cpu"``, ``"cuda"``, ...).

Install with the ``torch`` extra (``pip install polcam[torch]``, pinned to
``torch==2.13.0``: an unpinned install pulls a multi-GB CUDA build).  Chosen at
run time by the ``device`` option of the tensor methods; numpy stays the
default backend and the reference of this one.

:func:`ialm_batch` runs the IALM of :func:`polcam.separation.tensor.ialm_fast`
on a batch of equally sized tiles at once (one tensor problem per tile, each
with its own mu, threshold, residual and stopping iteration), which is what a
GPU needs to be busy.  The t-SVT of every Fourier slice is computed from the
eigenpairs of its Gram matrix (``torch.linalg.eigh``, batched over the tiles),
the same operator as the numpy solver's full path; the phase projection is
:func:`polcam.separation.tensor.phase_project_slices` in torch.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam.errors import MethodError
from polcam.separation._tsvt import packed_dft

__all__ = ["available", "check_device", "ialm_batch", "phase_project_batch"]


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
    lam, v = torch.linalg.eigh(g)
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
    B, n4, k, m = Dt.shape
    n1, n2 = shape
    f, finv, slices = packed_dft(n4)
    F = torch.as_tensor(f, device=dev, dtype=tdt)
    Finv = torch.as_tensor(finv, device=dev, dtype=tdt)

    def forward(x: Any) -> Any:
        return torch.einsum("ij,bjkm->bikm", F, x)

    def inverse(z: Any) -> Any:
        return torch.einsum("ij,bjkm->bikm", Finv, z)

    def slice_of(z: Any, rows: tuple[int, ...]) -> Any:
        return z[:, rows[0]] if len(rows) == 1 else torch.complex(z[:, rows[0]], z[:, rows[1]])

    norm_d = torch.linalg.vector_norm(Dt.reshape(B, -1), dim=1).to(torch.float64)
    if mu0 is None:
        zd = forward(Dt)
        spec = torch.zeros(B, dtype=torch.float64, device=dev)
        for rows in slices:
            a = slice_of(zd, rows)
            b = a if k >= m else a.mH
            top = torch.linalg.eigvalsh(b.mH @ b)[:, -1].clamp_min(0).sqrt().to(torch.float64)
            spec = torch.maximum(spec, top)
        mu = torch.where(spec > 0, 1.25 / torch.where(spec > 0, spec, torch.ones_like(spec)),
                         torch.ones_like(spec))
    else:
        mu = torch.full((B,), float(mu0), dtype=torch.float64, device=dev)
    mu_start = mu.clone()
    mu_cap = mu * mu_max
    lam_t = torch.as_tensor(np.broadcast_to(np.asarray(lam, dtype=np.float64), (B,)).copy(), device=dev)
    W = (torch.ones((1, 1, k, m), device=dev, dtype=tdt) if tau is None
         else torch.as_tensor(np.ascontiguousarray(tau), device=dev).to(tdt))
    if W.ndim == 3:
        W = W[None]
    W = W * lam_t.to(tdt)[:, None, None, None]

    def project(x: Any) -> Any:
        return phase_project_batch(x, n1, n2)

    L = torch.zeros_like(Dt)
    S = torch.zeros_like(Dt)
    Y = torch.zeros_like(Dt)
    Q = project(Dt) if gamma > 0 else None
    active = norm_d > 0
    iterations = [0] * B
    converged = [not bool(a) for a in active.tolist()]
    residuals: list[list[float]] = [[] for _ in range(B)]
    ranks: list[list[list[int]]] = [[] for _ in range(B)]

    def col(x: Any) -> Any:
        return x.to(tdt)[:, None, None, None]

    for it in range(1, max_iter + 1):
        if not bool(active.any()):
            break
        g = gamma * mu
        den = 2 * g + mu
        target = (col(mu / den) * (Dt - S) + col(1.0 / den) * Y
                  + (col(2 * g / den) * Q if gamma > 0 else 0.0))
        z = forward(target)
        t = (1.0 / den).to(tdt)
        zr = torch.empty_like(z)
        rk = []
        for rows in slices:
            x, r = _svt_gram(slice_of(z, rows), t)
            if len(rows) == 1:
                zr[:, rows[0]] = x
            else:
                zr[:, rows[0]] = x.real
                zr[:, rows[1]] = x.imag
            rk.append(r)
        L_new = inverse(zr)
        V = Dt - L_new + col(1.0 / mu) * Y
        thr = W * col(1.0 / mu)
        S_new = V - torch.maximum(torch.minimum(V, thr), -thr)
        rt = Dt - L_new - S_new
        Y_new = Y + col(mu) * rt
        res = (torch.linalg.vector_norm(rt.reshape(B, -1), dim=1).to(torch.float64)
               / torch.where(norm_d > 0, norm_d, torch.ones_like(norm_d)))
        a4 = active[:, None, None, None]
        L = torch.where(a4, L_new, L)
        S = torch.where(a4, S_new, S)
        Y = torch.where(a4, Y_new, Y)
        if gamma > 0:
            Q = torch.where(a4, project(L), Q)
        res_l = res.tolist()
        rk_l = torch.stack(rk, dim=1).tolist()
        for i, on in enumerate(active.tolist()):
            if on:
                iterations[i] = it
                residuals[i].append(res_l[i])
                ranks[i].append([int(v) for v in rk_l[i]])
                if res_l[i] < tol:
                    converged[i] = True
        done = torch.as_tensor(converged, device=dev)
        active = active & ~done
        mu = torch.where(active, torch.minimum(rho * mu, mu_cap), mu)
    out = L.cpu().numpy()
    records = [{"iterations": iterations[i], "converged": converged[i],
                "residual": residuals[i][-1] if residuals[i] else 0.0, "residuals": residuals[i],
                "ranks": ranks[i], "mu0": float(mu_start[i])} for i in range(B)]
    return (out[0] if single else out), records
