"""The paper's operators, written once for numpy arrays and PyTorch tensors.

M. Shakeri and H. Zhang, "Highlight specular reflection separation based on
tensor low-rank and sparse decomposition using polarimetric cues", section 3:
the illuminant pre-normalisation, the polarization chromaticity (eq. 3), the
representations (similar pixels of a block), the unfolding of the
representation images into the data tensor D, the weights tau, and the phase
projection Phi^-1(Phi(.)) of the phase term.  docs/methods/tensor.md states each as
implemented and every departure from the paper.

Every function takes numpy arrays or ``torch.Tensor`` (on any device) and
returns the same kind (:func:`polcam._xp.namespace`); the
random draws of :func:`representations` come from a numpy generator in both
cases, so both pick the same pixels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from polcam._xp import namespace
from polcam.errors import MethodError
from polcam.separation._illuminant import estimate_illuminant as _checked
from polcam.separation._illuminant import projected_chromaticity

__all__ = [
    "illuminant",
    "estimate_illuminant",
    "white_divisor",
    "normalize_illuminant",
    "polarization_chromaticity",
    "candidates",
    "representations",
    "gather",
    "tau_weights",
    "unfold",
    "fold",
    "phase_project",
]


# ---------------------------------------------------------------------------
# illuminant
# ---------------------------------------------------------------------------

def illuminant(stack: Any, option: Any) -> np.ndarray:
    """The illuminant chromaticity the driver normalises by: the ``illuminant`` option's meaning.

    The one place the tensor method's driver asks for the illuminant:
    ``"polarization"`` estimates it from the stack (the polarized light's colour,
    :func:`estimate_illuminant`, checked against the highlights' own colour by
    :func:`polcam.separation._illuminant.estimate_illuminant`),
    ``"white"`` is (1/3, 1/3, 1/3), and an RGB triple is taken as given.

    Parameters
    ----------
    stack
        (4, H, W, 3) float in [0, 1] (numpy or torch).
    option
        ``"polarization"``, ``"white"`` or three positive numbers.

    Returns
    -------
    numpy.ndarray
        (3,) float64 chromaticity summing to 1.
    """
    if isinstance(option, str):
        if option == "polarization":
            # the polarized light's colour checked against the highlights' (polcam.separation._illuminant):
            # right on the real stacks where the polarized colour alone is not (docs/benchmarks.md)
            col = _checked(namespace(stack).to_numpy(stack)).colour
            return col / col.sum()
        if option == "white":
            return np.full(3, 1 / 3)
        raise MethodError(f"illuminant {option!r}: expected 'polarization', 'white' or an RGB triple")
    gam = np.asarray(option, dtype=np.float64)
    return gam / gam.sum()


#: The polarized light's colour by projection (:func:`polcam.separation._illuminant.projected_chromaticity`).
estimate_illuminant = projected_chromaticity


def white_divisor(gamma: Any) -> np.ndarray:
    """``3 Gamma`` (Gamma normalised to sum 1), checked: what :func:`normalize_illuminant` divides by."""
    g = np.asarray(gamma, dtype=np.float64).reshape(3)
    if np.any(g <= 0):
        raise MethodError(f"illuminant chromaticity {g.tolist()}: expected three positive values")
    return 3.0 * (g / g.sum())


def normalize_illuminant(stack: Any, gamma: Any) -> Any:
    """``I / (3 Gamma)`` per channel: the image under a white illuminant."""
    xp = namespace(stack)
    return stack / xp.asarray(white_divisor(gamma), like=stack)


# ---------------------------------------------------------------------------
# chromaticity and representations
# ---------------------------------------------------------------------------

def polarization_chromaticity(stack: Any) -> Any:
    """Polarization-based chromaticity image (paper eq. 3).

    ``I_rawS = 2 Isv``, ``I_rawD = max(Ic - I_rawS, 0)`` and
    ``I_chro = I_rawD / (sum_RGB I_rawD + mean_p min_RGB Ic)``, with
    ``Ic = S0 / 2`` and ``Isv = sqrt(S1^2 + S2^2) / 2``.

    Parameters
    ----------
    stack
        (4, H, W, 3) float.

    Returns
    -------
    array
        (H, W, 3), each channel in [0, 1).
    """
    xp = namespace(stack)
    ic = (stack[0] + stack[1] + stack[2] + stack[3]) * 0.5 * 0.5
    isv = xp.hypot(stack[0] - stack[2], stack[1] - stack[3]) * 0.5
    raw_d = xp.clamp_min(ic - 2.0 * isv, 0.0)
    i_min_bar = xp.mean(xp.amin(ic, axis=-1))
    denom = xp.sum(raw_d, axis=-1, keepdims=True) + i_min_bar
    pos = denom > 0
    return xp.where(pos, raw_d / xp.where(pos, denom, 1.0), 0.0)


def candidates(n4: int, block: int) -> list[tuple[int, int]]:
    """The (dy, dx) offsets of a block's pixels other than its centre, after checking n4 and block."""
    if n4 < 1:
        raise MethodError(f"n4 = {n4}: expected at least 1 representation")
    if block < 1 or block % 2 == 0:
        raise MethodError(f"block = {block}: expected an odd block side >= 1")
    r = block // 2
    return [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dy, dx) != (0, 0)]


def representations(chro: Any, *, n4: int, block: int, threshold: float,
                    rng: np.random.Generator) -> tuple[Any, float]:
    """Offsets of ``n4`` similar pixels drawn from the block around every pixel.

    Representation 0 is the pixel itself.  Representations 1 .. n4-1 are drawn
    without replacement among the block's pixels q (q != p, inside the image)
    with ``||chro(p) - chro(q)|| < threshold``; where fewer pass, the missing
    ones are p itself.  The draw: one uniform key per pixel and candidate from
    ``rng`` (infinite where q is not similar), the smallest keys win.

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
    offsets : array
        (n4, H, W, 2) integer (dy, dx); ``offsets[0] == 0``.
    filled : float
        Share of representation slots filled by a similar neighbour (not p).
    """
    xp = namespace(chro)
    cand = candidates(n4, block)
    h, w, _ = chro.shape
    r = block // 2
    offsets = xp.zeros((n4, h, w, 2), like=xp.arange(1, chro))           # integer (dy, dx)
    if n4 == 1 or not cand:
        return offsets, 0.0
    pad = xp.pad_hw(chro, r, np.inf)
    keys = xp.asarray(rng.random((len(cand), h, w)), like=chro)
    for j, (dy, dx) in enumerate(cand):
        q = pad[r + dy:r + dy + h, r + dx:r + dx + w]
        with np.errstate(invalid="ignore"):                   # inf - inf = nan outside: not similar
            dist = xp.sqrt(xp.sum((q - chro) ** 2, axis=-1))
            keys[j] = xp.where(dist < threshold, keys[j], np.inf)
    take = min(n4 - 1, len(cand))
    picked, order = xp.sort0(keys)
    picked, order = picked[:take], order[:take]
    cand_arr = xp.index_array(cand, like=chro)
    valid = xp.isfinite(picked)
    offsets[1:take + 1] = xp.where(valid[..., None], cand_arr[order], 0)
    filled = float(xp.mean(xp.astype(valid, xp.float64))) * take / (n4 - 1)
    return offsets, filled


def gather(images: Any, offsets: Any) -> Any:
    """Representation images: ``out[i, ..., y, x, :] = images[..., y + dy_i, x + dx_i, :]``.

    Parameters
    ----------
    images
        (..., H, W, C).
    offsets
        (n4, H, W, 2) from :func:`representations`.

    Returns
    -------
    array
        (n4, ..., H, W, C).
    """
    xp = namespace(images)
    h, w = offsets.shape[1:3]
    lead = tuple(images.shape[:-3])
    c = images.shape[-1]
    flat = images.reshape(*lead, h * w, c)
    base = xp.arange(h * w, like=offsets).reshape(h, w)
    out = []
    for off in offsets:
        idx = (base + off[..., 0] * w + off[..., 1]).reshape(-1)   # flat index of (y + dy, x + dx)
        out.append(xp.take(flat, idx, axis=-2).reshape(*lead, h, w, c))
    return xp.stack(out)


# ---------------------------------------------------------------------------
# tau, unfolding, phase projection
# ---------------------------------------------------------------------------

def _gradient(a: Any, axis: int) -> Any:
    """``numpy.gradient`` along one axis: central differences inside, one-sided at the ends."""
    xp = namespace(a)
    n = a.shape[axis]
    if n < 2:
        return a * 0.0
    sl = [slice(None)] * a.ndim

    def at(s: slice | int) -> tuple[Any, ...]:
        return tuple(sl[:axis] + [s] + sl[axis + 1:])

    parts = [a[at(slice(1, 2))] - a[at(slice(0, 1))]]
    if n > 2:
        parts.append((a[at(slice(2, None))] - a[at(slice(None, -2))]) * 0.5)
    parts.append(a[at(slice(n - 1, n))] - a[at(slice(n - 2, n - 1))])
    if xp.name == "numpy":
        return np.concatenate(parts, axis=axis)
    return xp.torch.cat(parts, dim=axis)


def tau_weights(first: Any, *, alpha: float, beta: float, floor: float) -> Any:
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
    array
        (4, n1, n2, 3) tau > 0; the gradient is taken within each angle and
        channel image (central differences, one-sided at the borders), never
        across block boundaries.
    """
    xp = namespace(first)
    gy, gx = _gradient(first, 1), _gradient(first, 2)
    grad = xp.sqrt(gx * gx + gy * gy)
    return xp.clamp_min(1.0 - first, floor) * xp.exp(alpha * grad ** beta)


def unfold(d: Any) -> Any:
    """(..., n4, 4, n1, n2, 3) -> D, slice-first: (..., n4, 4 n1, 3 n2).

    Frontal slice i of the paper's D (4 n1, 3 n2, n4) is ``D[..., i, :, :]``:
    each angle's (n1, n2, 3) image is the (n1, 3 n2) matrix of column blocks
    [R | G | B], the four angles are stacked as row blocks, the representations
    are the third mode (first here, so each frontal slice is contiguous).
    """
    xp = namespace(d)
    *lead, n4, na, n1, n2, c = d.shape
    k = len(lead)
    z = xp.permute(d, list(range(k)) + [k, k + 1, k + 2, k + 4, k + 3])
    return z.reshape(*lead, n4, na * n1, c * n2)


def fold(z: Any, n1: int, n2: int) -> Any:
    """Inverse of :func:`unfold`: (..., n4, 4 n1, 3 n2) -> (..., n4, 4, n1, n2, 3)."""
    xp = namespace(z)
    *lead, n4, kk, m = z.shape
    k = len(lead)
    v = z.reshape(*lead, n4, kk // n1, n1, m // n2, n2)
    return xp.permute(v, list(range(k)) + [k, k + 1, k + 2, k + 4, k + 3])


def phase_project(z: Any, n1: int, n2: int, out: Any = None) -> Any:
    """``Phi^-1(Phi(z))``: one phase per pixel shared by R, G and B, on unfolded tensors.

    Per pixel, channel and representation, the sinusoid
    ``Ic + Isv cos(2t - 2 phi_c)`` is fitted to the four angle images; the common
    doubled phase is the direction of the sum of the channels' unit phasors
    ``(s1_c, s2_c) / |(s1_c, s2_c)|`` (``s1 = I0 - I90``, ``s2 = I45 - I135``;
    a channel with no amplitude carries no phase; direction (1, 0) where the sum
    is zero), so the mean respects the period pi; each channel is resynthesised
    with its own Ic and Isv and the common phase: with ``(c, s)`` the cosine and
    sine of the doubled phase, the four angle images are ``Ic + Isv c``,
    ``Ic + Isv s``, ``Ic - Isv c``, ``Ic - Isv s``.

    Parameters
    ----------
    z
        (..., n4, 4 n1, 3 n2) real, angle row blocks 0, 45, 90, 135 and channel
        column blocks R, G, B (:func:`unfold`).
    n1, n2
        Image height and width.
    out
        Optional array of z's shape and dtype to write into.

    Returns
    -------
    array
        Same shape as z, in ``out`` when given.
    """
    xp = namespace(z)
    lead = tuple(z.shape[:-2])
    v = z.reshape(*lead, 4, n1, 3, n2)
    s1 = v[..., 0, :, :, :] - v[..., 2, :, :, :]
    s2 = v[..., 1, :, :, :] - v[..., 3, :, :, :]
    amp = s1 * s1
    amp += s2 * s2
    xp.sqrt(amp, out=amp)                                        # 2 Isv
    tiny = xp.tiny(amp)
    inv = xp.clamp_min(amp, tiny)
    xp.div(1.0, inv, out=inv)                                    # where amp = 0, s1 = s2 = 0: no phasor
    s1 *= inv
    s2 *= inv
    c = s1[..., 0, :] + s1[..., 1, :]                            # sum of unit phasors over RGB
    c += s1[..., 2, :]
    s = s2[..., 0, :] + s2[..., 1, :]
    s += s2[..., 2, :]
    nz = xp.hypot(c, s)
    zero = nz == 0
    xp.clamp_min(nz, tiny, out=nz)
    xp.div(0.5, nz, out=nz)                                      # the 1/2 turns 2 Isv into Isv
    c *= nz
    s *= nz
    c[zero] = 0.5                                                # direction (1, 0) where the sum is zero
    amp_c = amp * c[..., None, :]                                # Isv cos 2phi
    amp_s = amp * s[..., None, :]                                # Isv sin 2phi
    s0h = v[..., 0, :, :, :] + v[..., 1, :, :, :]
    s0h += v[..., 2, :, :, :]
    s0h += v[..., 3, :, :, :]
    s0h *= 0.25                                                  # Ic
    if out is None:
        out = z * 0
    r = out.reshape(*lead, 4, n1, 3, n2)
    xp.add(s0h, amp_c, out=r[..., 0, :, :, :])
    xp.add(s0h, amp_s, out=r[..., 1, :, :, :])
    xp.sub(s0h, amp_c, out=r[..., 2, :, :, :])
    xp.sub(s0h, amp_s, out=r[..., 3, :, :, :])
    return out
