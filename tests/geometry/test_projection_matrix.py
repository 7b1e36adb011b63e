"""Projection matrix: normalised DLT (Eq 3.7-3.15), RQ decomposition (Eq 3.16), normalisation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from microcal import (
    DegenerateDataError,
    InputError,
    camera_centre,
    decompose_projection_matrix,
    estimate_projection_matrix,
    project_points,
    reprojection_error,
)
from microcal.geometry.projection_matrix import (
    is_affine_projection_matrix,
    normalize_camera_matrix,
    normalize_projection_matrix,
)
from microcal.sim.synthetic_geometry import dot_grid_points, random_camera_pair, random_points
from microcal.thesis.figures import P_SIDE_MM, P_TOP_MM, projection_matrix_um


def same_up_to_scale(A: np.ndarray, B: np.ndarray) -> float:
    """Largest element-wise difference of A and B after fixing scale and sign, relative."""
    a = normalize_projection_matrix(A)
    b = normalize_projection_matrix(B)
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.mark.parametrize(
    ("P_mm", "fx", "fy", "cx", "cy"),
    [(P_TOP_MM, 14914, 14653, 801, 634), (P_SIDE_MM, 12798, 12806, 638, 533)],
)
def test_thesis_camera_matrices_decompose(P_mm, fx, fy, cx, cy):
    for P in (P_mm, projection_matrix_um(P_mm)):
        K, R, t = decompose_projection_matrix(P)
        # Metric: absolute difference to the figures in the issue / thesis section 5.1, px.
        assert K[0, 0] == pytest.approx(fx, abs=1.0)
        assert K[1, 1] == pytest.approx(fy, abs=1.0)
        assert K[0, 2] == pytest.approx(cx, abs=1.0)
        assert K[1, 2] == pytest.approx(cy, abs=1.0)
        assert np.all(np.diag(K) > 0)
        assert K[2, 2] == 1.0
        assert np.allclose(np.tril(K, -1), 0.0)
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-12
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
        rebuilt = K @ np.hstack([R, t[:, None]])
        assert same_up_to_scale(rebuilt, P) < 1e-9


def test_thesis_translation_scales_with_the_unit():
    _, _, t_mm = decompose_projection_matrix(P_TOP_MM)
    _, _, t_um = decompose_projection_matrix(projection_matrix_um(P_TOP_MM))
    np.testing.assert_allclose(t_um, 1000 * t_mm, rtol=1e-12)


@pytest.mark.parametrize("P", [P_TOP_MM, P_SIDE_MM, projection_matrix_um(P_SIDE_MM)])
def test_decomposition_agrees_with_opencv(P):
    K, R, t = decompose_projection_matrix(P)
    K_cv, R_cv, C_cv = cv2.decomposeProjectionMatrix(P)[:3]
    K_cv = K_cv / K_cv[2, 2]
    C = -R.T @ t
    assert np.abs(K - K_cv).max() <= 1e-9 * np.abs(K).max()
    assert np.abs(R - R_cv).max() <= 1e-9
    np.testing.assert_allclose(C, (C_cv[:3] / C_cv[3]).ravel(), rtol=1e-9)


def test_decomposition_ignores_scale_and_sign():
    # OpenCV returns negative focal lengths for a negatively scaled P; we fix the sign.
    K, R, t = decompose_projection_matrix(P_TOP_MM)
    for scale in (-3.0, -1e-4, 7e5):
        K2, R2, t2 = decompose_projection_matrix(scale * P_TOP_MM)
        np.testing.assert_allclose(K2, K, rtol=1e-12)
        np.testing.assert_allclose(R2, R, atol=1e-12)
        np.testing.assert_allclose(t2, t, rtol=1e-12)


@given(seed=st.integers(0, 2**32 - 1))
def test_decomposition_round_trip_random_cameras(seed):
    rng = np.random.default_rng(seed)
    cam, _ = random_camera_pair(rng, rng.uniform(-1e4, 1e4, 3))
    scale = rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-3, 3)
    K, R, t = decompose_projection_matrix(cam.P * scale)
    np.testing.assert_allclose(K, cam.K, rtol=1e-9, atol=1e-9 * cam.K[0, 0])
    np.testing.assert_allclose(R, cam.R, atol=1e-9)
    np.testing.assert_allclose(t, cam.t_um, rtol=0, atol=1e-9 * np.linalg.norm(cam.t_um))


def test_estimate_recovers_exact_projection_matrix(rng):
    for _ in range(20):
        cam, _ = random_camera_pair(rng, np.array([4000.0, 4000.0, 2400.0]))
        p = random_points(rng, 40)
        P = estimate_projection_matrix(p, cam.project(p))
        assert same_up_to_scale(P, cam.P) < 1e-9


def test_estimate_from_dot_grid_at_known_heights(thesis_pair):
    # The thesis's procedure: a planar dot grid moved by known z steps.
    top, _ = thesis_pair
    p = np.vstack([dot_grid_points(20, 20, 250.0, z) for z in (0.0, 1000.0, 2000.0)])
    P = estimate_projection_matrix(p, top.project(p))
    assert same_up_to_scale(P, top.P) < 1e-9


@pytest.mark.parametrize("sigma_px", [0.05, 0.2, 1.0])
def test_reprojection_rms_matches_injected_noise(rng, thesis_pair, sigma_px):
    top, _ = thesis_pair
    p = random_points(rng, 2000)
    noise = rng.normal(scale=sigma_px, size=(2000, 2))
    q = top.project(p) + noise
    P = estimate_projection_matrix(p, q)
    rms = np.sqrt(np.mean(reprojection_error(P, p, q) ** 2))
    injected = np.sqrt(np.mean(np.sum(noise**2, axis=1)))
    # Metric: RMS of the Euclidean reprojection error vs RMS of the injected displacement.
    assert rms == pytest.approx(injected, rel=0.10)
    # and the fit does not chase the noise: the truth is reprojected better than the noise.
    truth_err = np.sqrt(np.mean(reprojection_error(P, p, top.project(p)) ** 2))
    assert truth_err < 0.2 * sigma_px


@pytest.mark.parametrize(
    ("n", "make", "error", "match"),
    [
        (5, "random", DegenerateDataError, "expected at least 6 correspondences, got 5"),
        (50, "plane", DegenerateDataError, "lie on one plane"),
        (50, "line", DegenerateDataError, "lie on one plane"),
        (50, "nan", InputError, "p_um: expected finite values, got 1 NaN"),
        (50, "count", DegenerateDataError, "same number of points, got 50 and 49"),
        (50, "shape", InputError, r"q_px: expected shape \(N, 2\), got \(50, 3\)"),
    ],
)
def test_estimate_rejects_degenerate_input(rng, thesis_pair, n, make, error, match):
    top, _ = thesis_pair
    p = random_points(rng, n)
    if make == "plane":
        p[:, 2] = 0.3 * p[:, 0] - 0.2 * p[:, 1] + 100.0
    if make == "line":
        p = np.outer(np.linspace(0, 1, n), [1000.0, 2000.0, 500.0])
    q = top.project(p)
    if make == "nan":
        p[3, 1] = np.nan
    if make == "count":
        q = q[:-1]
    if make == "shape":
        q = np.hstack([q, q[:, :1]])
    with pytest.raises(error, match=match):
        estimate_projection_matrix(p, q)


def test_decompose_rejects_camera_at_infinity():
    P = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
    with pytest.raises(DegenerateDataError, match=r"P\[2, :3\] = 0"):
        decompose_projection_matrix(P)
    P[2, :3] = [1e-3, 0, 0]
    P[0, 0] = 0.0
    with pytest.raises(DegenerateDataError, match="singular"):
        decompose_projection_matrix(P)


def test_decompose_rejects_bad_shape():
    with pytest.raises(InputError, match=r"P: expected shape \(3, 4\), got \(3, 3\)"):
        decompose_projection_matrix(np.eye(3))


def affine_matrix(scale: float = 1.0) -> np.ndarray:
    """A hand-built affine camera (parallel projection): 0.04 px/µm along a rotated view."""
    R = np.array([[0.8, 0.6, 0.0], [-0.36, 0.48, 0.8], [0.48, -0.64, 0.6]])
    P = np.zeros((3, 4))
    P[:2, :3] = 0.04 * R[:2]
    P[:2, 3] = [700.0, 500.0]
    P[2, 3] = 1.0
    return scale * P


@pytest.mark.parametrize("scale", [1.0, -3.0, 1e-4, 7e5])
def test_normalize_camera_matrix_leaves_pinhole_normalisation_alone(thesis_pair, scale):
    for cam in thesis_pair:
        P = cam.P * scale
        np.testing.assert_array_equal(normalize_camera_matrix(P), normalize_projection_matrix(P))


@pytest.mark.parametrize("scale", [1.0, -2.5, 1e-6, 3e4])
def test_normalize_camera_matrix_scales_an_affine_camera(scale):
    P = affine_matrix(scale)
    assert is_affine_projection_matrix(P)
    out = normalize_camera_matrix(P)
    np.testing.assert_array_equal(out[2], [0.0, 0.0, 0.0, 1.0])
    # Metric: element-wise, relative to the largest entry (one division by the scale).
    assert np.abs(out - affine_matrix()).max() <= 1e-15 * np.abs(affine_matrix()).max()


def test_affine_camera_is_refused_where_a_centre_is_needed():
    P = affine_matrix()
    with pytest.raises(DegenerateDataError, match=r"got P\[2, :3\] = 0 \(an affine camera\)"):
        normalize_projection_matrix(P)
    with pytest.raises(DegenerateDataError, match="camera_centre: expected a pinhole camera"):
        camera_centre(P)
    P[2, 3] = 0.0
    with pytest.raises(DegenerateDataError, match=r"or an affine camera .* got P\[2\] = 0"):
        normalize_camera_matrix(P)


def test_project_points_with_an_affine_camera(rng):
    P = affine_matrix(-2.0)
    p = random_points(rng, 20)
    np.testing.assert_allclose(project_points(P, p), p @ (P[:2, :3] / P[2, 3]).T
                               + P[:2, 3] / P[2, 3], rtol=1e-14)  # fmt: skip
