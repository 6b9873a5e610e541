"""Training of the ``lmmse`` filter bank on scenes polcam renders itself.

Run ``polcam bench train-lmmse`` to remake
``polcam/demosaicing/lmmse_weights.npz`` (a few minutes on two cores).  The
training stacks are drawn from a seeded random generator: scenes polcam renders
itself (:func:`training_stack`), scenes of :mod:`polcam.synth.patterns`, and crops of
public-domain / CC0 photographs that ship with scikit-image, given a simulated
polarization by :mod:`polcam.synth.photos`; so the weights carry no licence
that forbids shipping them (docs/methods/demosaic-lmmse.md lists the photographs' licences).

The scenes aim at what real colour-polarization frames contain and what the
benchmark's synthetic scenes do not: colours that do NOT share one
polarization.  Each scene is a background and a few shapes (ellipses, polygons,
half-planes, with sharp anti-aliased edges), each with

* a coloured diffuse layer: a random colour, textured by 1/f noise or stripes,
  weakly polarized (DoLP 0 to 0.25) with a smoothly varying AoLP;
* sometimes a strongly polarized coloured region (DoLP up to 0.9: filters,
  screens, sky);
* sometimes specular highlights in the illuminant's colour (near white), strongly
  polarized (DoLP 0.3 to 1) with an AoLP across the diffuse one;

then mild optical blur, clipping at the white level, and raw noise
(signal-dependent Gaussian, sometimes 8-bit quantisation) on the mosaic only; the
targets are the noise-free stacks.  To these the shipped weights add scenes of
:mod:`polcam.synth.patterns` (:func:`pattern_stack`: smooth, textured, edges, sweep,
with seeds the benchmark and the validation set do not use) and photograph crops
(:func:`polcam.synth.photos.photo_stack`, training photographs only).

The fit (:func:`fit_bank`) is constrained least squares: for every output (angle,
pixel of the 4x4 block, colour), minimise the squared error over all training
blocks subject to (1) a pixel's own sample is kept, (2) the weights on each (angle,
colour) lattice sum to 1 on the output's own lattice and 0 on the others, (3) the
moments of each lattice's weights about the output pixel vanish up to order
``moments`` (1: an image whose every angle and colour is an affine function of
position comes back exactly; 2, the shipped weights: a quadratic one).  A small ridge
term (``ridge`` times the mean diagonal of the Gram matrix) keeps the solve well
conditioned.  The defaults of the command line were chosen on polcam's own
validation set (:mod:`polcam.bench.demosaic_validation`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from polcam.demosaicing import mosaic_stack
from polcam.demosaicing.lmmse import (  # noqa: I001
    BLOCK,
    CANONICAL,
    NBLOCKS,
    block_features,
    lattice_of_taps,
    tap_offsets,
    to_blocks,
    weight_key,
)
from polcam.io.atomic import atomic_path
from polcam.mosaic import Layout, parse_layout
from polcam.synth.patterns import SCENES, make_scene
from polcam.synth.photos import TRAINING_PHOTOS, photo_stack

__all__ = ["fit_bank", "noisy_raw", "save_weights", "train", "training_stack"]

#: Defaults of the command line (chosen by :mod:`polcam.bench.demosaic_validation`;
#: docs/methods/demosaic-lmmse.md).
DEFAULT_PATTERNS = 50
DEFAULT_PHOTOS = 80
DEFAULT_MOMENTS = 2
DEFAULT_RIDGE = 3e-3

#: Rec. 709 luminance weights: the mono training stacks are the colour ones' luminance.
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


# ---------------------------------------------------------------------------
# scenes
# ---------------------------------------------------------------------------

def _smooth_field(rng: np.random.Generator, n: int, *, scale: float) -> np.ndarray:
    """A smooth random field in about [-1, 1]: a few low-frequency cosines, (n, n)."""
    y, x = np.mgrid[0:n, 0:n].astype(np.float32) / n
    out = np.zeros((n, n), np.float32)
    for _ in range(4):
        f = rng.uniform(0.2, scale)
        th = rng.uniform(0, np.pi)
        out += np.cos(2 * np.pi * f * (x * np.cos(th) + y * np.sin(th)) + rng.uniform(0, 2 * np.pi))
    return out / 2


def _pink(rng: np.random.Generator, n: int, beta: float) -> np.ndarray:
    """1/f^beta noise, zero mean, unit standard deviation, (n, n)."""
    f = np.fft.fftfreq(n)
    r = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2)
    r[0, 0] = 1.0
    spec = (rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))) / r**beta
    spec[0, 0] = 0
    img = np.real(np.fft.ifft2(spec)).astype(np.float32)
    return img / max(float(img.std()), 1e-6)


def _texture(rng: np.random.Generator, n: int) -> np.ndarray:
    """A multiplicative texture around 1, (n, n)."""
    kind = rng.integers(0, 4)
    if kind == 0:
        return np.ones((n, n), np.float32)
    if kind == 1:
        return np.clip(1 + rng.uniform(0.05, 0.5) * _pink(rng, n, rng.uniform(0.8, 1.6)), 0.05, 3)
    y, x = np.mgrid[0:n, 0:n].astype(np.float32)
    th = rng.uniform(0, np.pi)
    u = x * np.cos(th) + y * np.sin(th)
    if kind == 2:  # stripes of a random period (in rendered pixels)
        period = rng.uniform(4, 40)
        wave = np.cos(2 * np.pi * u / period)
    else:  # a chirp: frequency rising across the shape
        wave = np.cos(2 * np.pi * (u / n) ** 2 * rng.uniform(20, 120))
    if rng.random() < 0.5:
        wave = np.sign(wave)
    return (1 + rng.uniform(0.1, 0.7) * wave).astype(np.float32)


def _shape_mask(rng: np.random.Generator, n: int) -> np.ndarray:
    mask = np.zeros((n, n), np.uint8)
    kind = rng.integers(0, 3)
    if kind == 0:
        c = tuple(int(v) for v in rng.integers(0, n, 2))
        axes = tuple(int(v) for v in rng.integers(n // 16, n // 2, 2))
        cv2.ellipse(mask, c, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1, lineType=cv2.LINE_8)
    elif kind == 1:
        pts = rng.integers(-n // 4, n + n // 4, size=(int(rng.integers(3, 7)), 2)).astype(np.int32)
        cv2.fillPoly(mask, [cv2.convexHull(pts)], 1)
    else:
        y, x = np.mgrid[0:n, 0:n]
        th = rng.uniform(0, 2 * np.pi)
        mask[(x - rng.uniform(0, n)) * np.cos(th) + (y - rng.uniform(0, n)) * np.sin(th) > 0] = 1
    return mask.astype(bool)


def training_stack(rng: np.random.Generator, size: int) -> np.ndarray:
    """One random colour training scene.

    Parameters
    ----------
    rng
        Random generator (the scene is a function of its state).
    size
        Side in pixels (a multiple of 4).

    Returns
    -------
    numpy.ndarray
        (4, size, size, 3) float32 in [0, 1], angles 0, 45, 90, 135, RGB.
    """
    n = 2 * size  # rendered at twice the size, then area-averaged: anti-aliased edges
    s = np.zeros((3, n, n, 3), np.float32)  # S0, S1, S2 per channel
    for i in range(int(rng.integers(3, 9))):
        mask = np.ones((n, n), bool) if i == 0 else _shape_mask(rng, n)
        colour = rng.uniform(0, 1, 3) ** rng.uniform(0.5, 2.5)
        colour = colour / max(float(colour.max()), 1e-3) * rng.uniform(0.1, 1.0)
        diffuse = _texture(rng, n)[..., None] * colour.astype(np.float32)
        strong = rng.random() < 0.2
        rho = (rng.uniform(0.3, 0.9) if strong else rng.uniform(0, 0.25)) * (
            1 + 0.3 * _smooth_field(rng, n, scale=2.0))
        phi = rng.uniform(0, np.pi) + rng.uniform(0, 1.5) * _smooth_field(rng, n, scale=2.0)
        layers = [(diffuse, np.clip(rho, 0, 1), phi)]
        if rng.random() < 0.5:
            y, x = np.mgrid[0:n, 0:n].astype(np.float32)
            spec = np.zeros((n, n), np.float32)
            for _ in range(int(rng.integers(1, 4))):
                cy, cx = rng.uniform(0, n, 2)
                sig = rng.uniform(n / 80, n / 8)
                spec += rng.uniform(0.2, 1.5) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sig**2))
            light = 1 + rng.uniform(-0.15, 0.15, 3)
            rho_s = np.clip(rng.uniform(0.3, 1.0) + 0.1 * _smooth_field(rng, n, scale=3.0), 0, 1)
            phi_s = phi + np.pi / 2 + rng.uniform(-0.4, 0.4)
            layers.append((spec[..., None] * light.astype(np.float32), rho_s, phi_s))
        region = np.zeros((3, n, n, 3), np.float32)  # the shape hides what lies behind it
        for inten, r, p in layers:
            r3 = np.asarray(r, np.float32)[..., None]
            p3 = np.asarray(p, np.float32)[..., None]
            region[0] += inten
            region[1] += inten * r3 * np.cos(2 * p3)
            region[2] += inten * r3 * np.sin(2 * p3)
        s[:, mask] = region[:, mask]
    s = np.stack([cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA) for c in s])
    blur = rng.uniform(0, 1.0)
    if blur > 0.3:
        s = np.stack([cv2.GaussianBlur(c, (0, 0), blur) for c in s])
    theta = np.deg2rad([0, 45, 90, 135]).astype(np.float32)
    stack = 0.5 * (s[0][None] + np.cos(2 * theta)[:, None, None, None] * s[1][None]
                   + np.sin(2 * theta)[:, None, None, None] * s[2][None])
    stack *= np.float32(rng.uniform(0.4, 1.1) / max(float(np.percentile(stack, 99.5)), 1e-3))
    return np.clip(stack, 0, 1).astype(np.float32)


def noisy_raw(rng: np.random.Generator, raw: np.ndarray) -> np.ndarray:
    """A raw mosaic (values in [0, 1]) with random shot and read noise, half the time quantised to 8 bits."""
    a = rng.uniform(0, 2e-4)
    b = rng.uniform(0, 2e-3) ** 2
    out = raw + rng.normal(size=raw.shape).astype(np.float32) * np.sqrt(a * raw + b).astype(np.float32)
    if rng.random() < 0.5:
        out = np.round(out * 255) / 255
    return out.astype(np.float32)


# ---------------------------------------------------------------------------
# the fit
# ---------------------------------------------------------------------------

def _targets(stack: np.ndarray, channels: int) -> np.ndarray:
    """(4, H, W[, C]) -> (hb, wb, 4 * 16 * C) in (angle, y, x, colour) order."""
    st = stack.reshape(stack.shape[:3] + (channels,))
    k, h, w, c = st.shape
    t = st.reshape(k, h // BLOCK, BLOCK, w // BLOCK, BLOCK, c).transpose(1, 3, 0, 2, 4, 5)
    return t.reshape(h // BLOCK, w // BLOCK, -1)


def accumulate(stacks: Sequence[tuple[np.ndarray, np.ndarray]], lay: Layout
               ) -> tuple[np.ndarray, np.ndarray, int]:
    """Gram matrix X^T X (144, 144) and X^T Y (144, outputs) over (raw, truth) pairs in layout ``lay``."""
    channels = 3 if lay.is_color else 1
    gram = np.zeros((144, 144))
    cross = np.zeros((144, 4 * BLOCK * BLOCK * channels))
    count = 0
    for raw, truth in stacks:
        blocks = to_blocks(raw)
        hb = blocks.shape[0] - 2
        x = block_features(blocks, 0, hb).reshape(-1, 144).astype(np.float64)
        y = _targets(truth, channels)[1:-1, 1:-1].reshape(-1, cross.shape[1]).astype(np.float64)
        gram += x.T @ x
        cross += x.T @ y
        count += x.shape[0]
    return gram, cross, count


def fit_bank(gram: np.ndarray, cross: np.ndarray, lay: Layout, *, ridge: float = 1e-2,
             moments: int = 1) -> np.ndarray:
    """Constrained least-squares filter bank (see the module docstring).

    ``gram`` and ``cross`` come from :func:`accumulate`; ``moments``: the order up to which the
    moments of each lattice's weights about the output pixel vanish (0: none, 1: constraint (3),
    affine images exact; 2: also the second moments, quadratic images exact).

    Returns
    -------
    numpy.ndarray
        (144, 4 * 16 * C) float32 weights.
    """
    channels = 3 if lay.is_color else 1
    lat = lattice_of_taps(lay)
    off = tap_offsets()
    nlat = 4 * channels
    a = gram + ridge * np.trace(gram) / gram.shape[0] * np.eye(gram.shape[0])
    weights = np.zeros(cross.shape)
    ai = lay.angle_index(BLOCK, BLOCK)
    ci = lay.channel_index(BLOCK, BLOCK)
    centre = (NBLOCKS + 1) * BLOCK * BLOCK  # first tap of the centre block (block row 1, column 1)
    for k in range(4):
        for u in range(BLOCK):
            for v in range(BLOCK):
                for c in range(channels):
                    o = ((k * BLOCK + u) * BLOCK + v) * channels + c
                    target = k * channels + c
                    if ai[u, v] * channels + ci[u, v] == target:
                        weights[centre + u * BLOCK + v, o] = 1.0
                        continue
                    rows, rhs = [], []
                    for lt in range(nlat):
                        sel = (lat == lt).astype(np.float64)
                        rows.append(sel)
                        rhs.append(1.0 if lt == target else 0.0)
                        dy, dx = off[:, 0] - u, off[:, 1] - v
                        polys = [dy, dx] if moments >= 1 else []
                        polys += [dy * dy, dy * dx, dx * dx] if moments >= 2 else []
                        for poly in polys:
                            rows.append(sel * poly)
                            rhs.append(0.0)
                    cm = np.array(rows)
                    kkt = np.block([[a, cm.T], [cm, np.zeros((len(rows), len(rows)))]])
                    b = np.concatenate([cross[:, o], rhs])
                    try:
                        sol = np.linalg.solve(kkt, b)
                    except np.linalg.LinAlgError:  # pragma: no cover - dependent constraints
                        sol = np.linalg.lstsq(kkt, b, rcond=None)[0]
                    weights[:, o] = sol[:144]
    return weights.astype(np.float32)


def pattern_stack(rng: np.random.Generator, size: int) -> np.ndarray:
    """One training scene from :mod:`polcam.synth.patterns` (smooth, textured, edges or sweep, the
    colours sharing one polarization), drawn with a seed of at least 1000 (the benchmark reports
    seed 0, the validation set uses seed 1).

    Returns
    -------
    numpy.ndarray
        (4, size, size, 3) float32 in [0, 1], angles 0, 45, 90, 135, RGB.
    """
    name = SCENES[int(rng.integers(0, len(SCENES)))]
    seed = int(rng.integers(1000, 2**31 - 1))
    return make_scene(name, height=size, width=size, seed=seed, color=True).stack


def _sum_scenes(sums: dict[str, list], stacks: Iterator[np.ndarray], rng: np.random.Generator) -> None:
    for i, stack in enumerate(stacks):
        mono = np.tensordot(stack, LUMA, axes=([3], [0])).astype(np.float32)
        for (color, geo), name in CANONICAL.items():
            lay = parse_layout(name)
            truth = stack if color else mono
            raw = noisy_raw(rng, mosaic_stack(truth, layout=lay))
            g, x, n = accumulate([(raw, truth)], lay)
            key = weight_key(color, geo)
            if key in sums:
                sums[key][0] += g
                sums[key][1] += x
                sums[key][2] += n
            else:
                sums[key] = [g, x, n]
        if (i + 1) % 20 == 0:
            sys.stderr.write(f"{i + 1} scenes\n")


def gram_sums(*, scenes: int, size: int, seed: int, patterns: int = 0, photos: int = 0) -> dict[str, list]:
    """Render ``scenes`` scenes of :func:`training_stack` (generator seeded by ``seed``),
    ``patterns`` scenes of :func:`pattern_stack` (their own generator, seeded by ``[seed, 1]``)
    and ``photos`` crops of the training photographs with simulated polarization
    (:func:`polcam.synth.photos.photo_stack` on :data:`~polcam.synth.photos.TRAINING_PHOTOS`,
    generator ``[seed, 2]``), and sum the normal equations of the four banks of
    :data:`CANONICAL`: ``{weight_key: [gram, cross, count]}`` (see :func:`accumulate`).  The sums
    of the three kinds add: ``gram_sums(scenes=a, patterns=b)`` is ``gram_sums(scenes=a)`` plus
    ``gram_sums(scenes=0, patterns=b)``, and likewise for ``photos``."""
    sums: dict[str, list] = {}
    rng = np.random.default_rng(seed)
    _sum_scenes(sums, (training_stack(rng, size) for _ in range(scenes)), rng)
    rng = np.random.default_rng([seed, 1])
    _sum_scenes(sums, (pattern_stack(rng, size) for _ in range(patterns)), rng)
    rng = np.random.default_rng([seed, 2])
    _sum_scenes(sums, (photo_stack(rng, size, photos=TRAINING_PHOTOS) for _ in range(photos)), rng)
    return sums


def fit_all(sums: dict[str, list], *, ridge: float, moments: int = 1) -> dict[str, np.ndarray]:
    """The four banks of :data:`CANONICAL` from :func:`gram_sums`' normal equations."""
    out = {}
    for (color, geo), name in CANONICAL.items():
        key = weight_key(color, geo)
        g, x, _ = sums[key]
        out[key] = fit_bank(g, x, parse_layout(name), ridge=ridge, moments=moments)
    return out


def train(*, scenes: int, size: int, seed: int, ridge: float, moments: int = 1,
          patterns: int = 0, photos: int = 0) -> dict[str, np.ndarray]:
    """Render ``scenes`` scenes (and ``patterns`` pattern scenes, ``photos`` photograph crops) and
    fit the four banks of :data:`CANONICAL`."""
    return fit_all(gram_sums(scenes=scenes, size=size, seed=seed, patterns=patterns, photos=photos),
                   ridge=ridge, moments=moments)


def save_weights(weights: dict[str, np.ndarray], path: Path, *, info: dict) -> None:
    """Write trained weights and how they were made (``info``, stored as JSON) to an ``.npz``, atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, info=np.array(json.dumps(info)), **weights)
