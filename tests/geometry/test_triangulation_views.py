"""Triangulation from any number of views of any kind, with views missing per point."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import InputError
from microcal.geometry import (
    AffineCamera,
    CameraModel,
    triangulate_cameras,
    triangulate_views,
)
from microcal.geometry.projection_matrix import normalize_camera_matrix
from microcal.geometry.triangulation import _linear
from microcal.sim.synthetic_geometry import random_points
from microcal.thesis.cameras import thesis_cameras

CENTRE_UM = np.array([4000.0, 4000.0, 2400.0])


def affine_of(cam: CameraModel) -> AffineCamera:
    K = cam.K.copy()
    K[:2, :2] /= float(cam.depth_um(CENTRE_UM)[0])
    return AffineCamera(K, np.zeros(5), cam.R, cam.t_um, cam.image_size_px, cam.name + "-affine")


def across_camera() -> CameraModel:
    """A pinhole camera looking across the plane of the thesis cameras' axes."""
    top, side = thesis_cameras()
    axis = np.cross(top.R[2], side.R[2])
    axis /= np.linalg.norm(axis)
    x = side.R[2] - (side.R[2] @ axis) * axis
    x /= np.linalg.norm(x)
    R = np.vstack([x, np.cross(axis, x), axis])
    t = -R @ (CENTRE_UM - 290_000.0 * axis)
    return CameraModel(side.K, np.zeros(5), R, t, side.image_size_px, "across")


def ideal(cams, p):
    return [c.undistort_px(c.project(p)) for c in cams]


def test_two_views_are_the_pair(thesis_pair, rng):
    p = random_points(rng, 50)
    q = ideal(thesis_pair, p)
    q_noisy = [v + rng.normal(0, 0.1, v.shape) for v in q]
    got, cov, n = triangulate_views(list(thesis_pair), q_noisy, [0.1, 0.2])
    want, want_cov = triangulate_cameras(*thesis_pair, *q_noisy, 0.1, 0.2)
    assert n.tolist() == [2] * 50
    # Metric: worst-case difference, µm and µm²; the same equations and iterations.
    assert np.abs(got - want).max() < 1e-9
    assert np.abs(cov - want_cov).max() < 1e-9 * np.abs(want_cov).max()


@pytest.mark.parametrize("kinds", ["pinhole", "mixed", "affine"])
def test_three_views_round_trip_without_noise(rng, kinds):
    top, side = thesis_cameras()
    cams = {
        "pinhole": [top, side, across_camera()],
        "mixed": [top, affine_of(side), across_camera()],
        "affine": [affine_of(top), affine_of(side), affine_of(across_camera())],
    }[kinds]
    p = random_points(rng, 200)
    got, _, _ = triangulate_views(cams, ideal(cams, p), [0.1, 0.1, 0.1])
    # Metric: worst-case 3D distance, µm.
    assert np.abs(got - p).max() < 1e-6


def test_linear_solution_is_the_stacked_least_squares(rng):
    cams = [thesis_cameras()[0], affine_of(thesis_cameras()[1]), across_camera()]
    Ps = tuple(normalize_camera_matrix(c.P) for c in cams)
    p = random_points(rng, 20)
    q = [v + rng.normal(0, 0.3, v.shape) for v in ideal(cams, p)]
    got = _linear(Ps, tuple(q))
    for i in range(20):
        rows, rhs = [], []
        for P, qv in zip(Ps, q, strict=True):
            for j in (0, 1):
                a = qv[i, j] * P[2] - P[j]
                rows.append(a[:3])
                rhs.append(-a[3])
        want, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
        # Metric: difference from numpy's least squares of Eq 3.18 stacked over 3 views, µm.
        assert np.abs(got[i] - want).max() < 1e-6


def test_covariance_matches_monte_carlo_three_mixed_views():
    rng = np.random.default_rng(31)
    cams = [thesis_cameras()[0], affine_of(thesis_cameras()[1]), across_camera()]
    sig = [0.2, np.array([[0.03, 0.01], [0.01, 0.02]]), 0.15]
    trials = 20000
    for p in random_points(rng, 3):
        q = ideal(cams, p[None, :])
        noisy = []
        for qv, s in zip(q, sig, strict=True):
            L = np.linalg.cholesky(s if np.ndim(s) == 2 else np.eye(2) * s**2)
            noisy.append(qv + rng.normal(size=(trials, 2)) @ L.T)
        est, cov, _ = triangulate_views(cams, noisy, sig)
        d = est - p
        m2 = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov), d)
        # Metric: Mahalanobis mean square against its expectation 3, relative.
        assert m2.mean() == pytest.approx(3.0, rel=0.05)
        # and the sample covariance along the predicted principal directions.
        w, V = np.linalg.eigh(cov[0])
        along = np.einsum("ij,ik,kj->j", V, np.cov(est.T), V)
        np.testing.assert_allclose(along, w, rtol=0.10)


def test_a_missing_view_leaves_the_others(rng):
    top, side = thesis_cameras()
    cams = [top, side, across_camera()]
    p = random_points(rng, 30)
    q = [v + rng.normal(0, 0.1, v.shape) for v in ideal(cams, p)]
    q_lost = [v.copy() for v in q]
    q_lost[2][:10] = np.nan  # the third camera lost the first ten points
    q_lost[0][10:12] = np.nan  # and the first camera two others
    got, cov, n = triangulate_views(cams, q_lost, [0.1, 0.1, 0.1])
    full, full_cov, _ = triangulate_views(cams, q, [0.1, 0.1, 0.1])
    pair, pair_cov = triangulate_cameras(top, side, q[0][:10], q[1][:10], 0.1, 0.1)
    assert n.tolist() == [2] * 12 + [3] * 18
    assert np.abs(got[:10] - pair).max() < 1e-9
    assert np.abs(cov[:10] - pair_cov).max() < 1e-9 * np.abs(pair_cov).max()
    np.testing.assert_array_equal(got[12:], full[12:])
    # Fewer views, larger uncertainty: the trace grows for every point that lost one.
    tr = np.trace(cov, axis1=1, axis2=2)
    tr_full = np.trace(full_cov, axis1=1, axis2=2)
    assert np.all(tr[:12] > tr_full[:12])


def test_two_of_three_missing_is_nan(rng):
    cams = [*thesis_cameras(), across_camera()]
    p = random_points(rng, 4)
    q = ideal(cams, p)
    q[0][1] = np.nan
    q[2][1] = np.nan
    got, cov, n = triangulate_views(cams, q, [0.1, 0.1, 0.1])
    assert n.tolist() == [3, 1, 3, 3]
    assert np.isnan(got[1]).all()
    assert np.isnan(cov[1]).all()
    assert np.isfinite(got[[0, 2, 3]]).all()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (lambda c, q: ([c[0]], [q[0]], [0.1]), r"two or more cameras, got 1, 1 and 1"),
        (lambda c, q: (c, q, [0.1]), r"one entry each .* got 2, 2 and 1"),
        (lambda c, q: (c, [q[0], q[1][:3]], [0.1, 0.1]), r"same number of points in every view"),
        (lambda c, q: ([c[0], {"P": 1}], q, [0.1, 0.1]), r"cameras\[1\]: expected a camera model"),
        (lambda c, q: (c, q, [0.1, -1.0]), r"cov_px2\[1\]: expected a positive pixel"),
    ],
)
def test_bad_input_is_refused(thesis_pair, rng, args, match):
    q = ideal(thesis_pair, random_points(rng, 5))
    with pytest.raises(InputError, match=match):
        triangulate_views(*args(list(thesis_pair), q))
