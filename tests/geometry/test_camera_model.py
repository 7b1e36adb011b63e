"""Camera model (thesis Eq 3.3-3.6): projection, distortion, undistortion, Jacobian."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import CameraModel, InputError, camera_centre, project_points
from microcal.geometry.camera_model import distort_normalized, tilt_matrix
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
        (
            {"dist": [0, 0, 0]},
            r"dist: expected 4, 5, 8, 12 or 14 coefficients \(k1, k2, p1, p2\[, k3.*\), got 3$",
        ),
        ({"dist": [np.nan, 0, 0, 0]}, "dist: expected finite values"),
        ({"R": np.diag([1.0, 1.0, -1.0])}, r"R: expected a rotation"),
        ({"R": np.eye(3) * 1.01}, r"R: expected a rotation"),
        ({"t_um": [0, 0]}, r"t_um: expected shape \(3,\), got \(2,\)"),
        ({"image_size_px": (0, 10)}, r"image_size_px: expected \(width, height\) of 1 to 10\^6"),
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


# --- every OpenCV distortion model ---------------------------------------------------------

# A wide-angle lens (about 70 degrees across the diagonal) calibrated with OpenCV's tilted
# model: k1, k2, p1, p2, k3, rational k4..k6, thin prism s1..s4, tilt tau_x, tau_y (rad). The
# first 5, 8 and 12 are OpenCV's default, rational and thin-prism models.
WIDE_DIST = np.array([-0.37, 0.24, 5e-4, -5e-4, -0.13, 0.012, -0.008, 0.004,
                      1.2e-3, -8e-4, -1.1e-3, 6e-4, 0.012, -0.009])  # fmt: skip
MODEL_LENGTHS = (5, 8, 12, 14)


def wide_camera(n_coef: int, skew: float = 0.0) -> CameraModel:
    base = look_at_camera(np.array([0.0, -200.0, -1000.0]), np.zeros(3), 1300.0, (1280, 960))
    K = np.array([[1300.0, skew, 652.3], [0.0, 1305.0, 471.9], [0.0, 0.0, 1.0]])
    return CameraModel(K, WIDE_DIST[:n_coef], base.R, base.t_um, (1280, 960), "wide")


def points_over_the_image(cam: CameraModel, rng: np.random.Generator, n: int) -> np.ndarray:
    """World points whose ideal pixels cover the image and a 5 % margin, 500-1500 µm deep."""
    w, h = cam.image_size_px
    q = rng.uniform([-0.05 * w, -0.05 * h], [1.05 * w, 1.05 * h], size=(n, 2))
    xy = np.linalg.solve(cam.K[:2, :2], (q - cam.K[:2, 2]).T).T
    z = rng.uniform(500.0, 1500.0, size=(n, 1))
    c = np.hstack([xy * z, z])
    return (c - cam.t_um) @ cam.R  # R^T (c - t), row by row


def test_wide_angle_lens_does_not_fold_over_the_image():
    """The test lens is a sane one: the distortion is one-to-one over the image's range."""
    for n in MODEL_LENGTHS:
        # the image's corners see ideal points at r of about 0.74, its ideal corners are at 0.63
        r = np.linspace(0.0, 0.8, 500)
        for angle in np.linspace(0.0, 2 * np.pi, 16, endpoint=False):
            _, jac = distort_normalized(r[:, None] * [np.cos(angle), np.sin(angle)], WIDE_DIST[:n])
            assert np.linalg.det(jac).min() > 0.2


@pytest.mark.parametrize("n_coef", MODEL_LENGTHS)
def test_every_distortion_model_projects_as_opencv(n_coef):
    cam = wide_camera(n_coef)
    assert cam.dist.shape == (n_coef,)
    p = points_over_the_image(cam, np.random.default_rng(100 + n_coef), 2000)
    ours = cam.project(p)
    rvec, _ = cv2.Rodrigues(cam.R)
    theirs, _ = cv2.projectPoints(p, rvec, cam.t_um, cam.K, cam.dist)
    # Metric: worst-case pixel difference over the whole image; the same closed-form model,
    # evaluated in another order of operations (measured: 1.4e-12 px).
    assert np.abs(ours - theirs[:, 0, :]).max() < 1e-9


@pytest.mark.parametrize("n_coef", MODEL_LENGTHS)
def test_distortion_jacobian_matches_finite_differences(n_coef):
    rng = np.random.default_rng(200 + n_coef)
    xy = rng.uniform(-0.75, 0.75, size=(500, 2))  # normalised: the image and beyond
    _, jac = distort_normalized(xy, WIDE_DIST[:n_coef])
    h = 1e-6
    fd = np.empty_like(jac)
    for k in range(2):
        dxy = np.zeros(2)
        dxy[k] = h
        fd[:, :, k] = (distort_normalized(xy + dxy, WIDE_DIST[:n_coef])[0]
                       - distort_normalized(xy - dxy, WIDE_DIST[:n_coef])[0]) / (2 * h)  # fmt: skip
    # Metric: worst-case difference relative to the largest entry, central differences
    # (rounding of about 1e-10 at this step; measured: 1.3e-10 to 2.3e-10).
    assert np.abs(jac - fd).max() <= 1e-8 * np.abs(jac).max()


@pytest.mark.parametrize("n_coef", MODEL_LENGTHS)
def test_project_jacobian_matches_finite_differences_for_every_model(n_coef):
    cam = wide_camera(n_coef, skew=0.4)
    p = points_over_the_image(cam, np.random.default_rng(300 + n_coef), 200)
    jac = cam.project_jacobian(p)
    h = 1e-3  # µm, at 500-1500 µm from the camera
    fd = np.empty_like(jac)
    for k in range(3):
        dp = np.zeros(3)
        dp[k] = h
        fd[:, :, k] = (cam.project(p + dp) - cam.project(p - dp)) / (2 * h)
    # Metric: worst-case difference relative to the largest entry, central differences
    # (measured: about 1e-10).
    assert np.abs(jac - fd).max() <= 1e-7 * np.abs(jac).max()


@pytest.mark.parametrize("n_coef", MODEL_LENGTHS)
@pytest.mark.parametrize("skew", [0.0, 0.7])
def test_every_distortion_model_round_trips_over_the_image(n_coef, skew):
    cam = wide_camera(n_coef, skew)
    q = image_grid(cam)
    # ideal pixels over the image, distorted and undistorted again
    back = cam.undistort_px(cam.distort_px(q))
    assert np.all(np.isfinite(back))
    # Metric: worst-case pixel distance (the Newton iteration stops at 1e-6 px in the distorted
    # image; the ideal side is far closer after its last step; measured: 5e-13 px).
    assert np.abs(back - q).max() <= 1e-6
    # observed pixels over the image, undistorted and distorted again
    ideal = cam.undistort_px(q)
    assert np.all(np.isfinite(ideal))
    assert np.abs(cam.distort_px(ideal) - q).max() <= 1e-6


@pytest.mark.parametrize("n_coef", MODEL_LENGTHS)
def test_every_distortion_model_undistorts_as_opencv(n_coef):
    cam = wide_camera(n_coef)
    q = image_grid(cam, 21)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-14)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        theirs = cv2.undistortPointsIter(q[:, None, :], cam.K, cam.dist, None, cam.K, crit)
    else:  # OpenCV 5 folded the iteration criteria into undistortPoints
        theirs = cv2.undistortPoints(q[:, None, :], cam.K, cam.dist, R=None, P=cam.K, criteria=crit)
    # Metric: worst-case pixel difference; OpenCV's fixed-point iteration is the looser one
    # (measured: 6e-13 px with OpenCV 5).
    np.testing.assert_allclose(cam.undistort_px(q), theirs[:, 0, :], rtol=0, atol=1e-6)


def test_zero_extra_coefficients_reproduce_the_five_coefficient_model_exactly(rng):
    five = wide_camera(5, skew=0.4)
    p = points_over_the_image(five, rng, 500)
    q = five.project(p)
    for n in (8, 12, 14):
        cam = CameraModel(five.K, np.append(five.dist, np.zeros(n - 5)), five.R, five.t_um,
                          five.image_size_px)  # fmt: skip
        np.testing.assert_array_equal(cam.project(p), q)
        np.testing.assert_array_equal(cam.project_jacobian(p), five.project_jacobian(p))
        np.testing.assert_array_equal(cam.undistort_px(q), five.undistort_px(q))
    np.testing.assert_array_equal(tilt_matrix(0.0, 0.0), np.eye(3))


def test_tilt_moves_the_image_as_a_tilted_sensor_does():
    """A sensor tilted about its y axis stretches one side of the image and shrinks the other."""
    xy = np.array([[-0.3, 0.0], [0.3, 0.0], [0.0, 0.0]])
    dist = np.zeros(14)
    dist[13] = 0.02
    out, _ = distort_normalized(xy, dist)
    np.testing.assert_allclose(out[2], 0.0, atol=1e-15)  # the principal point stays
    assert abs(abs(out[0, 0]) - abs(out[1, 0])) > 1e-3  # and the sides differ
    np.testing.assert_allclose(out[:, 1], 0.0, atol=1e-15)


@pytest.mark.parametrize(("given", "stored"), [(4, 5), (5, 5), (8, 8), (12, 12), (14, 14)])
def test_distortion_keeps_the_number_of_coefficients_given(given, stored):
    cam = CameraModel(np.eye(3), WIDE_DIST[:given], np.eye(3), np.zeros(3), (640, 480))
    assert cam.dist.shape == (stored,)
    np.testing.assert_array_equal(cam.dist[:given], WIDE_DIST[:given])
    assert not cam.dist.flags.writeable
    assert len(cam.dist.tolist()) == stored  # as cameras.json writes it


@pytest.mark.parametrize("n_coef", [0, 1, 3, 6, 7, 9, 13, 15])
def test_other_numbers_of_distortion_coefficients_are_refused(n_coef):
    with pytest.raises(InputError) as info:
        CameraModel(np.eye(3), np.zeros(n_coef), np.eye(3), np.zeros(3), (640, 480))
    assert str(info.value) == (
        "dist: expected 4, 5, 8, 12 or 14 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6[, "
        f"s1, s2, s3, s4[, tau_x, tau_y]]]]), got {n_coef}"
    )


def test_distortion_of_another_shape_is_refused():
    with pytest.raises(
        InputError, match=r"dist: expected 4, 5, 8, 12 or 14 coefficients .*, got shape \(1, 5\)$"
    ):
        CameraModel(np.eye(3), np.zeros((1, 5)), np.eye(3), np.zeros(3), (640, 480))
    with pytest.raises(
        InputError, match=r"dist: expected 4, 5, 8, 12 or 14 coefficients .*, got str$"
    ):
        CameraModel(np.eye(3), "abc", np.eye(3), np.zeros(3), (640, 480))
    with pytest.raises(InputError, match="dist: expected finite values, got 1 NaN"):
        CameraModel(np.eye(3), [0.1] * 13 + [np.inf], np.eye(3), np.zeros(3), (640, 480))


@pytest.mark.parametrize("n_coef", [3, 4, 6, 7, 13, 15])
def test_distort_normalized_refuses_other_numbers_of_coefficients(n_coef):
    with pytest.raises(
        InputError, match=rf"dist: expected 5, 8, 12 or 14 coefficients \(k1, .*\), got {n_coef}$"
    ):
        distort_normalized(np.zeros((2, 2)), np.zeros(n_coef))
