"""Camera model (thesis Eq 3.3-3.6): projection, distortion, undistortion, Jacobian."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import CameraModel, InputError, camera_centre, project_points
from microcal.sim.synthetic_geometry import look_at_camera

# An ordinary photographic lens: strong barrel distortion, some tangential.
PHOTO_DIST = np.array([-0.28, 0.09, 1.2e-3, -8e-4, -0.012])


def photo_camera(skew: float = 0.0) -> CameraModel:
    base = look_at_camera(np.array([0.0, -200.0, -1000.0]), np.zeros(3), 900.0, (1280, 960))
    K = np.array([[900.0, skew, 652.3], [0.0, 905.0, 471.9], [0.0, 0.0, 1.0]])
    return CameraModel(K, PHOTO_DIST, base.R, base.t_um, (1280, 960), "photo")


def image_grid(cam: CameraModel, n: int = 41) -> np.ndarray:
    w, h = cam.image_size_px
    gx, gy = np.meshgrid(np.linspace(-0.5, w - 0.5, n), np.linspace(-0.5, h - 0.5, n))
    return np.column_stack([gx.ravel(), gy.ravel()])


def test_project_without_distortion_is_the_projection_matrix(thesis_pair, rng):
    for cam in thesis_pair:
        p = rng.uniform([0, 0, 0], [8000, 8000, 4800], size=(200, 3))
        np.testing.assert_allclose(cam.project(p), project_points(cam.P, p), rtol=0, atol=1e-9)
        np.testing.assert_allclose(cam.centre_um, camera_centre(cam.P), rtol=1e-12)


def test_project_with_distortion_matches_opencv(rng):
    cam = photo_camera(skew=0.0)
    p = rng.uniform([-300, -300, -100], [300, 300, 100], size=(500, 3))
    ours = cam.project(p)
    rvec, _ = cv2.Rodrigues(cam.R)
    theirs, _ = cv2.projectPoints(p, rvec, cam.t_um, cam.K, cam.dist)
    # Metric: worst-case pixel difference; both evaluate the same closed-form model.
    assert np.abs(ours - theirs[:, 0, :]).max() < 1e-9


def test_undistort_converges_to_1e6_px_everywhere_in_the_image():
    for skew in (0.0, 0.7):
        cam = photo_camera(skew)
        q = image_grid(cam)
        ideal = cam.undistort_px(q)
        assert np.all(np.isfinite(ideal))
        # Metric: worst-case distance after re-distorting, px.
        assert np.abs(cam.distort_px(ideal) - q).max() <= 1e-6


def test_undistort_inverts_distort_and_agrees_with_opencv():
    cam = photo_camera()
    ideal = image_grid(cam, 21) * 0.9 + 60
    q = cam.distort_px(ideal)
    np.testing.assert_allclose(cam.undistort_px(q), ideal, rtol=0, atol=1e-6)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        theirs = cv2.undistortPointsIter(q[:, None, :], cam.K, cam.dist, None, cam.K, crit)
    else:  # OpenCV 5 folded the iteration criteria into undistortPoints
        theirs = cv2.undistortPoints(q[:, None, :], cam.K, cam.dist, R=None, P=cam.K, criteria=crit)
    np.testing.assert_allclose(theirs[:, 0, :], ideal, rtol=0, atol=1e-4)


def test_undistort_far_outside_gives_nan_not_garbage():
    cam = photo_camera()
    q = np.array([[640.0, 480.0], [1e7, -1e7]])
    out = cam.undistort_px(q)
    assert np.all(np.isfinite(out[0]))
    assert np.all(np.isnan(out[1]))


def test_project_jacobian_matches_finite_differences(rng):
    cams = (
        photo_camera(0.4),
        look_at_camera(np.array([0, 0, -3e5]), np.zeros(3), 15000, (1600, 1200)),
    )
    for cam in cams:
        scale = 200.0 if cam.name == "photo" else 4000.0
        p = rng.uniform(-scale, scale, size=(50, 3))
        jac = cam.project_jacobian(p)
        h = scale * 1e-6
        fd = np.empty_like(jac)
        for k in range(3):
            dp = np.zeros(3)
            dp[k] = h
            fd[:, :, k] = (cam.project(p + dp) - cam.project(p - dp)) / (2 * h)
        # Metric: worst-case relative difference to the largest entry, central differences.
        assert np.abs(jac - fd).max() <= 1e-6 * np.abs(jac).max()


def test_points_behind_the_camera_project_to_nan():
    cam = look_at_camera(np.array([0.0, 0.0, -1000.0]), np.zeros(3), 1000, (640, 480))
    q = cam.project(np.array([[0.0, 0.0, -2000.0], [0.0, 0.0, 0.0]]))
    assert np.all(np.isnan(q[0]))
    assert np.all(np.isfinite(q[1]))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"K": np.eye(2)}, r"K: expected shape \(3, 3\), got \(2, 2\)"),
        ({"K": [[1, 0, 0], [1, 1, 0], [0, 0, 1]]}, "K: expected upper triangular"),
        ({"K": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "expected fx > 0 and fy > 0"),
        ({"dist": [0, 0, 0]}, r"dist: expected shape \(5,\), got \(3,\)"),
        ({"dist": [np.nan, 0, 0, 0]}, "dist: expected finite values"),
        ({"R": np.diag([1.0, 1.0, -1.0])}, r"R: expected a rotation"),
        ({"R": np.eye(3) * 1.01}, r"R: expected a rotation"),
        ({"t_um": [0, 0]}, r"t_um: expected shape \(3,\), got \(2,\)"),
        ({"image_size_px": (0, 10)}, r"image_size_px: expected \(width, height\) > 0"),
    ],
)
def test_camera_model_rejects_bad_parameters(kwargs, match):
    args = {
        "K": np.eye(3),
        "dist": np.zeros(5),
        "R": np.eye(3),
        "t_um": np.zeros(3),
        "image_size_px": (640, 480),
    }
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        CameraModel(**args)


@pytest.mark.parametrize(
    ("value", "match"),
    [
        (np.zeros((4, 2)), r"p_um: expected shape \(N, 3\), got \(4, 2\)"),
        (np.array([[1.0, np.nan, 2.0]]), "p_um: expected finite values, got 1 NaN"),
        ("abc", r"p_um: expected numbers of shape \(N, 3\), got str"),
    ],
)
def test_project_rejects_bad_points(thesis_pair, value, match):
    with pytest.raises(InputError, match=match):
        thesis_pair[0].project(value)


def test_single_point_is_accepted(thesis_pair):
    q = thesis_pair[0].project([1000.0, 2000.0, 300.0])
    assert q.shape == (1, 2)


def test_back_project_agrees_with_opencv():
    cam = photo_camera(skew=0.0)
    q = image_grid(cam, 21) * 0.9 + 60
    origin, direction = cam.back_project(q)
    np.testing.assert_array_equal(origin, np.broadcast_to(cam.centre_um, origin.shape))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        xy = cv2.undistortPointsIter(q[:, None, :], cam.K, cam.dist, None, None, crit)[:, 0, :]
    else:  # OpenCV 5 folded the iteration criteria into undistortPoints
        xy = cv2.undistortPoints(q[:, None, :], cam.K, cam.dist, R=None, criteria=crit)[:, 0, :]
    ray_c = np.hstack([xy, np.ones((len(xy), 1))])
    theirs = (ray_c / np.linalg.norm(ray_c, axis=1, keepdims=True)) @ cam.R
    # Metric: worst-case difference of the unit directions (radians, for small angles).
    assert np.abs(direction - theirs).max() < 1e-8
    # and the rays point into the scene: the camera sees their points in front of it.
    assert np.all((direction @ cam.R.T)[:, 2] > 0)


def test_back_project_of_far_outside_pixels_is_nan_not_garbage():
    cam = photo_camera()
    _, direction = cam.back_project(np.array([[640.0, 480.0], [1e7, -1e7]]))
    assert np.all(np.isfinite(direction[0]))
    assert np.all(np.isnan(direction[1]))
