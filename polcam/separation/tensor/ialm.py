"""The inexact ALM of the tensor problem: one loop for every backend and t-SVT.

Solves, per tensor (a batch of independent problems at once)::

    min ||L||_* + lam ||tau (.) S||_1 + gamma_t ||Q(L) - L||_F^2   s.t.  D = L + S

(paper eq. 4; eq. 10 with gamma = 0, eq. 11 with tau = 1 as well), ``||.||_*``
the tensor nuclear norm of :mod:`polcam.separation._tsvt`, Q the phase
projection (:func:`polcam.separation.tensor.operators.phase_project`).  The
loop is written over the array namespace (:mod:`polcam._xp`); a backend supplies only
the t-SVT, the spectral norm that sets mu0, and how element-wise updates are
split among threads (:mod:`.numpy_backend`, :mod:`.torch_backend`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from polcam._xp import namespace
from polcam.separation.tensor import numpy_backend, torch_backend
from polcam.separation.tensor.operators import fold, phase_project

__all__ = ["ialm", "solve_tiles", "backend_for"]


def backend_for(a: Any) -> Any:
    """The backend of an array: :mod:`.numpy_backend` for numpy, :mod:`.torch_backend` for a tensor."""
    if namespace(a).name == "numpy":
        return numpy_backend

    return torch_backend


def ialm(D: Any, *, tau: Any, lam: float | np.ndarray, gamma: float,
         project: Callable[..., Any] | None = None, chunked_project: bool = False, rho: float = 1.5,
         mu0: float | None = None, mu_max: float = 1e7, tol: float = 1e-5, max_iter: int = 200,
         solver: str = "exact", dtype: Any = None, threads: int = 1,
         svt_options: dict[str, Any] | None = None) -> tuple[Any, Any, list[dict[str, Any]] | dict[str, Any]]:
    """Inexact ALM for ``min ||L||_* + lam ||tau (.) S||_1 + gamma_t ||Q(L) - L||^2, D = L + S``.

    Updates per iteration t (mu_t grows by ``rho`` up to ``mu_max * mu0``,
    gamma_t = gamma * mu_t), as in Lin, Chen & Ma's inexact ALM:

    * ``L = tsvt((2 gamma_t Q + mu_t (D - S) + Y) / (2 gamma_t + mu_t), 1 / (2 gamma_t + mu_t))``
      (the minimiser of the L-terms; the paper's eq. 6 swaps the weights of Q
      and D - S);
    * ``S = soft(D - L + Y / mu_t, lam tau / mu_t)``;
    * ``Q = project(L)`` (skipped when ``gamma == 0``);
    * ``Y = Y + mu_t (D - L - S)``;

    stopping when ``||D - L - S||_F / ||D||_F < tol``.  Computed in the scaled form (Boyd et al.
    2011, section 3.1.1): with ``P = Y / mu`` and ``gamma_t = gamma mu_t`` the target is
    ``c1 E + c2 Q`` with ``E = D - S + P`` and constants ``c1 = 1 / (1 + 2 gamma)``,
    ``c2 = 2 gamma / (1 + 2 gamma)``; ``S = V - C`` and ``P_new = C mu / mu_new`` with
    ``V = D - L + P``, ``C = clip(V, +-lam tau / mu)``; the residual is ``C - P`` and the next
    ``E = L + (C - P) + P_new`` (docs/methods/tensor.md).

    Each problem of a batch has its own mu0, threshold, residual and stopping
    iteration; a problem that stops leaves the batch.

    Parameters
    ----------
    D
        (n4, k, m) data tensor laid out slice-first (frontal slices first,
        :func:`~polcam.separation.tensor.operators.unfold`), or a batch
        (B, n4, k, m); numpy or torch.
    tau
        Positive weights broadcastable to D (e.g. (1, k, m) or (B, 1, k, m)), or None for 1.
    lam
        Weight of the sparse term: one for all, or (B,) per problem.
    gamma
        Weight of the phase term (0 skips it).
    project
        Callable mapping a tensor shaped like D to Phi^-1(Phi(.)); required if
        gamma > 0.  With ``chunked_project`` it must act on each frontal slice
        alone and take ``out=``: it then runs inside the threads' chunks.
    rho, mu0, mu_max, tol, max_iter
        Schedule (mu0 None: 1.25 / ||bcirc(D)||_2 per problem) and stopping rule.
    solver
        The t-SVT: ``"exact"`` (a full SVD of every Fourier slice; numpy only)
        or ``"fast"`` (numpy: :class:`~polcam.separation._tsvt.FastTSVT`; torch:
        all eigenpairs of every slice's Gram matrix, batched).
    dtype
        Working precision (``"float32"`` or ``"float64"``); None: float64 for the
        exact solver, float32 for the fast one.
    threads
        Threads for the element-wise updates and the Fourier slices (numpy).
    svt_options
        Options of the numpy fast t-SVT (:class:`~polcam.separation._tsvt.SliceSVT`).

    Returns
    -------
    L, S : array
        Shaped like D, in the working precision.
    info : dict or list of dict
        Per problem (a list for a batch): iterations, converged, residual
        (final), residuals (per iteration), ranks (per iteration, the kept rank
        of each Fourier slice), mu0, svt_counts (how often each t-SVT path ran;
        numpy's fast solver).
    """
    if gamma > 0 and project is None:
        raise ValueError("gamma > 0 needs a phase projection")
    xp, single = namespace(D), D.ndim == 3
    Dn, tau_n = _working_copy(D, tau, single=single, dtype=dtype, solver=solver)
    norm_d = np.sqrt(xp.sqnorms(Dn))
    out_l, out_s = xp.zeros(Dn.shape, like=Dn), xp.zeros(Dn.shape, like=Dn)
    records = [_empty_record() for _ in range(Dn.shape[0])]
    ids = [i for i in range(Dn.shape[0]) if norm_d[i] > 0]
    if ids:
        _loop(Dn, tau_n, ids, records, out_l, out_s, xp=xp, bk=backend_for(D), lam=lam, gamma=gamma,
              project=project, chunked_project=chunked_project, rho=rho, mu0=mu0, mu_max=mu_max, tol=tol,
              max_iter=max_iter, solver=solver, threads=threads, svt_options=svt_options or {}, norm_d=norm_d)
    return (out_l[0], out_s[0], records[0]) if single else (out_l, out_s, records)


def _working_copy(D: Any, tau: Any, *, single: bool, dtype: Any, solver: str) -> tuple[Any, Any]:
    """D as a batch (B, n4, k, m) copied in the working precision (None: float64 for the exact solver,
    float32 for the fast one), and tau in it."""
    xp = namespace(D)
    name = np.dtype(dtype).name if dtype is not None else ("float64" if solver == "exact" else "float32")
    dt = xp.dtype_of(name)
    Dn = xp.copy(xp.astype(D[None] if single else D, dt))
    tau_n = None if tau is None else xp.astype(tau[None] if single and tau.ndim == 3 else tau, dt)
    return Dn, tau_n


def _empty_record() -> dict[str, Any]:
    """A problem's record before its first iteration (what a zero problem keeps)."""
    return {"iterations": 0, "converged": True, "residual": 0.0, "residuals": [], "ranks": [], "mu0": 0.0,
            "svt_counts": {}}


def _loop(D_all: Any, tau: Any, ids: list[int], records: list[dict[str, Any]], out_l: Any, out_s: Any, *,
          xp: Any, bk: Any, lam: Any, gamma: float, project: Any, chunked_project: bool, rho: float,
          mu0: float | None, mu_max: float, tol: float, max_iter: int, solver: str, threads: int,
          svt_options: dict[str, Any], norm_d: np.ndarray) -> None:
    """The iterations of :func:`ialm` on the problems ``ids`` (non-zero), writing into out_l, out_s."""
    B_all = D_all.shape[0]
    sel = ids if len(ids) < B_all else None
    D = D_all if sel is None else D_all[xp.index_array(sel, like=D_all)]
    B, n4 = D.shape[:2]
    nd = norm_d[ids]
    mu = _initial_mu(bk, D, mu0)
    for j, i in enumerate(ids):
        records[i]["mu0"] = float(mu[j])
    mu_cap = mu * mu_max
    W, Wn = _thresholds(D, tau, lam, ids, sel, B_all)
    c1, c2 = 1.0 / (1.0 + 2.0 * gamma), 2.0 * gamma / (1.0 + 2.0 * gamma)
    svt = bk.make_tsvt(solver, n4=n4, batch=B, dtype=D.dtype, threads=threads, options=svt_options)
    L, P, T, V, R = (xp.zeros(D.shape, like=D) for _ in range(5))
    E = xp.copy(D)
    Q = project(D) if gamma > 0 else None
    live = list(ids)
    with bk.chunks(n4, threads) as each:
        for it in range(1, max_iter + 1):
            if gamma > 0:
                def target(c: Any) -> None:
                    xp.mul(E[c], c1, out=T[c])
                    xp.mul(Q[c], c2, out=V[c])
                    T[c] += V[c]

                each(target)
                L, ranks = svt(T, 1.0 / (mu * (1.0 + 2.0 * gamma)))
            else:
                L, ranks = svt(E, 1.0 / (mu * (1.0 + 2.0 * gamma)))
            mu_c, inv_c = xp.column(mu, like=D), xp.column(1.0 / mu, like=D)

            def update(c: Any) -> np.ndarray:
                v_, t_, r_ = V[c], T[c], R[c]
                xp.sub(D[c], L[c], out=v_)             # V = D - L + P
                v_ += P[c]
                xp.mul(v_, mu_c, out=t_)               # mu C = clip(mu V, -w, w)
                xp.clip(t_, Wn[c], W[c], out=t_)
                xp.mul(t_, inv_c, out=r_)              # R = C - P = D - L - S
                r_ -= P[c]
                return xp.sqnorms(r_)

            res = np.sqrt(sum(each(update))) / nd
            done = _record(records, live, it, res, ranks, tol=tol, max_iter=max_iter)
            if done:
                jd = xp.index_array(done, like=D)
                dst = xp.index_array([live[j] for j in done], like=D)
                out_l[dst] = L[jd]
                out_s[dst] = V[jd] - R[jd] - P[jd]         # S = V - C
                for j in done:
                    records[live[j]]["svt_counts"] = svt.counts(j)
                keep = [j for j in range(len(live)) if j not in set(done)]
                if not keep:
                    break
                jk = xp.index_array(keep, like=D)
                D, W, Wn, L, P, T, V, R = (a[jk] for a in (D, W, Wn, L, P, T, V, R))
                E = xp.copy(E[jk])
                mu, mu_cap, nd = mu[keep], mu_cap[keep], nd[keep]
                svt.keep(keep)
                live = [live[j] for j in keep]
                if Q is not None:
                    Q = Q[jk]
            mu_next = np.minimum(rho * mu, mu_cap)
            scale_c = xp.column(1.0 / mu_next, like=D)

            def advance(c: Any) -> None:
                xp.add(L[c], R[c], out=E[c])           # E = L + (C - P) + P_new
                xp.mul(T[c], scale_c, out=P[c])        # P_new = Y_new / mu_next = mu C / mu_next
                E[c] += P[c]
                if gamma > 0 and chunked_project:
                    project(L[c], out=Q[c])

            each(advance)
            if gamma > 0 and not chunked_project:
                Q = project(L)
            mu = mu_next


def _initial_mu(bk: Any, D: Any, mu0: float | None) -> np.ndarray:
    """mu0 per problem (B,): given, or ``1.25 / ||bcirc(D)||_2`` (Lin, Chen & Ma's choice; 1 for a zero norm)."""
    if mu0 is None:
        spec = bk.spectral_norms(D)
        return np.where(spec > 0, 1.25 / np.where(spec > 0, spec, 1.0), 1.0)
    return np.full(D.shape[0], float(mu0))


def _thresholds(D: Any, tau: Any, lam: Any, ids: list[int], sel: list[int] | None, B_all: int) -> tuple[Any, Any]:
    """``lam tau`` of the problems ``ids``, and its negative, broadcast to D's shape (the S update's clip)."""
    xp = namespace(D)
    k, m = D.shape[2:]
    lam_b = np.broadcast_to(np.asarray(lam, dtype=np.float64), (B_all,))[ids]
    if tau is None:
        W = xp.zeros((1, 1, k, m), like=D) + 1.0
    else:
        W = tau if sel is None or tau.shape[0] == 1 else tau[xp.index_array(sel, like=D)]
    W = W * xp.column(lam_b, like=D)
    return xp.broadcast_to(W, D.shape), xp.broadcast_to(-W, D.shape)


def _record(records: list[dict[str, Any]], live: list[int], it: int, res: np.ndarray, ranks: Any, *,
            tol: float, max_iter: int) -> list[int]:
    """Append iteration ``it``'s residual and ranks to the live problems' records; the positions that stop."""
    done = []
    for j, i in enumerate(live):
        rec = records[i]
        rec["iterations"] = it
        rec["residuals"].append(float(res[j]))
        rec["ranks"].append([int(r) for r in ranks[j]])
        if res[j] < tol or it == max_iter:
            rec["converged"] = bool(res[j] < tol)
            rec["residual"] = float(res[j])
            done.append(j)
    return done


def solve_tiles(d0: Any, tau: Any, *, n1: int, n2: int, lam: float, gamma: float, opt: dict[str, Any],
                tol: float, threads: int = 1) -> tuple[Any, list[dict[str, Any]]]:
    """The tensor problems of a batch of equally sized tiles: their diffuse layers.

    Parameters
    ----------
    d0
        (B, n4, 4 n1, 3 n2) unfolded initial diffuse of each tile (numpy or torch).
    tau
        (B, 1, 4 n1, 3 n2) weights of the first representation, or None.
    n1, n2
        Tile height and width.
    lam, gamma
        Weights of the sparse and phase terms.
    opt
        The method's options (``rho``, ``mu0``, ``mu_max``, ``max_iter``, ``solver``, ``precision``).
    tol
        Stopping tolerance.
    threads
        Threads of one tile's updates and Fourier slices (numpy).

    Returns
    -------
    diffuse : array
        (B, n1, n2, 3) float64: representation 1 of L, mean over the four angles.
    records : list of dict
        The IALM record of each tile (:func:`ialm`).
    """
    xp = namespace(d0)
    exact = opt["solver"] == "exact"

    def project(t: Any, out: Any = None) -> Any:
        return phase_project(t, n1, n2, out=out)

    L, _S, recs = ialm(d0, tau=tau, lam=lam, gamma=gamma, project=project if gamma > 0 else None,
                       chunked_project=True, rho=opt["rho"], mu0=opt["mu0"], mu_max=opt["mu_max"], tol=tol,
                       max_iter=opt["max_iter"], solver=opt["solver"],
                       dtype="float64" if exact else opt["precision"], threads=threads)
    first = xp.astype(fold(L[:, :1], n1, n2)[:, 0], xp.float64)      # (B, 4, n1, n2, 3)
    return xp.mean(first, axis=1), recs

