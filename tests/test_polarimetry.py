"""Stokes parameters and the sinusoid fit against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.polarimetry import (
    Stokes,
    aolp,
    dolp,
    fit_residual,
    fit_sinusoid,
    imax,
    imin,
    stokes,
    synthesize,
)


def _malus(s0, rho, theta):
    """Ideal polarizer readings of partially polarized light (Malus + unpolarized half)."""
    t = np.deg2rad(np.array([0.0, 45.0, 90.0, 135.0]))[:, None]
    return 0.5 * s0 * (1 + rho * np.cos(2 * t - 2 * theta))


def test_closed_forms_on_random_partially_polarized_light():
    rng = np.random.default_rng(1)
    s0 = rng.uniform(0.1, 2.0, 500)
    rho = rng.uniform(0, 1, 500)
    theta = rng.uniform(0, np.pi, 500)
    i = _malus(s0, rho, theta)
    s = stokes(i)
    np.testing.assert_allclose(s.s0, s0, rtol=1e-12)
    np.testing.assert_allclose(s.s1, s0 * rho * np.cos(2 * theta), atol=1e-12)
    np.testing.assert_allclose(s.s2, s0 * rho * np.sin(2 * theta), atol=1e-12)
    np.testing.assert_allclose(dolp(i), rho, atol=1e-12)
    d = np.abs((aolp(i) - theta + np.pi / 2) % np.pi - np.pi / 2)
    assert d[rho > 1e-3].max() < 1e-9
    f = fit_sinusoid(i)
    np.testing.assert_allclose(f.ic, s0 / 2)
    np.testing.assert_allclose(f.isv, s0 * rho / 2, atol=1e-12)
    np.testing.assert_allclose(imin(i), s0 / 2 * (1 - rho), atol=1e-12)
    np.testing.assert_allclose(imax(i), s0 / 2 * (1 + rho), atol=1e-12)
    np.testing.assert_allclose(fit_residual(i), 0, atol=1e-12)


def test_fit_is_least_squares_for_noisy_samples():
    # compare against a generic least-squares solve of I = a + b cos 2t + c sin 2t
    rng = np.random.default_rng(2)
    i = rng.uniform(0, 1, (4, 50))
    t = np.deg2rad([0, 45, 90, 135])
    A = np.stack([np.ones(4), np.cos(2 * t), np.sin(2 * t)], axis=1)
    coef, *_ = np.linalg.lstsq(A, i, rcond=None)
    f = fit_sinusoid(i)
    np.testing.assert_allclose(f.ic, coef[0], atol=1e-12)
    np.testing.assert_allclose(f.isv, np.hypot(coef[1], coef[2]), atol=1e-12)
    np.testing.assert_allclose(np.cos(2 * f.phi) * f.isv, coef[1], atol=1e-12)
    np.testing.assert_allclose(np.sin(2 * f.phi) * f.isv, coef[2], atol=1e-12)


def test_aolp_range_and_known_angles():
    for deg in [0, 30, 45, 90, 135, 179.9]:
        i = _malus(np.array([1.0]), 1.0, np.deg2rad(deg))
        a = aolp(i)
        assert 0 <= a[0] < np.pi
        assert np.isclose(np.rad2deg(a[0]), deg % 180, atol=1e-9)
    # tiny negative S2 with positive S1: just below pi wraps into [0, pi)
    a = aolp(Stokes(np.array([1.0]), np.array([1.0]), np.array([-1e-300])))
    assert 0 <= a[0] < np.pi


def test_dark_and_zero_pixels_are_finite():
    i = np.zeros((4, 3, 3, 3), dtype=np.float32)
    with np.errstate(all="raise"):
        d = dolp(i)
        a = aolp(i)
    assert np.all(d == 0) and np.all(np.isfinite(a))
    assert d.dtype == np.float32 and a.dtype == np.float32
    # noise can make S0 < sqrt(S1^2+S2^2): DoLP is clipped to 1
    assert dolp(np.array([[1.0], [0.0], [0.0], [0.0]]))[0] == 1.0


def test_synthesize_inverts_the_fit():
    rng = np.random.default_rng(3)
    ic = rng.uniform(0.2, 0.6, (8, 8, 3))
    isv = rng.uniform(0, 0.2, (8, 8, 3))
    phi = rng.uniform(0, np.pi, (8, 8, 3))
    stack = synthesize(ic, isv, phi)
    assert stack.shape == (4, 8, 8, 3)
    f = fit_sinusoid(stack)
    np.testing.assert_allclose(f.ic, ic)
    np.testing.assert_allclose(f.isv, isv, atol=1e-12)
    np.testing.assert_allclose(synthesize(f.ic, f.isv, f.phi), stack, atol=1e-12)


def test_shapes_and_errors():
    with pytest.raises(ValueError, match="4 angle images"):
        stokes(np.zeros((3, 4, 4)))
    s = stokes(np.ones((4, 5, 6), dtype=np.uint8))
    assert s.s0.dtype == np.float32 and s.s0.shape == (5, 6)


def _real(shared_data, name):
    path = shared_data / "real-imx250mzr" / name
    if not path.exists():
        pytest.skip(f"{path} not available")
    import cv2

    from polcam.demosaicing import demosaic

    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert raw.shape == (2048, 2448)
    return lambda layout: demosaic(raw, layout=layout, resolution="cell")


@pytest.mark.parametrize("name", ["fruits.png", "carps.png"])
def test_real_frames_fit_the_sinusoid_with_the_true_layout(shared_data, name):
    """An ideal polarizer cell gives (I0 + I90) - (I45 + I135) = 0; a layout that pairs the
    wrong pixels does not."""
    stack_of = _real(shared_data, name)

    def median_residual(layout):
        st = stack_of(layout)
        s = stokes(st)
        lit = (s.s0 > 0.3) & (st.max(axis=0) < 0.95)
        assert lit.mean() > 0.05
        return float(np.median(np.abs(fit_residual(st))[lit] / s.s0[lit]))

    rel = median_residual("imx250mzr")
    assert rel < 0.03
    for wrong in ("mono:90,0,45,135", "mono:0,45,90,135"):
        assert median_residual(wrong) > 1.3 * rel


def test_real_matte_scene_is_weakly_polarized(shared_data):
    st = _real(shared_data, "fruits.png")("imx250mzr")
    s = stokes(st)
    d = dolp(s)[(s.s0 > 0.3) & (st.max(axis=0) < 0.95)]
    assert np.median(d) < 0.15            # matte fruit on paper: mostly weakly polarized
    assert np.percentile(d, 99.9) > 0.2    # with a few polarized glints and edges


def test_real_water_reflection_is_polarized_horizontally(shared_data):
    """Light reflected by a (horizontal) water surface is polarized perpendicular to the plane of
    incidence: strong DoLP, AoLP concentrated near the image's horizontal."""
    st = _real(shared_data, "carps.png")("imx250mzr")
    s = stokes(st)
    d, a = dolp(s), aolp(s)
    m = (d > 0.3) & (s.s0 > 0.1)
    assert m.mean() > 0.5
    z = np.exp(2j * a[m]).mean()
    assert abs(z) > 0.8                   # concentrated orientation
    mean_deg = np.rad2deg(np.angle(z) / 2) % 180
    assert min(mean_deg, 180 - mean_deg) < 25


def _reference_maps(i: np.ndarray) -> dict[str, np.ndarray]:
    """The closed forms written out with whole-array numpy, in the stack's dtype."""
    h = i.dtype.type(0.5)
    s0 = (i[0] + i[1] + i[2] + i[3]) * h
    s1, s2 = i[0] - i[2], i[1] - i[3]
    lin = np.hypot(s1, s2)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.clip(np.where(s0 > 0, lin / np.where(s0 > 0, s0, 1), 0), 0, 1)
    a = np.mod(h * np.arctan2(s2, s1), np.pi)
    a = np.where(a >= np.pi, 0, a)
    return {"s0": s0, "s1": s1, "s2": s2, "dolp": d, "aolp": a, "ic": s0 * h, "isv": lin * h,
            "imin": s0 * h - lin * h, "imax": s0 * h + lin * h, "residual": (i[0] + i[2]) - (i[1] + i[3])}


@pytest.mark.parametrize("shape", [(4, 3), (4, 37, 29, 3), (4, 1031, 1033)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fused_maps_equal_the_closed_forms(shape, dtype):
    from polcam import polarimetry

    rng = np.random.default_rng(3)
    i = rng.uniform(-0.05, 1.0, shape).astype(dtype)  # some S0 <= 0: DoLP 0 there
    i[:, :1] = 0.0                                   # dark pixels: S0 = 0, angle of (0, 0)
    got = polarimetry.maps(i, polarimetry.MAPS)
    want = _reference_maps(i)
    ulp = 2 * np.finfo(dtype).eps
    for name, ref in want.items():
        assert got[name].dtype == dtype and got[name].shape == shape[1:], name
        if name == "aolp":  # an orientation: 0 and pi are one
            d = np.abs(got[name] - ref)
            assert np.minimum(d, np.pi - d).max() <= 4 * ulp, name
            assert got[name].min() >= 0 and got[name].max() < np.pi
        else:  # the magnitude is sqrt(x^2 + y^2), within an ulp of hypot
            np.testing.assert_allclose(got[name], ref, rtol=ulp, atol=ulp, err_msg=name)
    assert (got["dolp"][want["s0"] <= 0] == 0).all()
    # one map at a time, and the public functions, give the same arrays
    for name in ("s0", "dolp", "aolp", "imin"):
        np.testing.assert_array_equal(polarimetry.maps(i, [name])[name], got[name])
    np.testing.assert_array_equal(dolp(stokes(i)), got["dolp"])
    np.testing.assert_array_equal(aolp(Stokes(got["s0"], got["s1"], got["s2"])), got["aolp"])
    np.testing.assert_array_equal(imax(i), got["imax"])


def test_fused_maps_refuse_unknown_names():
    from polcam import polarimetry

    with pytest.raises(ValueError, match="unknown maps.*'dolq'"):
        polarimetry.maps(np.zeros((4, 2, 2), np.float32), ["dolq"])


def test_maps_together_equal_separate_calls_with_dtype_and_clip():
    from polcam import polarimetry

    rng = np.random.default_rng(4)
    i = rng.uniform(-0.2, 1.3, (4, 300, 401, 3)).astype(np.float32)  # some values outside [0, 1]
    a, b = polarimetry.maps_together(i, {"names": ("s0", "dolp")},
                                     {"names": ("ic", "isv"), "dtype": np.float64, "clip": (0.0, 1.0)})
    np.testing.assert_array_equal(a["s0"], polarimetry.maps(i, ["s0"])["s0"])
    ref = polarimetry.maps(np.clip(i, 0, 1).astype(np.float64), ["ic", "isv"])
    for k in ("ic", "isv"):
        assert b[k].dtype == np.float64
        np.testing.assert_array_equal(b[k], ref[k])
    assert not np.array_equal(b["ic"], polarimetry.maps(i.astype(np.float64), ["ic"])["ic"])
