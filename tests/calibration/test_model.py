"""Tests of polcam.calibration.model: forward model, analysis and correction matrices."""

from __future__ import annotations

import numpy as np
import pytest

from polcam.calibration.model import (
    analysis_matrices,
    cell_view,
    correction_matrices,
    diattenuation_to_extinction,
    extinction_to_diattenuation,
    forward,
    from_cells,
    ideal_rows,
    measurement_rows,
    model_from_coefficients,
    nominal_orientation,
    residual_signs,
)
from polcam.mosaic import parse_layout
from polcam.polarimetry import fit_residual, stokes

ANG = np.array([0.0, 45.0, 90.0, 135.0])


def test_extinction_diattenuation_round_trip_and_known_values():
    # ER 50 -> 49/51, ER 300 -> 299/301 (definition D = (ER-1)/(ER+1))
    assert extinction_to_diattenuation(50.0) == pytest.approx(49 / 51)
    assert extinction_to_diattenuation(300.0) == pytest.approx(299 / 301)
    er = np.array([1.0, 2.0, 50.0, 300.0])
    np.testing.assert_allclose(diattenuation_to_extinction(extinction_to_diattenuation(er)), er, rtol=1e-12)
    assert np.isinf(diattenuation_to_extinction(1.0))


def test_ideal_pixels_reproduce_polcam_stokes_conventions():
    rng = np.random.default_rng(0)
    s0 = rng.uniform(0.2, 1.0, 50)
    p = rng.uniform(0, 1, 50)
    a = rng.uniform(0, np.pi, 50)
    s1, s2 = s0 * p * np.cos(2 * a), s0 * p * np.sin(2 * a)
    stack = np.stack([forward((s0, s1, s2), 1.0, 1.0, t) for t in ANG])
    st = stokes(stack)
    np.testing.assert_allclose(st.s0, s0, rtol=1e-12)
    np.testing.assert_allclose(st.s1, s1, atol=1e-12)
    np.testing.assert_allclose(st.s2, s2, atol=1e-12)
    # Malus: I(t) = S0/2 (1 + p cos(2t - 2a))
    np.testing.assert_allclose(stack[1], s0 / 2 * (1 + p * np.cos(np.pi / 2 - 2 * a)), atol=1e-12)


def test_forward_model_with_imperfections_matches_transmission_formula():
    # a polarizer of diattenuation D at theta transmits g/2 S0 (1 + D p cos(2a - 2theta)) + d
    g, d_, th, dark = 1.07, 0.97, 47.0, 12.5
    s0, p, a = 0.8, 0.6, np.deg2rad(30.0)
    i = forward((s0, s0 * p * np.cos(2 * a), s0 * p * np.sin(2 * a)), g, d_, th, dark)
    want = g / 2 * s0 * (1 + d_ * p * np.cos(2 * a - 2 * np.deg2rad(th))) + dark
    assert i == pytest.approx(want, rel=1e-12)


def test_model_from_coefficients_inverts_the_sinusoid():
    g, d_, th, s0 = 0.93, 0.985, 133.2, 0.9
    c0 = g * s0 / 2
    c1 = c0 * d_ * np.cos(2 * np.deg2rad(th))
    c2 = c0 * d_ * np.sin(2 * np.deg2rad(th))
    scale, dia, theta = model_from_coefficients(c0, c1, c2)
    assert scale == pytest.approx(g * s0)
    assert dia == pytest.approx(d_)
    assert theta == pytest.approx(th)
    # a partially polarized source: the fitted amplitude is divided by its DoLP
    _, dia2, _ = model_from_coefficients(c0, 0.9 * c1, 0.9 * c2, source_dolp=0.9)
    assert dia2 == pytest.approx(d_)
    # zero signal gives D = 0, no warning
    assert model_from_coefficients(0.0, 0.0, 0.0)[1] == 0.0


def test_cell_view_round_trip_and_order():
    a = np.arange(6 * 8).reshape(6, 8)
    cells = cell_view(a)
    assert cells.shape == (3, 4, 4)
    # cell (1, 2) covers rows 2-3, cols 4-5: order r0c0, r0c1, r1c0, r1c1
    np.testing.assert_array_equal(cells[1, 2], [a[2, 4], a[2, 5], a[3, 4], a[3, 5]])
    np.testing.assert_array_equal(from_cells(cells), a)
    rgb = np.arange(4 * 4 * 3).reshape(4, 4, 3)
    np.testing.assert_array_equal(from_cells(cell_view(rgb)), rgb)


def test_nominal_orientation_and_residual_signs_follow_the_layout():
    lay = parse_layout("imx250mzr")  # 90 45 / 135 0
    np.testing.assert_array_equal(nominal_orientation(lay, 2, 2), [[90, 45], [135, 0]])
    np.testing.assert_array_equal(residual_signs(ANG), [1, -1, 1, -1])


def test_analysis_matrix_is_the_pseudo_inverse():
    rng = np.random.default_rng(1)
    g = rng.uniform(0.9, 1.1, (5, 4))
    d = rng.uniform(0.95, 1.0, (5, 4))
    th = ANG + rng.normal(0, 2, (5, 4))
    rows = measurement_rows(g, d, th)
    a = analysis_matrices(rows)
    for k in range(5):
        np.testing.assert_allclose(a[k], np.linalg.pinv(rows[k]), atol=1e-12)
    # ideal sensor: the analysis matrix of polcam.polarimetry
    a_ideal = analysis_matrices(ideal_rows(ANG))
    np.testing.assert_allclose(a_ideal, [[0.5, 0.5, 0.5, 0.5], [1, 0, -1, 0], [0, 1, 0, -1]], atol=1e-12)


def test_degenerate_rows_need_a_fallback():
    rows = measurement_rows(np.array([0.0, 1, 1, 1]), 1.0, ANG)
    rows[..., :] = 0.0  # all pixels dead
    with pytest.raises(ValueError):
        analysis_matrices(rows)
    a = analysis_matrices(rows, fallback=ideal_rows(ANG))
    np.testing.assert_allclose(a, np.linalg.pinv(ideal_rows(ANG)), atol=1e-12)


def test_correction_matrix_is_identity_for_an_ideal_sensor():
    m = correction_matrices(ideal_rows(ANG), ANG)
    np.testing.assert_allclose(m, np.eye(4), atol=1e-12)
    # in a mosaic cell order too (imx250mzr: 90, 45, 135, 0)
    cell = np.array([90.0, 45.0, 135.0, 0.0])
    np.testing.assert_allclose(correction_matrices(ideal_rows(cell), cell), np.eye(4), atol=1e-12)


def test_correction_recovers_stokes_of_an_imperfect_cell_exactly():
    rng = np.random.default_rng(2)
    n = 200
    g = rng.uniform(0.9, 1.1, (n, 4))
    d = extinction_to_diattenuation(rng.uniform(50, 300, (n, 4)))
    th = ANG + rng.normal(0, 3, (n, 4))
    s0 = rng.uniform(0.1, 1.0, n)
    p = rng.uniform(0, 1, n)
    a = rng.uniform(0, np.pi, n)
    s = np.stack([s0, s0 * p * np.cos(2 * a), s0 * p * np.sin(2 * a)], -1)
    rows = measurement_rows(g, d, th)
    x = np.einsum("nkj,nj->nk", rows, s)               # noise-free measurements
    m = correction_matrices(rows, ANG)
    out = np.einsum("nij,nj->ni", m, x).T              # (4, n) ideal stack
    st = stokes(out)
    np.testing.assert_allclose(st.s0, s[:, 0], atol=1e-12)
    np.testing.assert_allclose(st.s1, s[:, 1], atol=1e-12)
    np.testing.assert_allclose(st.s2, s[:, 2], atol=1e-12)
    # uncorrected, the same data are off by far more
    raw = stokes(x.T)
    assert np.max(np.abs(raw.s1 - s[:, 1])) > 1e-2


def test_correction_keeps_the_unexplained_part_on_the_residual_axis():
    rng = np.random.default_rng(3)
    g = rng.uniform(0.95, 1.05, 4)
    rows = measurement_rows(g, 0.98, ANG + rng.normal(0, 2, 4))
    s = np.array([0.7, 0.1, -0.2])
    extra = np.array([0.01, -0.004, 0.002, 0.005])  # not explained by any Stokes vector
    x = rows @ s + extra
    m = correction_matrices(rows, ANG)
    out = m @ x
    w_a = rows @ np.linalg.pinv(rows)
    unexplained = (np.eye(4) - w_a) @ x
    # fit_residual of the output is the signed sum of the unexplained part per unit gain
    assert fit_residual(out[:, None])[0] == pytest.approx(float(residual_signs(ANG) @ (unexplained / g)), abs=1e-12)
    assert abs(fit_residual(out[:, None])[0]) > 1e-4
