"""Training of polarized-residual's learned unpolarized-specular stage on the randomized scene family.

Run ``polcam bench train-residual`` to remake ``polcam/separation/residual_weights.npz``
(a few minutes on two cores).  The scenes are the randomized family's training seeds
(:func:`polcam.synth.family.training_seeds`; validation and test never share one), rendered and
demosaiced as a camera gives them (:func:`polcam.synth.family.render_family`); their albedo
photographs are public domain or CC0, so the weights ship.

For every scene polarized-residual runs without the stage; the target at each pixel of the stage's
zone (:func:`polcam.separation._learned_residual.zone`) is the multiple of ``G`` by which the layer
exceeds the truth, ``s* = clip((D - T) . G / |G|^2, 0, b)`` (``b`` the stage's bound:
:func:`polcam.separation._learned_residual.features`).  The MLP's output ``b clip(z, 0, 1)`` is
fitted to it by L-BFGS (scipy) on the weighted squared error

    sum_p w_p |G|^2 (b_p clip(z_p, 0, 1) - s*_p)^2 + l2 |theta|^2,

with ``w_p = 1 / (N_obj MSE_scene)`` (``MSE_scene`` the layer's error before the stage over the
object, at least 10^-4.5), so each scene weighs as its PSNR's change does, and pixels off the object
(backdrop) weigh 0.3 of that.  A random subset of ``max_samples`` pixels is fitted.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from polcam.io.atomic import atomic_path
from polcam.separation.polarized_residual import LEARNED_FEATURES, learned_inputs
from polcam.synth.family import render_family, training_seeds

__all__ = ["DEFAULT_HIDDEN", "DEFAULT_L2", "DEFAULT_ITERATIONS", "DEFAULT_SAMPLES", "DEFAULT_SCENES", "scene_samples",
           "training_samples", "fit", "train", "save_weights"]

#: Hidden layer widths.
DEFAULT_HIDDEN = (24, 24)
#: Weight of the parameters' squared norm in the loss (the loss is normalised to a mean weight of 1e-3).
DEFAULT_L2 = 1e-4
#: L-BFGS iterations.
DEFAULT_ITERATIONS = 400
#: Training scenes (validation split: 200 scenes 27.36 dB, 400 scenes with 500,000 pixels 27.43).
DEFAULT_SCENES = 400
#: Pixels fitted (a random subset of the zones of all scenes).
DEFAULT_SAMPLES = 500_000
#: Least error (MSE, linear light) a scene's weight is taken at: 45 dB.
_MSE_FLOOR = 10 ** (-45 / 10)
#: Weight of backdrop pixels against the object's.
_BACKDROP = 0.3


def scene_samples(seed: int, *, size: int = 128) -> dict[str, np.ndarray]:
    """One training scene's samples: ``x`` (N, F) float32, ``target``, ``bound``, ``weight`` (N,) float64."""
    sc = render_family(seed, size=size)
    inputs = learned_inputs(sc.stack)
    d, g = np.asarray(inputs["diffuse"], np.float64), np.asarray(inputs["g"], np.float64)
    t = np.asarray(sc.diffuse, np.float64)
    gsq = float((g * g).sum())
    bound = np.asarray(inputs["bound"], np.float64)
    target = np.clip(((d - t) * g).sum(-1) / gsq, 0.0, bound)
    m = sc.mask
    mse = float(((d - t) ** 2).mean(-1)[m].mean()) if m.any() else _MSE_FLOOR
    w = gsq / max(mse, _MSE_FLOOR) / max(int(m.sum()), 1)
    z = np.asarray(inputs["zone"], bool)
    return {"x": np.asarray(inputs["x"]), "target": target[z], "bound": bound[z],
            "weight": np.where(m[z], w, _BACKDROP * w)}


def training_samples(n: int, *, size: int = 128, start: int = 0, max_samples: int = DEFAULT_SAMPLES,
                     seed: int = 0) -> dict[str, np.ndarray]:
    """The samples of ``n`` training scenes, a random subset of at most ``max_samples`` pixels."""
    parts = [scene_samples(sd, size=size) for sd in training_seeds(n, start=start)]
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    keep = np.random.default_rng(seed).random(len(out["target"])) < min(1.0, max_samples / max(len(out["target"]), 1))
    return {k: v[keep] for k, v in out.items()}


def _shapes(n_in: int, hidden: tuple[int, ...]) -> Iterator[tuple[tuple[int, int], tuple[int]]]:
    sizes = (n_in, *hidden, 1)
    for a, b in zip(sizes[:-1], sizes[1:]):
        yield (a, b), (b,)


def _unpack(p: np.ndarray, shapes: list[tuple[tuple[int, int], tuple[int]]]) -> list[np.ndarray]:
    out, i = [], 0
    for ws, bs in shapes:
        n = ws[0] * ws[1]
        out += [p[i:i + n].reshape(ws), p[i + n:i + n + bs[0]]]
        i += n + bs[0]
    return out


def fit(samples: dict[str, np.ndarray], *, hidden: tuple[int, ...] = DEFAULT_HIDDEN, l2: float = DEFAULT_L2,
        iterations: int = DEFAULT_ITERATIONS, seed: int = 0) -> dict[str, np.ndarray]:
    """Fit the MLP to ``samples`` (:func:`training_samples`); returns the weights' arrays.

    Returns ``layers``, ``mu``, ``sd`` (the features' normalisation) and ``w0``, ``b0``, ... float64,
    as :func:`polcam.separation._learned_residual.forward` reads them.
    """
    x = np.asarray(samples["x"], np.float64)
    y, bound = samples["target"], samples["bound"]
    wt = samples["weight"] / samples["weight"].sum() * len(y) / 1e3
    mu, sd = x.mean(0), x.std(0) + 1e-6
    xn = (x - mu) / sd
    shapes = list(_shapes(x.shape[1], tuple(hidden)))
    rng = np.random.default_rng(seed)
    p0 = np.concatenate([np.concatenate([rng.normal(0, 1 / np.sqrt(ws[0]), ws[0] * ws[1]), np.zeros(bs[0])])
                         for ws, bs in shapes])

    def loss_grad(p: np.ndarray) -> tuple[float, np.ndarray]:
        ws = _unpack(p, shapes)
        hs = [xn]
        for j in range(0, len(ws) - 2, 2):
            hs.append(np.tanh(hs[-1] @ ws[j] + ws[j + 1]))
        z = (hs[-1] @ ws[-2] + ws[-1])[:, 0]
        r = bound * np.clip(z, 0.0, 1.0) - y
        loss = float((wt * r * r).sum() + l2 * (p * p).sum())
        delta = (2 * wt * r * bound * ((z > 0) & (z < 1)))[:, None]
        grads: list[np.ndarray] = []
        for j in range(len(ws) - 2, -1, -2):
            grads = [hs[j // 2].T @ delta, delta.sum(0)] + grads
            if j > 0:
                delta = (delta @ ws[j].T) * (1 - hs[j // 2] ** 2)
        return loss, np.concatenate([g.ravel() for g in grads]) + 2 * l2 * p

    from scipy.optimize import minimize  # scipy.optimize only for training

    res = minimize(loss_grad, p0, jac=True, method="L-BFGS-B", options={"maxiter": int(iterations)})
    ws = _unpack(res.x, shapes)
    out = {"layers": np.array(len(shapes)), "mu": mu, "sd": sd, "loss": np.array(res.fun)}
    for i in range(len(shapes)):
        out[f"w{i}"], out[f"b{i}"] = ws[2 * i], ws[2 * i + 1]
    return out


def train(n: int = DEFAULT_SCENES, *, size: int = 128, start: int = 0, max_samples: int = DEFAULT_SAMPLES,
          hidden: tuple[int, ...] = DEFAULT_HIDDEN, l2: float = DEFAULT_L2,
          iterations: int = DEFAULT_ITERATIONS, seed: int = 0) -> dict[str, np.ndarray]:
    """Render ``n`` training scenes and fit the model (:func:`training_samples`, :func:`fit`)."""
    samples = training_samples(n, size=size, start=start, max_samples=max_samples, seed=seed)
    return fit(samples, hidden=hidden, l2=l2, iterations=iterations, seed=seed)


def save_weights(weights: dict[str, np.ndarray], path: Path, *, info: dict[str, Any]) -> None:
    """Write the weights, the feature names and how they were made (``info``, JSON) to an ``.npz``, atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, info=np.array(json.dumps(info)), features=np.array(json.dumps(list(LEARNED_FEATURES))),
                                **weights)
