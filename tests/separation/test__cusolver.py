"""The batched CUDA eigensolver: the torch fallback on the CPU, cuSOLVER's batched call on a GPU."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from polcam.separation import _cusolver  # noqa: E402


def _hermitian(b: int, n: int, dtype, device: str):
    g = torch.Generator().manual_seed(n)
    a = torch.randn(b, 2 * n, n, dtype=dtype, generator=g)
    a[:, :, n // 2:] *= 1e-2                     # a spread of eigenvalues, as a Gram matrix has
    return (a.mH @ a).to(device)


def _check(g, w, v, rtol):
    assert w.shape == g.shape[:2] and v.shape == g.shape
    assert torch.all(w[:, 1:] >= w[:, :-1])                  # ascending
    rec = (v * w.to(v.dtype)[:, None, :]) @ v.mH
    scale = g.abs().amax(dim=(-1, -2), keepdim=True).clamp_min(1.0)
    assert float(((rec - g).abs() / scale).max()) < rtol
    eye = torch.eye(g.shape[-1], dtype=v.dtype, device=v.device)
    assert float((v.mH @ v - eye).abs().max()) < rtol
    ref = torch.linalg.eigvalsh(g.cpu().to(torch.complex128 if g.is_complex() else torch.float64))
    np.testing.assert_allclose(w.cpu().double().numpy(), ref.numpy(), atol=rtol * float(ref.abs().max()))


@pytest.mark.parametrize("dtype", [torch.float64, torch.complex64])
def test_cpu_tensors_use_torch(dtype):
    g = _hermitian(3, 7, dtype, "cpu")
    w, v = _cusolver.eigh(g)
    _check(g, w, v, 1e-5)
    w2, none = _cusolver.eigh(g, vectors=False)
    assert none is None
    torch.testing.assert_close(w2, w)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("dtype,rtol", [(torch.float32, 2e-5), (torch.complex64, 2e-5),
                                        (torch.float64, 1e-12), (torch.complex128, 1e-12)])
@pytest.mark.parametrize("n", [5, 40, 96, 300])
def test_cuda_batched_eigh(dtype, rtol, n):
    assert _cusolver.available()
    g = _hermitian(37, n, dtype, "cuda")
    w, v = _cusolver.eigh(g)
    # a backward-stable eigensolver's error grows like n eps (above BATCHED_MAX_N this is
    # PyTorch's own path: in float32 at n = 300 it exceeded 2e-5 of ||G|| on an H100)
    rtol = max(rtol, 4 * n * torch.finfo(w.dtype).eps)
    _check(g, w, v, rtol)
    w2, _ = _cusolver.eigh(g, vectors=False)
    torch.testing.assert_close(w2, w, rtol=rtol, atol=rtol * float(w.abs().max()))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("dtype", [torch.float32, torch.complex64])
def test_cuda_zero_and_diagonal_matrices_in_a_batch(dtype):
    # identical representations make whole Fourier slices zero: their Gram matrices are 0
    g = _hermitian(6, 33, dtype, "cuda")
    g[[1, 4]] = 0
    g[2] = torch.diag_embed(torch.linspace(3, -1, 33, device="cuda")).to(dtype)
    before = _cusolver.fallbacks
    w, v = _cusolver.eigh(g)
    assert torch.all(w[[1, 4]] == 0)
    _check(g, w, v, 2e-5)
    assert _cusolver.fallbacks == before          # solved directly, not by the retry


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_failed_results_are_decomposed_again(monkeypatch):
    # a result that fails the check (here: every matrix, by a tolerance no result meets)
    g = _hermitian(4, 20, torch.complex64, "cuda")
    monkeypatch.setattr(_cusolver, "CHECK_TOL", (-1.0, -1.0))
    before = _cusolver.fallbacks
    w, v = _cusolver.eigh(g)
    assert _cusolver.fallbacks == before + 4
    _check(g, w, v, 1e-5)


@pytest.mark.parametrize("dtype", [torch.float32, torch.complex64])
def test_repair_fills_diagonal_slots_and_redoes_failed_results(dtype):
    # what eigh does after the batched call, on results made here: slot 1 is diagonal (a
    # stand-in was decomposed there), slot 2 came back with NaN vectors and a success code,
    # slot 3 with a failure code
    g = _hermitian(5, 12, dtype, "cpu")
    g[1] = torch.diag_embed(torch.tensor([2.0, -1, 0, 5, 3, 3, 1, 0, 0, 4, -2, 7])).to(dtype)
    plain = torch.tensor([False, True, False, False, False])
    a = torch.where(plain[:, None, None], _cusolver._stand_in(12, g), g)
    w, v = torch.linalg.eigh(a)
    v = v.clone()
    v[2, 3, 4] = float("nan")
    info = torch.tensor([0, 0, 0, 7, 0], dtype=torch.int32)
    before = _cusolver.fallbacks
    w2, v2 = _cusolver._repair(g, plain, w.clone(), v, info)
    assert _cusolver.fallbacks == before + 2          # slots 2 and 3, not the diagonal one
    _check(g, w2, v2, 1e-5)
    wo, none = _cusolver._repair(g, plain, w.clone(), None, info)
    assert none is None and _cusolver.fallbacks == before + 3   # without vectors: slot 3 only
    torch.testing.assert_close(wo, w2, rtol=1e-5, atol=1e-5 * float(w2.abs().max()))
