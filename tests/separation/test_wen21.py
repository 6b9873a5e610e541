"""wen21 against synthetic polarization scenes with known diffuse layers.

Wen'21 publishes no reference figures we could compare with, so the scenes are
built here from the model the method assumes, with the ground truth kept:
Lambertian-shaded spheres of a few albedos (diffuse, unpolarized) under one
light, plus a specular lobe of the illuminant colour that is partially
polarized (DoLP rising smoothly from ``rho_range[0]`` at the centre of a sphere
to ``rho_range[1]`` near its rim, AoLP perpendicular to the plane of incidence).
A polarizer at angle t sees ``I(t) = D + S/2 (1 + rho cos(2t - 2 phi))``; the
mean over the four angles is ``D + S/2``, so the true diffuse layer on
polcam's scale (one polarization image) is ``D`` and the true specular ``S/2``.

Run this file as a script to print the PSNR table of docs/methods/wen21.md:
``.venv/bin/python tests/separation/test_wen21.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from polcam.errors import MethodError
from polcam.polarimetry import fit_sinusoid
from polcam.separation import method_spec, methods, separate
from polcam.separation.wen21 import (
    kmeans,
    polarization_chromaticity,
    polarization_illuminant,
    rpca_ialm,
    separate_wen21,
)

ALBEDOS = ((0.8, 0.25, 0.2), (0.2, 0.7, 0.3), (0.25, 0.35, 0.85), (0.75, 0.7, 0.2))
GREYS = ((0.6, 0.6, 0.6), (0.35, 0.35, 0.35), (0.8, 0.8, 0.8), (0.5, 0.5, 0.5))


def _scene(n: int = 64, *, rho_range: tuple[float, float] = (0.3, 0.9), noise: float = 0.0,
           seed: int = 0, spec_gain: float = 0.6, shininess: float = 30.0,
           albedos: tuple[tuple[float, float, float], ...] = ALBEDOS,
           background: tuple[float, float, float] = (0.35, 0.3, 0.3),
           light: tuple[float, float, float] = (0.4, -0.5, 0.77),
           illuminant: tuple[float, float, float] = (1.0, 1.0, 1.0),
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Four spheres on a flat background.

    Returns
    -------
    stack : (4, n, n, 3) float64 in [0, 1], angles 0, 45, 90, 135
    diffuse : (n, n, 3) the true diffuse layer D
    specular : (n, n, 3) the true specular layer S/2 (before clipping)
    """
    yy, xx = np.mgrid[0:n, 0:n] + 0.5
    e = np.asarray(illuminant, dtype=np.float64)
    diffuse = np.broadcast_to(0.5 * np.asarray(background) * e, (n, n, 3)).copy()
    spec = np.zeros((n, n))
    rho = np.zeros((n, n))
    phi = np.zeros((n, n))
    lvec = np.asarray(light, dtype=np.float64)
    lvec /= np.linalg.norm(lvec)
    half = lvec + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    radius = n / 4.4
    centres = [(cy, cx) for cy in (n / 4, 3 * n / 4) for cx in (n / 4, 3 * n / 4)]
    for k, (cy, cx) in enumerate(centres):
        u, v = (xx - cx) / radius, (yy - cy) / radius
        inside = u * u + v * v < 1
        nz = np.sqrt(np.clip(1 - u * u - v * v, 0, 1))
        normal = np.stack([u, v, nz], axis=-1)
        shade = np.clip(normal @ lvec, 0, 1)
        albedo = np.asarray(albedos[k % len(albedos)]) * e
        diffuse[inside] = (albedo * (0.1 + 0.8 * shade[..., None]))[inside]
        spec[inside] = (np.clip(normal @ half, 0, 1) ** shininess)[inside]
        zenith = np.arccos(nz)
        r = rho_range[0] + (rho_range[1] - rho_range[0]) * np.clip(zenith / (np.pi / 2.5), 0, 1)
        rho[inside] = r[inside]
        phi[inside] = (np.mod(np.arctan2(v, u) + np.pi / 2, np.pi))[inside]
    s = spec_gain * spec
    t = np.deg2rad([0.0, 45.0, 90.0, 135.0])[:, None, None]
    spec_t = (s / 2)[None] * (1 + rho[None] * np.cos(2 * t - 2 * phi[None]))
    stack = diffuse[None] + spec_t[..., None] * e
    if noise:
        stack = stack + np.random.default_rng(seed).normal(0.0, noise, stack.shape)
    return np.clip(stack, 0.0, 1.0), diffuse, (s / 2)[..., None] * e


def _psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(estimate, np.float64) - truth) ** 2))
    return 10.0 * np.log10(1.0 / mse)


# name -> scene options; the PSNR table in the docs lists the same scenes (at 96 x 96)
SCENES = {
    "partially polarized, noise 0.005": dict(noise=0.005),
    "weakly polarized lobe (DoLP 0.3-0.5)": dict(rho_range=(0.3, 0.5)),
    "strongly polarized lobe (DoLP 0.7-0.9)": dict(rho_range=(0.7, 0.9)),
    "warm illuminant (1, 0.8, 0.55)": dict(illuminant=(1.0, 0.8, 0.55)),
    "broad lobe (shininess 8)": dict(shininess=8.0),
    "other light and albedos, noise 0.003": dict(
        albedos=((0.5, 0.2, 0.6), (0.9, 0.6, 0.3), (0.3, 0.6, 0.7), (0.6, 0.6, 0.55)),
        background=(0.2, 0.25, 0.2), light=(-0.3, 0.2, 0.93), shininess=20.0,
        noise=0.003, seed=5),
}


def _scores(stack: np.ndarray, diffuse: np.ndarray, **options) -> tuple[float, float, float]:
    wen = separate(stack, method="wen21", **options)
    imin = separate(stack, method="imin")
    return (_psnr(stack.mean(axis=0), diffuse), _psnr(imin.diffuse, diffuse),
            _psnr(wen.diffuse, diffuse))


# --- quality on synthetic scenes with known diffuse ---------------------------------


@pytest.mark.parametrize("name", list(SCENES))
def test_recovers_diffuse_better_than_mean_and_imin(name):
    stack, diffuse, _ = _scene(64, **SCENES[name])
    p_mean, p_imin, p_wen = _scores(stack, diffuse)
    # imin leaves the unpolarized share (1 - rho) S/2 of the lobe in the diffuse layer;
    # wen21 removes it: a clear margin over imin, and far above the raw mean
    assert p_imin > p_mean
    assert p_wen > p_imin + 3.0, (p_mean, p_imin, p_wen)


def test_grey_surfaces_no_worse_than_imin():
    # Grey albedo under white light: specular and diffuse have one colour (Wen'21's
    # "near-duplicate" case), so only the polarization bound separates them.
    stack, diffuse, _ = _scene(64, albedos=GREYS, background=(0.4, 0.4, 0.4), noise=0.003)
    _, p_imin, p_wen = _scores(stack, diffuse)
    assert p_wen >= p_imin - 0.1, (p_imin, p_wen)


def test_leaves_specular_free_pixels_alone():
    stack, diffuse, specular = _scene(64)
    res = separate(stack, method="wen21")
    free = specular.max(axis=-1) < 1e-4
    assert free.mean() > 0.5
    err = np.abs(res.diffuse - diffuse)[free]
    assert err.mean() < 1e-4 and np.percentile(err, 99) < 1e-3


def test_removes_specular_in_the_lobe():
    stack, diffuse, specular = _scene(64)
    res = separate(stack, method="wen21")
    lobe = specular.max(axis=-1) > 0.05
    assert lobe.sum() > 20
    # the specular layer found in the lobe is close to the true one (S/2)
    rel = np.abs(res.specular[lobe] - specular[lobe]).mean() / specular[lobe].mean()
    assert rel < 0.1, rel


def test_saturated_highlights_stay_finite_and_in_range():
    stack, diffuse, _ = _scene(64, spec_gain=2.0)
    assert (stack >= 1.0).any()  # the lobe clips
    res = separate(stack, method="wen21")
    mean = stack.mean(axis=0)
    assert np.isfinite(res.diffuse).all()
    assert (res.diffuse >= 0).all() and (res.diffuse <= mean + 1e-6).all()
    assert _psnr(res.diffuse, diffuse) > _psnr(separate(stack, method="imin").diffuse, diffuse)


def test_recovers_illuminant_colour_from_polarization():
    e = np.array([1.0, 0.8, 0.55])
    stack, _, _ = _scene(64, illuminant=tuple(e), spec_gain=0.3)
    assert stack.max() < 1.0  # no clipping: Isv is exactly rho S/2 times the illuminant
    fit = fit_sinusoid(stack)
    np.testing.assert_allclose(polarization_illuminant(fit.isv), e / e.mean(), rtol=1e-9)
    res = separate(stack, method="wen21")
    np.testing.assert_allclose(res.info["illuminant"], e / e.mean(), rtol=1e-9)


def test_white_illuminant_option_is_worse_under_coloured_light():
    stack, diffuse, _ = _scene(64, illuminant=(1.0, 0.8, 0.55))
    p_pol = _psnr(separate(stack, method="wen21").diffuse, diffuse)
    p_white = _psnr(separate(stack, method="wen21", illuminant="white").diffuse, diffuse)
    p_given = _psnr(separate(stack, method="wen21", illuminant=(1.0, 0.8, 0.55)).diffuse, diffuse)
    assert p_pol > p_white + 3.0
    assert abs(p_pol - p_given) < 0.5


# --- the scale contract, shapes, dtype, determinism ---------------------------------


def test_scale_contract_shapes_and_dtype():
    stack, _, _ = _scene(48, noise=0.01, seed=2)
    res = separate(stack, method="wen21")
    mean = stack.mean(axis=0)
    assert res.diffuse.shape == res.specular.shape == (48, 48, 3)
    assert res.diffuse.dtype == res.specular.dtype == np.float32
    np.testing.assert_allclose(res.diffuse + res.specular, mean, atol=1e-6)
    assert (res.diffuse >= 0).all() and (res.specular >= 0).all()
    assert res.info["method"] == "wen21" and res.info["seconds"] >= 0
    assert isinstance(res.info["iterations"], int) and res.info["iterations"] >= 1
    assert res.info["converged"] is True
    assert res.info["clusters"] == 8


def test_diffuse_never_above_polarization_minimum():
    stack, _, _ = _scene(48, noise=0.01, seed=3)
    diffuse, _ = separate_wen21(stack)
    fit = fit_sinusoid(stack)
    assert diffuse.shape == (48, 48, 3) and diffuse.dtype == np.float64
    bound = np.maximum(fit.ic - fit.isv, 0.0)  # Imin, which noise can push below 0
    assert (diffuse <= bound + 1e-12).all() and (diffuse >= 0).all()
    assert (diffuse < bound - 1e-3).any()  # and it does go below Imin


def test_exposure_invariance():
    # every term of the objective scales with the image (lam and the prior's weight
    # are normalised), so halving the exposure halves the diffuse layer
    stack, _, _ = _scene(48, noise=0.005, seed=4)
    full, _ = separate_wen21(stack)
    half, _ = separate_wen21(0.5 * stack)
    np.testing.assert_allclose(half, 0.5 * full, atol=1e-6)


def test_deterministic_for_a_seed():
    stack, diffuse, _ = _scene(48, noise=0.01, seed=1)
    a = separate(stack, method="wen21", seed=7)
    b = separate(stack, method="wen21", seed=7)
    np.testing.assert_array_equal(a.diffuse, b.diffuse)
    assert a.info["iterations"] == b.info["iterations"]
    # another seed gives another clustering but the same quality
    c = separate(stack, method="wen21", seed=8)
    assert abs(_psnr(c.diffuse, diffuse) - _psnr(a.diffuse, diffuse)) < 1.5


def test_registered():
    assert "wen21" in methods()
    spec = method_spec("wen21")
    assert spec.kind == "stack" and not spec.mono
    assert "Wen" in spec.reference and "2021" in spec.reference


# --- bad input -----------------------------------------------------------------------


def test_mono_stack_refused():
    with pytest.raises(MethodError, match="needs colour"):
        separate(np.full((4, 8, 8), 0.5), method="wen21")


def test_single_image_refused():
    with pytest.raises(MethodError, match=r"needs a \(4, H, W, 3\) polarization stack"):
        separate(np.full((8, 8, 3), 0.5), method="wen21")


def test_direct_call_with_wrong_shape_refused():
    with pytest.raises(MethodError, match=r"wen21: stack of shape \(3, 8, 8, 3\)"):
        separate_wen21(np.zeros((3, 8, 8, 3)))


@pytest.mark.parametrize("options, word", [
    (dict(clusters=0), "clusters=0"),
    (dict(clusters=2.5), "clusters=2.5"),
    (dict(seed=-1), "seed=-1"),
    (dict(beta=-1.0), "beta=-1.0"),
    (dict(lam_scale=0), "lam_scale=0"),
    (dict(tol=float("nan")), "tol=nan"),
    (dict(max_iter=0), "max_iter=0"),
    (dict(illuminant="blue"), "illuminant='blue'"),
    (dict(illuminant=(1.0, 0.0, 1.0)), "illuminant="),
])
def test_bad_options_refused(options, word):
    with pytest.raises(MethodError, match=word.replace("(", r"\(").replace(")", r"\)")):
        separate(np.full((4, 8, 8, 3), 0.5), method="wen21", **options)


# --- degenerate images: never NaN, never out of range, no warnings -------------------


def test_all_zero_input():
    res = separate(np.zeros((4, 16, 16, 3)), method="wen21")
    assert (res.diffuse == 0).all() and (res.specular == 0).all()


def test_uniform_unpolarized_image_is_all_diffuse():
    # no polarization and one colour: nothing is sparse, S = 0 is optimal
    # (moving s from every row lowers ||L||_* by at most sqrt(3 n) s but costs 3 n lam s)
    for colour in ((0.4, 0.4, 0.4), (0.7, 0.3, 0.1)):
        stack = np.broadcast_to(np.asarray(colour), (4, 12, 12, 3)).copy()
        res = separate(stack, method="wen21")
        np.testing.assert_allclose(res.diffuse, stack[0], atol=1e-6)


@pytest.mark.parametrize("kind", ["saturated", "dark", "noise", "one-pixel", "one-channel"])
def test_degenerate_images(kind):
    rng = np.random.default_rng(0)
    stack = {
        "saturated": np.ones((4, 16, 16, 3)),
        "dark": rng.uniform(0, 1e-5, (4, 16, 16, 3)),
        "noise": rng.uniform(0, 1, (4, 24, 24, 3)),
        "one-pixel": rng.uniform(0, 1, (4, 1, 1, 3)),
        "one-channel": np.stack([rng.uniform(0, 1, (4, 16, 16)),
                                 np.zeros((4, 16, 16)), np.zeros((4, 16, 16))], axis=-1),
    }[kind]
    res = separate(stack, method="wen21")
    mean = stack.mean(axis=0).astype(np.float32)
    assert np.isfinite(res.diffuse).all() and np.isfinite(res.specular).all()
    assert (res.diffuse >= 0).all() and (res.diffuse <= mean).all()
    assert (res.specular >= 0).all()
    fit = fit_sinusoid(stack)
    assert (res.diffuse <= np.maximum(fit.ic - fit.isv, 0.0) + 1e-6).all()


# --- the building blocks --------------------------------------------------------------


def test_polarization_chromaticity_closed_form():
    ic = np.array([[0.5, 0.3, 0.2], [0.1, 0.1, 0.1]])
    isv = np.array([[0.05, 0.05, 0.05], [0.0, 0.0, 0.1]])
    # raw_d = max(ic - 2 isv, 0) = [0.4, 0.2, 0.1] and [0.1, 0.1, 0]
    # mean over pixels of min_RGB ic = (0.2 + 0.1) / 2 = 0.15
    expected = np.array([[0.4, 0.2, 0.1], [0.1, 0.1, 0.0]])
    expected /= np.array([[0.7 + 0.15], [0.2 + 0.15]])
    np.testing.assert_allclose(polarization_chromaticity(ic, isv), expected, rtol=1e-12)
    assert (polarization_chromaticity(np.zeros((2, 3)), np.zeros((2, 3))) == 0).all()
    with pytest.raises(MethodError, match="expected two equal"):
        polarization_chromaticity(np.zeros((2, 3)), np.zeros((2, 2)))


def test_kmeans_finds_separated_groups():
    rng = np.random.default_rng(0)
    centres = np.array([[0.1, 0.1, 0.1], [0.6, 0.2, 0.1], [0.1, 0.5, 0.3]])
    truth = rng.integers(0, 3, 3000)
    x = centres[truth] + rng.normal(0, 0.01, (3000, 3))
    labels, found = kmeans(x, 3, rng=np.random.default_rng(1))
    # the same partition up to relabelling
    pairs = set(zip(truth.tolist(), labels.tolist()))
    assert len(pairs) == 3
    np.testing.assert_allclose(np.sort(found, axis=0), np.sort(centres, axis=0), atol=2e-3)
    # fewer distinct points than clusters requested
    labels, found = kmeans(np.repeat(centres[:2], 50, axis=0), 5, rng=np.random.default_rng(0))
    assert len(found) == 2 and set(labels.tolist()) == {0, 1}


def test_rpca_exact_recovery():
    # Candes, Li, Ma & Wright (2011): a random rank-3 matrix plus 5 % gross errors is
    # recovered exactly with lam = 1 / sqrt(max(n1, n2))
    rng = np.random.default_rng(3)
    low = rng.normal(size=(200, 3)) @ rng.normal(size=(3, 80)) / np.sqrt(3)
    sparse = np.zeros_like(low)
    mask = rng.uniform(size=low.shape) < 0.05
    sparse[mask] = rng.choice([-1.0, 1.0], mask.sum()) * rng.uniform(1, 5, mask.sum())
    res = rpca_ialm(low + sparse)
    assert res.converged and res.iterations < 60
    assert np.linalg.norm(res.low_rank - low) / np.linalg.norm(low) < 1e-5
    assert np.abs(res.sparse - sparse).max() < 1e-4


def test_rpca_with_direction_recovers_dichromatic_pixels():
    # n pixels of one diffuse colour with white specular on 2 % of them: the plain
    # RPCA of an (n, 3) matrix cannot tell extra diffuse from specular, the
    # direction constraint (specular rows = s * (1, 1, 1), s >= 0) can
    rng = np.random.default_rng(4)
    n = 4000
    low = np.outer(rng.uniform(0.1, 1.0, n), [0.7, 0.3, 0.2])
    sparse = np.zeros((n, 3))
    idx = rng.choice(n, 80, replace=False)
    sparse[idx] = rng.uniform(0.1, 0.5, (80, 1))
    m = low + sparse
    res = rpca_ialm(m, direction=np.ones(3), lower=0.0, upper=m)
    assert res.converged
    np.testing.assert_allclose(res.sparse, sparse, atol=1e-4)
    rows = res.sparse
    np.testing.assert_allclose(rows - rows[:, :1], 0.0, atol=1e-12)  # along (1, 1, 1)
    plain = rpca_ialm(m)
    assert np.abs(plain.sparse - sparse).max() > 0.1


def test_rpca_quadratic_prior_dominates_when_heavy():
    # beta -> infinity pins S to the prior (inside the bounds), whatever the l1 term says
    rng = np.random.default_rng(6)
    m = rng.uniform(0.2, 1.0, (300, 3))
    prior = 0.3 * m
    res = rpca_ialm(m, prior=prior, beta=1e6, lower=0.0, upper=m)
    assert res.converged
    np.testing.assert_allclose(res.sparse, prior, atol=1e-4)
    np.testing.assert_allclose(res.low_rank, m - prior, atol=1e-4)


def test_rpca_bounds_and_zero_matrix():
    rng = np.random.default_rng(5)
    m = rng.uniform(0, 1, (200, 3))
    lo = 0.1 * m
    res = rpca_ialm(m, lower=lo, upper=m)
    assert (res.sparse >= lo - 1e-15).all() and (res.sparse <= m + 1e-15).all()
    z = rpca_ialm(np.zeros((5, 3)))
    assert (z.low_rank == 0).all() and (z.sparse == 0).all() and z.converged
    with pytest.raises(MethodError, match="expected 2-D"):
        rpca_ialm(np.zeros(5))
    with pytest.raises(MethodError, match="positive values"):
        rpca_ialm(m, direction=np.array([1.0, 0.0, 1.0]))


def test_converges_on_a_256_scene():
    # speed is measured in docs/benchmarks.md, not asserted here
    stack, _, _ = _scene(256, noise=0.005)
    res = separate(stack, method="wen21")
    assert res.info["converged"]


# Scenes that played no part in choosing the defaults (docs/methods/wen21.md).
HELD_OUT = {
    "held-out 1: other albedos and light, gain 0.9, noise 0.004": dict(
        albedos=((0.9, 0.5, 0.4), (0.4, 0.4, 0.8), (0.5, 0.8, 0.8), (0.3, 0.3, 0.25)),
        light=(0.1, 0.6, 0.79), spec_gain=0.9, shininess=15.0, noise=0.004, seed=11),
    "held-out 2: DoLP 0.2-0.6, sharp lobe, noise 0.002": dict(
        albedos=((0.7, 0.7, 0.65), (0.6, 0.3, 0.3), (0.2, 0.5, 0.2), (0.9, 0.9, 0.3)),
        light=(-0.5, -0.4, 0.77), spec_gain=0.5, shininess=50.0, noise=0.002, seed=12,
        rho_range=(0.2, 0.6)),
    "held-out 3: two albedos, bluish light, gain 1, noise 0.006": dict(
        albedos=((0.3, 0.5, 0.9), (0.8, 0.4, 0.2)), light=(0.3, 0.3, 0.9), spec_gain=1.0,
        shininess=12.0, noise=0.006, seed=13, illuminant=(0.9, 1.0, 1.1)),
}


def _print_tables() -> None:
    """The PSNR tables of docs/methods/wen21.md."""
    tuned = dict(SCENES)
    tuned["grey albedos, noise 0.003"] = dict(albedos=GREYS, background=(0.4, 0.4, 0.4),
                                              noise=0.003)
    tuned["saturated lobe (gain 2)"] = dict(spec_gain=2.0)
    for title, scenes in (("scenes used to choose the defaults", tuned),
                          ("held-out scenes", HELD_OUT)):
        print(f"\n{title}\n")
        print("| scene (96 x 96) | input mean | imin | wen21 | wen21 iterations |")
        print("|---|---|---|---|---|")
        for scene_name, scene_options in scenes.items():
            st, dif, _ = _scene(96, **scene_options)
            r = separate(st, method="wen21")
            pm, pi, pw = _scores(st, dif)
            print(f"| {scene_name} | {pm:.2f} | {pi:.2f} | {pw:.2f} | {r.info['iterations']} |")
    # the defaults against their neighbours, PSNR (dB) over each set of scenes
    sets = {name: [_scene(96, **o)[:2] for o in scenes.values()]
            for name, scenes in (("tuning", tuned), ("held-out", HELD_OUT))}
    variants = [dict(), dict(clusters=4), dict(clusters=6), dict(clusters=12), dict(clusters=16),
                dict(beta=0.0), dict(beta=0.3), dict(beta=3.0), dict(lam_scale=0.6),
                dict(lam_scale=0.7), dict(lam_scale=0.85), dict(lam_scale=1.4),
                dict(illuminant="white")] + [dict(seed=k) for k in range(1, 5)]
    print("\n| options | tuning mean | tuning min | held-out mean | held-out min |")
    print("|---|---|---|---|---|")
    for opts in variants:
        cells = []
        for pairs in sets.values():
            ps = [_psnr(separate(st, method="wen21", **opts).diffuse, dif) for st, dif in pairs]
            cells += [f"{np.mean(ps):.2f}", f"{np.min(ps):.2f}"]
        label = ", ".join(f"{k}={v!r}" for k, v in opts.items()) or "defaults"
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    _print_tables()


def test_a_given_fit_is_used_and_checked():
    from polcam.errors import MethodError
    from polcam.polarimetry import fit_sinusoid
    from polcam.separation.wen21 import separate_wen21

    rng = np.random.default_rng(11)
    stack = rng.uniform(0.0, 1.0, (4, 20, 24, 3)).astype(np.float32)
    d0, _ = separate_wen21(stack)
    fit = fit_sinusoid(stack, dtype=np.float64)
    d1, _ = separate_wen21(stack, fit=fit)
    np.testing.assert_array_equal(d0, d1)
    other = fit_sinusoid(stack[:, ::-1], dtype=np.float64)  # another image's fit changes the answer
    assert not np.array_equal(separate_wen21(stack, fit=other)[0], d0)
    with pytest.raises(MethodError, match=r"fit of shapes \(20, 23, 3\)"):
        separate_wen21(stack, fit=fit_sinusoid(stack[:, :, :23], dtype=np.float64))
