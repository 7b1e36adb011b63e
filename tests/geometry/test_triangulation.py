"""Triangulation (Eq 3.18): linear and optimal, against OpenCV, its covariance, affine views."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from microcal import (
    DegenerateDataError,
    InputError,
    project_points,
    reprojection_error,
    triangulate,
    triangulate_optimal,
    triangulation_covariance,
)
from microcal.geometry import triangulate_cameras
from microcal.sim.synthetic_geometry import random_camera_pair, random_points
from microcal.thesis.cameras import thesis_cameras

CENTRE = np.array([4000.0, 4000.0, 2400.0])


def views(cams, p):
    return cams[0].project(p), cams[1].project(p)


def reprojection_cost(P1, P2, q1, q2, p):
    """Sum of the squared reprojection errors in both views, per point."""
    return reprojection_error(P1, p, q1) ** 2 + reprojection_error(P2, p, q2) ** 2


@pytest.mark.parametrize("method", ["linear", "optimal"])
def test_round_trip_without_noise_thesis_cameras(thesis_pair, rng, method):
    p = random_points(rng, 5000)
    q1, q2 = views(thesis_pair, p)
    got = triangulate(thesis_pair[0].P, thesis_pair[1].P, q1, q2, method=method)
    # Metric: worst-case error relative to the point's distance from the origin.
    assert np.max(np.linalg.norm(got - p, axis=1) / np.linalg.norm(p, axis=1)) < 1e-9


@given(seed=st.integers(0, 2**32 - 1), method=st.sampled_from(["linear", "optimal"]))
def test_round_trip_without_noise_random_geometry(seed, method):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-5e4, 5e4, 3)
    cams = random_camera_pair(rng, centre)
    p = centre + rng.uniform(-5000, 5000, size=(50, 3))
    q1, q2 = views(cams, p)
    got = triangulate(cams[0].P, cams[1].P, q1, q2, method=method)
    assert np.max(np.linalg.norm(got - p, axis=1) / np.linalg.norm(p, axis=1)) < 1e-9


def opencv_triangulate(P1, P2, q1, q2):
    h = cv2.triangulatePoints(P1, P2, q1.T.copy(), q2.T.copy())
    return (h[:3] / h[3]).T


def test_linear_agrees_with_opencv(thesis_pair, rng):
    P1, P2 = thesis_pair[0].P, thesis_pair[1].P
    p = random_points(rng, 2000)
    q1, q2 = views(thesis_pair, p)
    ours = triangulate(P1, P2, q1, q2)
    theirs = opencv_triangulate(P1, P2, q1, q2)
    # Without noise: same point to 1e-9 relative.
    assert np.max(np.linalg.norm(ours - theirs, axis=1) / np.linalg.norm(p, axis=1)) < 1e-9
    # With 0.1 px noise both solve the same equations under different constraints; they agree
    # to a small fraction of the error the noise causes.
    n1, n2 = q1 + rng.normal(0, 0.1, q1.shape), q2 + rng.normal(0, 0.1, q2.shape)
    ours = triangulate(P1, P2, n1, n2)
    theirs = opencv_triangulate(P1, P2, n1, n2)
    diff = np.linalg.norm(ours - theirs, axis=1)
    err = np.linalg.norm(ours - p, axis=1)
    assert np.sqrt(np.mean(diff**2)) < 0.05 * np.sqrt(np.mean(err**2))


def test_optimal_never_reprojects_worse_than_linear(thesis_pair, rng):
    P1, P2 = thesis_pair[0].P, thesis_pair[1].P
    p = random_points(rng, 3000)
    q1, q2 = views(thesis_pair, p)
    q1 = q1 + rng.normal(0, 0.3, q1.shape)
    q2 = q2 + rng.normal(0, 0.3, q2.shape)
    lin = triangulate(P1, P2, q1, q2)
    opt = triangulate(P1, P2, q1, q2, method="optimal")
    c_lin, c_opt = reprojection_cost(P1, P2, q1, q2, lin), reprojection_cost(P1, P2, q1, q2, opt)
    assert np.all(c_opt <= c_lin * (1 + 1e-12))
    assert np.mean(c_opt) < np.mean(c_lin)


def test_optimal_is_a_stationary_point(thesis_pair, rng):
    # At the optimum the gradient of the reprojection cost vanishes: check by finite differences.
    P1, P2 = thesis_pair[0].P, thesis_pair[1].P
    p = random_points(rng, 20)
    q1, q2 = views(thesis_pair, p)
    q1 = q1 + rng.normal(0, 0.5, q1.shape)
    q2 = q2 + rng.normal(0, 0.5, q2.shape)
    opt = triangulate_optimal(P1, P2, q1, q2)

    def cost(x):
        return reprojection_cost(P1, P2, q1, q2, x)

    h = 1e-3
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        grad = (cost(opt + d) - cost(opt - d)) / (2 * h)
        assert np.abs(grad).max() < 1e-6


def test_covariance_matches_monte_carlo(thesis_pair, rng):
    P1, P2 = thesis_pair[0].P, thesis_pair[1].P
    sig1 = np.array([[0.207**2, 0.01], [0.01, 0.172**2]])  # thesis Table 4-1, one corner
    sig2 = 0.09
    points = random_points(rng, 4)
    trials = 20000
    for p in points:
        q1, q2 = views(thesis_pair, p[None, :])
        L1 = np.linalg.cholesky(sig1)
        n1 = q1 + rng.normal(size=(trials, 2)) @ L1.T
        n2 = q2 + rng.normal(0, sig2, size=(trials, 2))
        est = triangulate_optimal(P1, P2, n1, n2, sig1, sig2)
        cov = triangulation_covariance(P1, P2, p, sig1, sig2)[0]
        sample = np.cov(est.T)
        # Metric: variance along each principal direction of the prediction, relative.
        w, V = np.linalg.eigh(cov)
        along = np.einsum("ij,ik,kj->j", V, sample, V)
        np.testing.assert_allclose(along, w, rtol=0.10)
        # and the normalised errors have mean square 3 (three degrees of freedom).
        d = est - p
        m2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
        assert m2.mean() == pytest.approx(3.0, rel=0.10)


def test_covariance_shape_and_units(thesis_pair, rng):
    P1, P2 = thesis_pair[0].P, thesis_pair[1].P
    p = random_points(rng, 7)
    cov = triangulation_covariance(P1, P2, p, 0.1, 0.1)
    assert cov.shape == (7, 3, 3)
    np.testing.assert_allclose(cov, np.transpose(cov, (0, 2, 1)))
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # Doubling the pixel noise doubles the standard deviations in µm.
    cov2 = triangulation_covariance(P1, P2, p, 0.2, 0.2)
    np.testing.assert_allclose(cov2, 4 * cov, rtol=1e-12)


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((np.eye(3), None, None, None), {}, r"P1: expected shape \(3, 4\), got \(3, 3\)"),
        ((None, None, np.zeros((5, 3)), None), {}, r"q1_px: expected shape \(N, 2\), got \(5, 3\)"),
        ((None, None, None, np.zeros((4, 2))), {}, "same number of points, got 5 and 4"),
        ((None, None, np.full((5, 2), np.nan), None), {}, "q1_px: expected finite values"),
        ((None, None, None, None), {"method": "svd"}, "method: expected 'linear' or 'optimal'"),
    ],
)
def test_triangulate_rejects_bad_input(thesis_pair, args, kwargs, match):
    defaults = (thesis_pair[0].P, thesis_pair[1].P, np.zeros((5, 2)), np.zeros((5, 2)))
    full = [d if a is None else a for a, d in zip(args, defaults, strict=True)]
    with pytest.raises(InputError, match=match):
        triangulate(*full, **kwargs)


@pytest.mark.parametrize(
    ("cov", "match"),
    [
        (-0.1, "expected a positive pixel standard deviation"),
        (np.array([[1.0, 2.0], [2.0, 1.0]]), "expected positive definite"),
        (np.ones((3, 2, 2)), r"cov1_px2: expected shape \(5, 2, 2\), got \(3, 2, 2\)"),
    ],
)
def test_covariance_rejects_bad_pixel_noise(thesis_pair, cov, match):
    P1, P2 = thesis_pair[0].P, thesis_pair[1].P
    with pytest.raises(InputError, match=match):
        triangulation_covariance(P1, P2, np.ones((5, 3)), cov, 0.1)


def test_single_pair_is_accepted(thesis_pair):
    p = np.array([1000.0, 2000.0, 500.0])
    q1, q2 = views(thesis_pair, p)
    got = triangulate(thesis_pair[0].P, thesis_pair[1].P, q1[0], q2[0])
    assert got.shape == (1, 3)
    np.testing.assert_allclose(got[0], p, rtol=1e-9)


def affine_side(thesis_pair, scale: float = 1.0) -> np.ndarray:
    """A hand-built affine P (parallel projection along the side camera's axis), any scale."""
    R = thesis_pair[1].R
    m = 0.04  # px/µm, the side camera's scale at its working distance
    P = np.zeros((3, 4))
    P[:2, :3] = m * R[:2]
    P[:2, 3] = np.array([800.0, 600.0]) - m * R[:2] @ CENTRE
    P[2, 3] = 1.0
    return scale * P


@pytest.mark.parametrize("scale", [1.0, -2.5, 1e-3])
@pytest.mark.parametrize("method", ["linear", "optimal"])
def test_round_trip_pinhole_and_affine(thesis_pair, rng, scale, method):
    P1, P2 = thesis_pair[0].P, affine_side(thesis_pair, scale)
    assert np.all(P2[2, :3] == 0)
    p = random_points(rng, 2000)
    q1, q2 = project_points(P1, p), project_points(P2, p)
    for args in ((P1, P2, q1, q2), (P2, P1, q2, q1)):  # the affine view first or second
        got = triangulate(*args, method=method)
        # Metric: worst-case error relative to the point's distance from the origin.
        assert np.max(np.linalg.norm(got - p, axis=1) / np.linalg.norm(p, axis=1)) < 1e-9


@given(seed=st.integers(0, 2**32 - 1), method=st.sampled_from(["linear", "optimal"]))
def test_round_trip_pinhole_and_affine_random_geometry(seed, method):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-5e4, 5e4, 3)
    pinhole, other = random_camera_pair(rng, centre)
    P2 = np.zeros((3, 4))  # parallel projection along the other camera's axis
    P2[:2, :3] = 10 ** rng.uniform(-2, 0) * other.R[:2]
    P2[:2, 3] = rng.uniform(0, 1000, 2)
    P2[2, 3] = rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-3, 3)
    P2[:2] *= P2[2, 3]
    p = centre + rng.uniform(-5000, 5000, size=(50, 3))
    got = triangulate(pinhole.P, P2, pinhole.project(p), project_points(P2, p), method=method)
    assert np.max(np.linalg.norm(got - p, axis=1) / np.linalg.norm(p, axis=1)) < 1e-9


def test_pinhole_and_affine_with_noise(thesis_pair, rng):
    P1, P2 = thesis_pair[0].P, affine_side(thesis_pair)
    p = random_points(rng, 3000)
    q1 = project_points(P1, p) + rng.normal(0, 0.2, (3000, 2))
    q2 = project_points(P2, p) + rng.normal(0, 0.2, (3000, 2))
    lin = triangulate(P1, P2, q1, q2)
    opt = triangulate_optimal(P1, P2, q1, q2, 0.2, 0.2)
    c_lin, c_opt = reprojection_cost(P1, P2, q1, q2, lin), reprojection_cost(P1, P2, q1, q2, opt)
    assert np.all(c_opt <= c_lin * (1 + 1e-12))
    # The optimal estimate's error matches its predicted covariance: mean square 3 (3 dof).
    cov = triangulation_covariance(P1, P2, opt, 0.2, 0.2)
    d = opt - p
    m2 = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov), d)
    assert m2.mean() == pytest.approx(3.0, rel=0.10)


def test_covariance_with_an_affine_view_is_the_first_order_bound(thesis_pair, rng):
    # (J^T W J)^-1 with J by central differences of both views' projections.
    P1, P2 = thesis_pair[0].P, affine_side(thesis_pair, -4.0)
    sig1 = np.array([[0.04, 0.01], [0.01, 0.03]])
    sig2 = 0.15
    p = random_points(rng, 5)
    cov = triangulation_covariance(P1, P2, p, sig1, sig2)
    W = np.linalg.inv(np.block([[sig1, np.zeros((2, 2))], [np.zeros((2, 2)), sig2**2 * np.eye(2)]]))
    h = 1.0
    for pi, ci in zip(p, cov, strict=True):
        J = np.empty((4, 3))
        for k in range(3):
            dp = np.zeros(3)
            dp[k] = h
            plus = np.concatenate([project_points(P, pi + dp)[0] for P in (P1, P2)])
            minus = np.concatenate([project_points(P, pi - dp)[0] for P in (P1, P2)])
            J[:, k] = (plus - minus) / (2 * h)
        # Metric: element-wise, relative to the largest entry.
        want = np.linalg.inv(J.T @ W @ J)
        assert np.abs(ci - want).max() <= 1e-9 * np.abs(want).max()


def test_triangulate_cameras_is_the_optimal_pair_number_for_number(thesis_pair, rng):
    cams = thesis_cameras(np.array([0.5, 0, 1e-3, -1e-3, 0]), np.array([0.4, 0, -1e-3, 1e-3, 0]))
    p = random_points(rng, 500)
    q1, q2 = (c.undistort_px(c.project(p)) + rng.normal(0, 0.1, (500, 2)) for c in cams)
    cov1, cov2 = np.array([[0.02, 0.003], [0.003, 0.01]]), 0.12
    got, got_cov = triangulate_cameras(cams[0], cams[1], q1, q2, cov1, cov2)
    want = triangulate_optimal(cams[0].P, cams[1].P, q1, q2, cov1, cov2)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(
        got_cov, triangulation_covariance(cams[0].P, cams[1].P, want, cov1, cov2)
    )


def test_a_view_that_is_no_camera_is_refused(thesis_pair):
    P2 = np.zeros((3, 4))
    P2[:2, :3] = np.eye(3)[:2]
    with pytest.raises(DegenerateDataError, match=r"got P\[2\] = 0"):
        triangulate(thesis_pair[0].P, P2, np.zeros((1, 2)), np.zeros((1, 2)))
