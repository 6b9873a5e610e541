"""The PyTorch backend: device checks (with or without torch) and its batched t-SVT."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.separation.tensor import torch_backend


def test_torch_device_errors():
    if not torch_backend.available():
        with pytest.raises(MethodError, match="PyTorch"):
            torch_backend.check_device("cpu")
        return
    with pytest.raises(MethodError, match="not a torch device"):
        torch_backend.check_device("nonsense")
    torch_backend.check_device("cpu")


def test_gram_tsvt_is_the_exact_tsvt():
    torch = pytest.importorskip("torch")
    from polcam.separation._tsvt import tsvt

    rng = np.random.default_rng(16)
    for n4, k, m in [(4, 20, 15), (3, 12, 30)]:
        z = rng.normal(size=(2, n4, k, m))
        t = np.array([0.7, 3.0])
        op = torch_backend.make_tsvt("fast", n4=n4, batch=2, dtype=torch.float64)
        got, ranks = op(torch.as_tensor(z), t)
        for b in range(2):
            want, r = tsvt(np.moveaxis(z[b], 0, 2), t[b], solver="exact")
            np.testing.assert_allclose(got[b].numpy(), np.moveaxis(want, 2, 0), atol=1e-9)
            assert ranks[b] == r
    norms = torch_backend.spectral_norms(torch.as_tensor(z))
    from polcam.separation.tensor.numpy_backend import spectral_norms

    np.testing.assert_allclose(norms, spectral_norms(z), rtol=1e-9)
    with pytest.raises(MethodError, match="fast solver"):
        torch_backend.make_tsvt("exact", n4=3, batch=1, dtype=torch.float64)
