"""The blocked IALM iterations of wen21's solver (polcam.separation._rpca)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from itertools import pairwise

import numpy as np
import pytest

from polcam.separation import _kernels, _rpca
from polcam.separation._rpca import rpca_direction_t, rpca_ialm


def _problem(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A (3, n) dichromatic matrix: diffuse of rank 1 plus sparse specular along g."""
    rng = np.random.default_rng(seed)
    g = np.array([0.9, 1.0, 1.1])
    diffuse = np.outer([0.7, 0.4, 0.2], rng.uniform(0.1, 0.8, n))
    spec = np.where(rng.random(n) < 0.1, rng.uniform(0.1, 0.5, n), 0.0)
    m = diffuse + np.outer(g, spec) + rng.normal(0, 1e-3, (3, n))
    m = np.ascontiguousarray(np.clip(m, 0, None))
    lower = np.ascontiguousarray(0.2 * np.outer(g, spec))
    prior = np.ascontiguousarray(np.minimum(2 * lower, m))
    return m, lower, prior, g


@pytest.mark.parametrize("parts", [2, 3, 5])
def test_blocks_on_threads_give_the_serial_result_bit_for_bit(monkeypatch, parts):
    monkeypatch.setattr(_rpca, "_IALM_BLOCK", 256)  # 1000 pixels: 4 blocks, unevenly split
    m, lower, prior, g = _problem(1000)
    kw = {"lam": 1 / np.sqrt(1000), "beta": 0.5, "tol": 1e-9, "max_iter": 60}
    serial, its, conv = rpca_direction_t(m, lower, prior, g, **kw)
    with ThreadPoolExecutor(max_workers=2) as pool:
        threaded, its_t, conv_t = rpca_direction_t(m, lower, prior, g, pool=pool, parts=parts, **kw)
    assert its == its_t and conv == conv_t and its > 5
    np.testing.assert_array_equal(threaded, serial)


def test_blocked_solver_matches_the_general_one(monkeypatch):
    """The transposed, blocked path solves the same problem as rpca_ialm's general loop."""
    monkeypatch.setattr(_rpca, "_IALM_BLOCK", 256)
    m, lower, prior, g = _problem(1000, seed=1)
    kw = {"lam": 1 / np.sqrt(1000), "beta": 0.5, "tol": 1e-9, "max_iter": 200}
    with ThreadPoolExecutor(max_workers=2) as pool:
        sp, _, conv = rpca_direction_t(m, lower, prior, g, pool=pool, parts=2, **kw)
    ref = rpca_ialm(m.T, lower=lower.T, upper=m.T, direction=g, prior=prior.T, **kw)
    assert conv and ref.converged
    np.testing.assert_allclose(sp, ref.sparse.T, atol=1e-7)


def _reference_pass(x, y, sc, g, s_lo, s_hi, p, proj, coef, edges):
    """One iteration of the direction-constrained IALM in whole-array numpy (the kernel's spec)."""
    inv, c1, c2, t, mu, inv_next, _, _ = coef
    arg = x - np.outer(g, sc) + y * inv
    low = proj @ arg
    d = x - low
    v = (d + y * inv) * c1 + p * c2
    sc = np.clip((g @ v - t * g.sum()) / (g @ g), s_lo, s_hi)
    r = d - np.outer(g, sc)
    y = y + mu * r
    nxt = y * inv_next + x - np.outer(g, sc)
    grams = np.stack([nxt[:, a:b] @ nxt[:, a:b].T for a, b in pairwise(edges)])
    rrs = np.array([np.sum(r[:, a:b] ** 2) for a, b in pairwise(edges)])
    return low, sc, y, grams, rrs


@pytest.mark.parametrize("use_p", [True, False])
def test_compiled_pass_matches_a_numpy_iteration(use_p):
    rng = np.random.default_rng(3)
    n = 1000
    x, y, p = rng.uniform(0, 1, (3, 3, n))
    y *= 0.3
    sc = rng.uniform(0, 0.4, n)
    g = np.array([0.8, 1.0, 1.2])
    s_lo = rng.uniform(0, 0.8, n)
    s_hi = s_lo + rng.uniform(0, 0.3, n)  # some clipped below, some above
    a = rng.normal(size=(3, 3))
    proj = a @ a.T / 4
    mu = 1.7
    coef = np.array([1 / mu, 0.8, 0.2, 0.05, mu, 1 / (1.5 * mu), g.sum(), g @ g])
    if not use_p:
        coef[2] = 0.0  # the kernel skips p; the reference adds p * 0
    edges = np.array([0, 256, 512, 700, 1000])
    ref = _reference_pass(x, y, sc, g, s_lo, s_hi, p, proj, coef, edges)
    low = np.empty_like(x)
    grams, rrs = np.empty((4, 3, 3)), np.empty(4)
    y0, sc0 = y.copy(), sc.copy()
    _kernels.ialm_pass(x, y, sc, low, g, s_lo, s_hi, p, use_p, proj, edges, coef, grams, rrs)
    # without the low-rank part (a (3, 0) array): the same update of everything else
    y2, sc2, grams2, rrs2 = y0.copy(), sc0.copy(), np.empty((4, 3, 3)), np.empty(4)
    _kernels.ialm_pass(x, y2, sc2, np.empty((3, 0)), g, s_lo, s_hi, p, use_p, proj, edges, coef, grams2, rrs2)
    for a, b in ((y2, y), (sc2, sc), (grams2, grams), (rrs2, rrs)):
        np.testing.assert_array_equal(a, b)
    for got, want in zip((low, sc, y, grams, rrs), ref):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
    clipped = (ref[1] == s_lo).sum(), (ref[1] == s_hi).sum()
    assert min(clipped) > 10  # both bounds were exercised


def test_solver_caches_outside_an_unwritable_package_without_warnings(tmp_path):
    """numba caches the kernel elsewhere when the package's __pycache__ cannot be made.

    A file named ``__pycache__`` stands in for a read-only install (chmod does not stop root).
    """
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    import polcam

    pkg = tmp_path / "site" / "polcam"
    shutil.copytree(Path(polcam.__file__).parent, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    (pkg / "separation" / "__pycache__").write_text("not a directory")
    code = ("import numpy as np; from polcam.separation._rpca import rpca_direction_t; "
            "x = np.random.default_rng(0).uniform(0.1, 1, (3, 50)); "
            "sp, it, ok = rpca_direction_t(x, 0 * x, x / 2, np.ones(3), lam=0.1, beta=0.5, "
            "tol=1e-9, max_iter=50); print(it, bool(np.isfinite(sp).all()))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(PYTHONPATH=str(tmp_path / "site"), HOME=str(tmp_path), PYTHONDONTWRITEBYTECODE="1",
               XDG_CACHE_HOME=str(tmp_path / "cache"))
    for _ in range(2):  # compiles and stores, then loads
        out = subprocess.run([sys.executable, "-W", "error", "-c", code], check=False, env=env, capture_output=True,
                             text=True, timeout=120, cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        assert out.stderr == ""
        its, finite = out.stdout.split()
        assert finite == "True" and int(its) > 1
    assert list((tmp_path / "cache").rglob("*ialm_pass*.nbi"))
