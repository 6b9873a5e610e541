"""The polarization that demosaicing draws at intensity edges, fitted and removed from a stack.

Used by ``polarized-residual`` (docs/methods/polarized-residual.md, step 0).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam import _imageops
from polcam._xp import namespace

__all__ = ["without_edge_polarization"]


def without_edge_polarization(stack: Any, *, order: int = 1) -> Any:
    """``stack`` with the part of its Stokes components that the intensity's derivatives explain removed.

    A polarization sensor samples the four angles at four positions of each 2 x 2 cell, so an
    interpolated stack carries, at an intensity edge, a difference between angles proportional to
    the intensity's gradient across the sample offsets: to first order ``q ~ a_x gx + a_y gy`` and
    ``u ~ b_x gx + b_y gy`` with coefficients set by the layout and the demosaicing.  The
    demosaicing interpolates each angle from samples up to two pixels away, so the profile of that
    difference across an edge is wider than a 3 x 3 derivative: the gradient is taken at two
    scales, the 3 x 3 and 5 x 5 Sobel derivatives, whose combinations span the profiles of
    interpolation supports from one to two pixels (on a noiseless grey checker of 16-pixel squares
    through the IMX250MYR mosaic and the default demosaicing the 3 x 3 alone explains 0.77 of the
    false polarization's energy, the two scales 0.88; through the IMX250MZR mosaic and its default
    0.83 and 0.95).  Light that is really polarized is not a fixed linear function of the
    local gradient across a scene: a highlight's flanks have gradients of both signs under one
    AoLP.  So per channel the coefficients are the least-squares fit of ``q`` and ``u`` on the
    gradients' components (``order`` 2 adds the three 3 x 3 second derivatives) over the whole
    image, and the fitted part is removed: ``I0, I90`` move by ``-+ dq``, ``I45, I135`` by
    ``-+ du``; ``Ic`` is unchanged.

    Parameters
    ----------
    stack
        (4, H, W, C) float32, angles 0, 45, 90, 135 (numpy or torch).
    order
        1 (gradients at two scales) or 2 (and second derivatives).

    Returns
    -------
    (4, H, W, C) float32 of the same kind.
    """
    xp = namespace(stack)
    ic = stack.mean(axis=0)
    q = 0.5 * (stack[0] - stack[2])
    u = 0.5 * (stack[1] - stack[3])
    dq, du = [], []
    for c in range(ic.shape[-1]):
        img = ic[..., c]
        gx, gy = _imageops.sobel(img, 1, 0), _imageops.sobel(img, 0, 1)
        # the 5 x 5 derivative scaled to the 3 x 3's response on a ramp (128 against 8)
        regs = [gx, gy, _imageops.sobel(img, 1, 0, ksize=5) / 16.0, _imageops.sobel(img, 0, 1, ksize=5) / 16.0]
        if order >= 2:
            regs += [_imageops.sobel(gx, 1, 0), _imageops.sobel(gy, 0, 1), _imageops.sobel(gx, 0, 1)]
        n = len(regs)
        ata = np.zeros((n, n))
        for i in range(n):                # symmetric: each product once
            for j in range(i, n):
                ata[i, j] = ata[j, i] = float((regs[i] * regs[j]).sum())
        fits = []
        for t in (q[..., c], u[..., c]):
            atb = np.array([float((r * t).sum()) for r in regs])
            try:
                coef = np.linalg.solve(ata + 1e-12 * np.eye(n) * max(np.trace(ata), 1e-30), atb)
            except np.linalg.LinAlgError:
                coef = np.zeros(n)
            fit = regs[0] * float(coef[0])
            for k in range(1, n):
                fit = fit + regs[k] * float(coef[k])
            fits.append(xp.astype(fit, xp.float32))
        dq.append(fits[0])
        du.append(fits[1])
    dqx = xp.stack(dq, axis=-1)
    dux = xp.stack(du, axis=-1)
    return xp.stack([stack[0] - dqx, stack[1] - dux, stack[2] + dqx, stack[3] + dux], axis=0)
