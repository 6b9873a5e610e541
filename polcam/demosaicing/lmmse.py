"""``lmmse``: a linear minimum-mean-square-error filter bank learned from rendered scenes.

The idea is Spote, Lapray, Thomas and Farup's LMMSE demosaicing of colour
polarization filter arrays (2021), which follows Amba, Dias and Alleysson's
LMMSE demosaicing of colour filter arrays: every output value is a linear
function of the raw samples around it, and the linear map that minimises the
mean squared error over a training set of full-resolution stacks is the Wiener
solution ``W = E[y x^T] E[x x^T]^-1``.  Because the map is learned jointly for
all four angles and all three colours, it uses the correlations between angles
(S1, S2 vary more slowly than S0) and between colours that a per-lattice
interpolation ignores, which is what DoLP and AoLP need.

As implemented here (docs/methods/demosaic-lmmse.md has the details):

* The raw is cut into 4x4 blocks; the 4 x 4 x 4 angles (x 3 colours) outputs of a
  block are one linear map of the 12 x 12 raw samples of the block and its eight
  neighbours (144 inputs): one matrix product per frame.
* The filters are fit by constrained least squares (:mod:`polcam.bench.lmmse_training`)
  on scenes polcam renders itself and on public-domain / CC0 photographs with simulated
  polarization (:mod:`polcam.synth.photos`), so the weights can ship.
  Constraints: a pixel's own sample is kept exactly; the weights each output puts on
  each (angle, colour) lattice sum to 1 on its own lattice and 0 on the others, so a
  uniformly polarized, uniformly coloured scene comes back exactly whatever the
  weights; the first and second moments of those weights about the output pixel
  vanish too, so images whose every angle and colour is quadratic in x and y come back
  exactly.
* A second stage re-estimates every angle from its own samples with the bank's S0
  as guide, through the polarization ratio ``I / (S0 / 2)``, which is
  ``1 + DoLP cos(2 (theta - AoLP))``, free of the intensity's texture: this is where
  the DoLP and AoLP gain comes from (after the Stokes-domain and
  polarization-difference ideas of Qiu et al. 2019 and Li et al. 2019).  Colour
  layouts run the shared ratio (:func:`polcam.demosaicing._shared_ratio.shared_ratio_stage`:
  the ratios of all colours of an angle, each colour's smooth offset removed,
  interpolated on the angle's period-2 lattice, plus each colour's smooth residual);
  :func:`second_stage` is the per-colour ratio stage (each (angle, colour) lattice on
  its own, the lattice's bilinear tent smoothed by a Gaussian), selectable by
  :data:`LMMSE_PARAMS`.
* Weights exist for two cell geometries: orthogonal angles on the diagonals of the
  2x2 cell (IMX250: ``90 45 / 135 0``) and side by side.  Any other layout (other
  arrangements, Bayer phases, ROI offsets, mirrored read-outs) is brought to one of
  these by a flip or transpose of the image, a shift of the pattern's phase and the
  matching relabelling of the angles (the physical one where one exists), and the
  result is brought back.
* Borders: each (angle, colour) lattice is mirrored about its own outermost
  samples, which keeps the mosaic's phase.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from polcam.demosaicing._lattice import bilinear_cells, normconv, run_jobs, sublattices
from polcam.demosaicing._lattice import gauss_kernel as _gauss
from polcam.demosaicing._lattice import tent_kernel as _tent_kernel
from polcam.demosaicing._registry import register
from polcam.demosaicing._shared_ratio import shared_ratio_from_half
from polcam.errors import MethodError
from polcam.mosaic import Layout, parse_layout

__all__ = ["BLOCK", "CANONICAL", "LMMSE_PARAMS", "NBLOCKS", "REFERENCE", "WEIGHTS_FILE", "Plan", "apply_bank",
           "block_features", "lattice_of_taps", "lmmse", "plan", "run_lmmse", "second_stage", "tap_offsets",
           "to_blocks", "weight_key"]

REFERENCE = ("LMMSE demosaicing after N. Spote, P.-J. Lapray, J.-B. Thomas, I. Farup, \"Joint demosaicing "
             "of colour and polarisation from filter arrays\", CIC 2021 (and P. Amba, J. Dias, "
             "D. Alleysson, \"Random color filter arrays are better than regular ones\", JIST 2016), "
             "filters learned from polcam's own rendered scenes and public-domain photographs with simulated "
             "polarization")

#: Block side in pixels: outputs are computed per 4x4 block of the raw.
BLOCK = 4
#: Neighbourhood of a block, in blocks (3: the block and its eight neighbours, 12x12 pixels).
NBLOCKS = 3
#: The canonical layout of each (colour?, geometry) the weights are stored for.
CANONICAL: dict[tuple[bool, str], str] = {
    (False, "diag"): "mono:90,45,135,0",
    (True, "diag"): "color:90,45,135,0:RGGB",
    (False, "beside"): "mono:0,90,45,135",
    (True, "beside"): "color:0,90,45,135:RGGB",
}
#: The shipped weights (made by ``polcam bench train-lmmse``).
WEIGHTS_FILE = Path(__file__).with_name("lmmse_weights.npz")

_ROWS_PER_JOB = 32  # block rows per strip


def weight_key(color: bool, geometry: str) -> str:
    """Name of a weight matrix in :data:`WEIGHTS_FILE`."""
    return f"{'color' if color else 'mono'}_{geometry}"


@lru_cache(maxsize=1)
def shipped_weights() -> dict[str, np.ndarray]:
    if not WEIGHTS_FILE.is_file():  # pragma: no cover - a broken install
        raise MethodError(f"lmmse weights {WEIGHTS_FILE} are missing: reinstall polcam or run "
                          "polcam bench train-lmmse")
    with np.load(WEIGHTS_FILE) as data:
        return {k: np.ascontiguousarray(data[k], dtype=np.float32) for k in data.files if k != "info"}


# ---------------------------------------------------------------------------
# geometry: bring any layout to a canonical one
# ---------------------------------------------------------------------------

def _transform(a: np.ndarray, t: tuple[bool, bool, bool]) -> np.ndarray:
    """Apply (transpose, flip rows, flip columns) to the first two axes of ``a``."""
    tr, fy, fx = t
    if tr:
        a = np.swapaxes(a, 0, 1)
    if fy:
        a = a[::-1]
    if fx:
        a = a[:, ::-1]
    return a


def _untransform(a: np.ndarray, t: tuple[bool, bool, bool]) -> np.ndarray:
    """Inverse of :func:`_transform` on axes 1, 2 of a stack (4, H, W[, C])."""
    tr, fy, fx = t
    if fx:
        a = a[:, :, ::-1]
    if fy:
        a = a[:, ::-1]
    if tr:
        a = np.swapaxes(a, 1, 2)
    return a


def _physical(t: tuple[bool, bool, bool]) -> tuple[int, ...]:
    """The relabelling of angle indices (0, 45, 90, 135) a transform makes: a direction at
    angle theta in the image becomes 90 - theta under a transpose, -theta under a flip."""
    tr, fy, fx = t
    idx = np.arange(4)
    if tr:
        idx = (2 - idx) % 4
    if fy:
        idx = (-idx) % 4
    if fx:
        idx = (-idx) % 4
    return tuple(int(i) for i in idx)


_D4 = [tuple((m + s * i) % 4 for i in range(4)) for s in (1, -1) for m in range(4)]
_TRANSFORMS = [(tr, fy, fx) for tr in (False, True) for fy in (False, True) for fx in (False, True)]


@dataclass(frozen=True)
class Plan:
    """How a layout maps to a canonical one.

    ``transform`` (transpose, flip rows, flip columns) applied to the raw; then the pixel
    (y, x) of the transformed raw is canonical class ``((y + shift[0]) % 4, (x + shift[1]) % 4)``;
    ``relabel[a]`` is the canonical angle index measuring this layout's angle index a.
    """

    key: str
    canonical: Layout
    transform: tuple[bool, bool, bool]
    shift: tuple[int, int]
    relabel: tuple[int, ...]


def plan(lay: Layout, height: int, width: int) -> Plan:
    """The :class:`Plan` that brings a ``height`` x ``width`` mosaic of ``lay`` to a canonical layout."""
    # the pattern of a flipped image depends on its size only modulo the period
    hh, ww = 2 * BLOCK + height % BLOCK, 2 * BLOCK + width % BLOCK
    ai = lay.angle_index(hh, ww)
    ci = lay.channel_index(hh, ww)
    for physical_only in (True, False):
        for t in _TRANSFORMS:
            a_t = _transform(ai, t)[:BLOCK, :BLOCK]
            c_t = _transform(ci, t)[:BLOCK, :BLOCK]
            sigmas = [_physical(t)] if physical_only else _D4
            for geo in ("diag", "beside"):
                canon = parse_layout(CANONICAL[(lay.is_color, geo)])
                ca = canon.angle_index(2 * BLOCK, 2 * BLOCK)
                cc = canon.channel_index(2 * BLOCK, 2 * BLOCK)
                for sy in range(BLOCK):
                    for sx in range(BLOCK):
                        if not np.array_equal(cc[sy:sy + BLOCK, sx:sx + BLOCK], c_t):
                            continue
                        want_a = ca[sy:sy + BLOCK, sx:sx + BLOCK]
                        for sigma in sigmas:
                            if np.array_equal(np.asarray(sigma)[a_t], want_a):
                                return Plan(weight_key(lay.is_color, geo), canon, t, (sy, sx), sigma)
    raise MethodError(f"layout {lay} cannot be mapped to a canonical lmmse layout")  # pragma: no cover


# ---------------------------------------------------------------------------
# features and the filter bank
# ---------------------------------------------------------------------------

def lattice_of_taps(canon: Layout) -> np.ndarray:
    """(144,) index of the (angle, colour) lattice of every input tap, angle * C + colour."""
    n = NBLOCKS * BLOCK
    ai = canon.angle_index(n, n)
    ci = canon.channel_index(n, n)
    c = 3 if canon.is_color else 1
    lat = ai * c + ci  # (n, n) in pixel order
    return _pixels_to_taps(lat)


def tap_offsets() -> np.ndarray:
    """(144, 2) position (y, x) of every input tap relative to the centre block's corner."""
    n = NBLOCKS * BLOCK
    yy, xx = np.mgrid[0:n, 0:n] - BLOCK
    return np.stack([_pixels_to_taps(yy), _pixels_to_taps(xx)], axis=1)


def _pixels_to_taps(a: np.ndarray) -> np.ndarray:
    """An (12, 12) pixel array in tap order (block row, block column, y in block, x in block)."""
    n = NBLOCKS
    return a.reshape(n, BLOCK, n, BLOCK).transpose(0, 2, 1, 3).reshape(-1)


def to_blocks(padded: np.ndarray) -> np.ndarray:
    """(4 hb, 4 wb) -> (hb, wb, 16) blocks in (y, x) order."""
    h, w = padded.shape
    return np.ascontiguousarray(
        padded.reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).transpose(0, 2, 1, 3)
    ).reshape(h // BLOCK, w // BLOCK, BLOCK * BLOCK)


def block_features(blocks: np.ndarray, r0: int, r1: int) -> np.ndarray:
    """Features of output block rows r0..r1 (block rows of ``blocks`` minus the one-block halo).

    ``blocks`` (hb + 2, wb + 2, 16); returns (r1 - r0, wb, 144) float32 in tap order.
    """
    wb = blocks.shape[1] - 2
    parts = [blocks[r0 + di:r1 + di, dj:dj + wb] for di in range(NBLOCKS) for dj in range(NBLOCKS)]
    return np.concatenate(parts, axis=2)


def _mirror(t: np.ndarray, n: int, p: int) -> np.ndarray:
    """Indices ``t`` (any integers) mirrored into [0, n) about the outermost sample of their
    own lattice (period ``p``), so every index keeps its class mod p."""
    t = t.copy()
    for _ in range(64):
        lo = t < 0
        t[lo] = 2 * (t[lo] % p) - t[lo]
        hi = t >= n
        r = t[hi] % p
        t[hi] = 2 * (r + p * ((n - 1 - r) // p)) - t[hi]
        if not (lo.any() or hi.any()):
            return t
    raise AssertionError("mirror did not converge")  # pragma: no cover


def apply_bank(img: np.ndarray, weights: np.ndarray, shift: tuple[int, int], channels: int, *,
               guide: bool = False) -> np.ndarray:
    """Run a filter bank on a mosaic in a canonical layout (up to the phase ``shift``).

    Parameters
    ----------
    img
        (H, W) float32 mosaic; pixel (y, x) is canonical class ((y + sy) % 4, (x + sx) % 4).
    weights
        (144, n * 16 * channels) float32, outputs in (angle, y in block, x in block, colour) order
        (n angles, 4 for the shipped banks).
    shift
        (sy, sx).
    channels
        3 for colour, 1 for mono.
    guide
        Return only ``S0 / 2`` per channel, ``(((I0 + I1) + I2) + I3) / 4`` of the bank's four
        angles (what ``stack.sum(axis=0) / 4`` of the full result gives, bit for bit), without
        the four angles' full-size images.

    Returns
    -------
    numpy.ndarray
        (n, H, W, channels) float32, (1, H, W, channels) with ``guide``.
    """
    h, w = img.shape
    sy, sx = shift
    hb = -(-(sy + h) // BLOCK)
    wb = -(-(sx + w) // BLOCK)
    rows = _mirror(np.arange((hb + 2) * BLOCK) - BLOCK - sy, h, BLOCK)
    cols = _mirror(np.arange((wb + 2) * BLOCK) - BLOCK - sx, w, BLOCK)
    padded = img[np.ix_(rows, cols)]
    blocks = to_blocks(padded)
    n = 1 if guide else weights.shape[1] // (BLOCK * BLOCK * channels)
    out = np.empty((n, hb * BLOCK, wb * BLOCK, channels), np.float32)
    jobs = [lambda r0=r0: _job(blocks, weights, out, r0, min(hb, r0 + _ROWS_PER_JOB), wb, channels, guide)
            for r0 in range(0, hb, _ROWS_PER_JOB)]
    run_jobs(jobs)
    return out[:, sy:sy + h, sx:sx + w]


def _job(blocks: np.ndarray, weights: np.ndarray, out: np.ndarray, r0: int, r1: int, wb: int,
         channels: int, guide: bool) -> None:
    feats = block_features(blocks, r0, r1).reshape(-1, weights.shape[0])
    n = weights.shape[1] // (BLOCK * BLOCK * channels)
    y = (feats @ weights).reshape(r1 - r0, wb, n, BLOCK, BLOCK, channels)  # one 2-D GEMM
    if guide:  # S0 / 2: the angles summed in the order of stack.sum(axis=0)
        half = np.add(y[:, :, 0], y[:, :, 1])
        for k in range(2, n):
            half += y[:, :, k]
        half *= np.float32(0.25)
        y = half[:, :, None]
        n = 1
    for k in range(n):
        dst = out[k, r0 * BLOCK:r1 * BLOCK].reshape(r1 - r0, BLOCK, wb, BLOCK, channels)
        dst[...] = y[:, :, k].transpose(0, 2, 1, 3, 4)


#: Parameters of the second stage (docs/methods/demosaic-lmmse.md says how they were chosen).
LMMSE_PARAMS: dict[str, float | str] = {
    # second stage per kind of layout: "shared-ratio" (colour only), "ratio" (polarization ratio of
    # each lattice), "difference" or "none"
    "color_stage": "shared-ratio",
    "mono_stage": "none",
    # Gaussian of the normalised convolution of the ratios / differences, pixels (colour, mono)
    "sigma": 2.0,
    "mono_sigma": 1.0,
    # offset of the ratio's denominator, relative to the mean of the mosaic
    "ratio_eps": 1e-2,
    # kernel of the normalised convolution: "gauss" (a Gaussian of ``sigma`` / ``mono_sigma``) or
    # "tent" (the lattice's bilinear tent, radius = the lattice period, convolved with a Gaussian
    # of ``tent_sigma``: ratios that are affine in x and y come back exactly)
    "kernel": "tent",
    "tent_sigma": 1.5,
    # the "shared-ratio" stage (colour; polcam.demosaicing._shared_ratio): Gaussians in pixels of the
    # all-colour ratio (with the period-2 tent), the colours' offsets and the colours' residual
    "common_sigma": 1.2,
    "offset_sigma": 12.0,
    "residual_sigma": 3.0,
}


def second_stage(img: np.ndarray, stack: np.ndarray, lay: Layout, *, mode: str, sigma: float,
                 eps: float, kernel: str = "gauss") -> np.ndarray:
    """Re-estimate every angle from its own samples, with S0 from ``stack`` as the guide.

    ``mode="ratio"``: the polarization ratio ``q = I / (S0 / 2 + e)`` of each (angle,
    colour) lattice's samples (S0 of the sample's own colour, clipped to [0, 2]) is
    interpolated by normalised convolution and multiplied back by ``S0 / 2 + e``;
    ``"difference"``: the polarization difference ``I - S0 / 2`` is interpolated and
    added back.  Both vary much more slowly than the intensity where the
    polarization is smooth (the ratio is ``1 + DoLP cos(2 (theta - AoLP))``, free of
    the intensity's texture), which is what DoLP and AoLP need.  Own samples are kept.

    Parameters
    ----------
    img
        (H, W) float32 mosaic.
    stack
        (4, H, W, C) first-stage estimate (C = 3 colour, 1 mono).
    mode
        "ratio" or "difference".
    sigma
        ``kernel="gauss"``: the Gaussian (pixels, truncated at 2.5 sigma); ``"tent"``: the
        Gaussian the lattice's tent is convolved with (:func:`_tent_kernel`; 0: the tent alone,
        bilinear interpolation of the ratio).
    eps
        Offset of the ratio's denominator, relative to the mosaic's mean.
    kernel
        "gauss" or "tent" (affine ratios exact).

    Returns
    -------
    numpy.ndarray
        (4, H, W, C) float32.
    """
    h, w = img.shape
    channels = stack.shape[-1]
    period = lay.period
    half = stack.sum(axis=0) * np.float32(0.25)  # S0 / 2 per channel, (H, W, C)
    ci = lay.channel_index(h, w)
    own = np.take_along_axis(half, ci[..., None], axis=2)[..., 0]
    e = np.float32(eps * max(float(np.mean(img, dtype=np.float64)), 1e-6))
    if mode == "ratio":
        # the true ratio I / (S0 / 2) = 1 + DoLP cos(...) lies in [0, 2]; the clip keeps a poor
        # first-stage S0 (near 0 or negative on aliased detail) from blowing it up
        val = np.clip(img / (np.maximum(own, 0) + e), 0, 2)
        base = np.maximum(half, 0) + e
    else:
        val = img - own
        base = half
    if kernel == "tent":
        kern = _tent_kernel(period, sigma)
    elif kernel == "gauss":
        kern = _gauss(sigma)
    else:
        raise MethodError(f"lmmse kernel {kernel!r}: expected 'gauss' or 'tent'")
    out = np.empty_like(stack)

    def job(k: int, c: int) -> None:
        offsets = sublattices(lay, k, c)
        q = normconv(val, offsets, period, kern)
        est = out[k, ..., c]
        if mode == "ratio":
            np.multiply(q, base[..., c], out=est)
        else:
            np.add(q, base[..., c], out=est)
        for oy, ox in offsets:  # own samples kept
            est[oy::period, ox::period] = img[oy::period, ox::period]

    run_jobs([lambda k=k, c=c: job(k, c) for k in range(4) for c in range(channels)])
    return out


def lmmse(img: np.ndarray, lay: Layout) -> np.ndarray:
    """LMMSE filter-bank demosaicing of a float32 (H, W) mosaic, with the shipped weights and
    :data:`LMMSE_PARAMS`.

    Returns
    -------
    numpy.ndarray
        float32 (4, H, W) for a mono layout, (4, H, W, 3) for a colour one.
    """
    return run_lmmse(img, lay, weights=shipped_weights(), params=LMMSE_PARAMS)


def run_lmmse(img: np.ndarray, lay: Layout, *, weights: dict[str, np.ndarray],
              params: dict[str, float | str]) -> np.ndarray:
    """:func:`lmmse` with given banks (:func:`weight_key` -> (144, outputs) float32) and
    second-stage parameters (the keys of :data:`LMMSE_PARAMS`): what the model selection of
    :mod:`polcam.bench.demosaic_validation` runs on its validation scenes.

    Returns
    -------
    numpy.ndarray
        float32 (4, H, W) for a mono layout, (4, H, W, 3) for a colour one.
    """
    h, w = img.shape
    p = plan(lay, h, w)
    raw = np.ascontiguousarray(_transform(img, p.transform))
    channels = 3 if lay.is_color else 1
    bank = np.ascontiguousarray(weights[p.key], dtype=np.float32)
    mode = str(params["color_stage" if lay.is_color else "mono_stage"])
    if mode == "shared-ratio":
        # the stage reads the first stage only through S0 / 2 per colour: the bank of that alone
        half = apply_bank(raw, bank, p.shift, channels, guide=True)
        half = np.ascontiguousarray(_untransform(half, p.transform)[0])
        return shared_ratio_from_half(img, half, lay, common_sigma=float(params["common_sigma"]),
                                      offset_sigma=float(params["offset_sigma"]),
                                      residual_sigma=float(params["residual_sigma"]), eps=float(params["ratio_eps"]),
                                      out=np.empty((4, h, w, channels), np.float32))
    canon = apply_bank(raw, bank, p.shift, channels)
    if p.relabel != (0, 1, 2, 3):
        canon = canon[list(p.relabel)]
    stack = np.ascontiguousarray(_untransform(canon, p.transform))
    if mode != "none":
        kernel = str(params.get("kernel", "gauss"))
        sigma = float(params["tent_sigma"] if kernel == "tent" else params["sigma" if lay.is_color else "mono_sigma"])
        stack = second_stage(img, stack, lay, mode=mode, sigma=sigma, eps=float(params["ratio_eps"]),
                             kernel=kernel)
    if not lay.is_color:
        stack = stack[..., 0]
    return np.ascontiguousarray(stack)


register("lmmse", cell=bilinear_cells, reference=REFERENCE)(lmmse)
