"""Synthetic calibration image sets: truth, poses, spread, flips, rendering accuracy, stereo."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.calibration_views import (
    CalibrationViews,
    render_calibration_views,
    render_stereo_calibration_views,
    wide_angle_camera,
    wide_angle_stereo_pair,
)
from microcal.sim.render import Placement, render_placement
from microcal.vision.targets import parse_target

# 7 + 5 inner corners add up to an even number: the board looks the same turned by 180 degrees.
BOARD = parse_target("chessboard:7x5:30000")
CAMERA = wide_angle_camera()
W, H = CAMERA.image_size_px
ROT_Z_180 = np.diag([-1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def wide() -> CalibrationViews:
    return render_calibration_views(CAMERA, BOARD, 10, seed=3, flip_fraction=0.3)


@pytest.fixture(scope="module")
def clean() -> CalibrationViews:
    return render_calibration_views(CAMERA, BOARD, 4, seed=11, blur_sigma_px=0.0, noise_sigma=0.0)


def board_centres_px(views: CalibrationViews) -> np.ndarray:
    c = BOARD.centre_um
    return np.array([views.camera.project(R @ c + t)[0] for R, t in zip(views.board_R, views.board_t_um, strict=True)])  # fmt: skip


def detect(image: np.ndarray, truth: np.ndarray, half: int) -> np.ndarray:
    """OpenCV's detector and cornerSubPix, in the truth's numbering (nearest corner)."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(image, BOARD.pattern_size, flags=flags)
    assert found
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    refined = cv2.cornerSubPix(image, corners, (half, half), (-1, -1), crit).reshape(-1, 2)
    nearest = np.linalg.norm(truth[:, None] - refined[None], axis=2).argmin(axis=1)
    assert len(set(nearest.tolist())) == len(truth)
    return np.asarray(refined[nearest], dtype=np.float64)


def test_shapes_and_truth(wide):
    n = BOARD.pattern_size[0] * BOARD.pattern_size[1]
    assert wide.n_views == 10
    assert len(wide.images) == len(wide.corners_px) == len(wide.rotated_180) == 10
    assert wide.board_R.shape == (10, 3, 3)
    assert wide.board_t_um.shape == (10, 3)
    for v, (image, corners) in enumerate(zip(wide.images, wide.corners_px, strict=True)):
        assert image.shape == (H, W)
        assert image.dtype == np.uint8
        assert corners.shape == (n, 2)
        # the truth is the camera's projection of the target's points, in their numbering
        expected = CAMERA.project(wide.placement(v).points_world_um())
        np.testing.assert_allclose(corners, expected)
        R = wide.board_R[v]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
    assert wide.cameras == {"left": CAMERA}
    assert wide.target == BOARD
    assert (wide.blur_px, wide.noise) == (0.7, 2.0)
    # the left camera's frame is {G}: the pose in the camera frame is the same
    R, t = wide.board_in_camera(0)
    np.testing.assert_allclose(R, wide.board_R[0])
    np.testing.assert_allclose(t, wide.board_t_um[0])


def test_the_same_seed_gives_the_same_images_and_another_seed_others():
    a = render_calibration_views(CAMERA, BOARD, 2, seed=5)
    b = render_calibration_views(CAMERA, BOARD, 2, seed=5)
    c = render_calibration_views(CAMERA, BOARD, 2, seed=6)
    for x, y in zip(a.images, b.images, strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.board_t_um, b.board_t_um)
    assert not np.array_equal(a.board_t_um, c.board_t_um)
    assert not any(np.array_equal(x, y) for x, y in zip(a.images, c.images, strict=True))


def test_the_poses_do_not_depend_on_blur_and_noise(clean):
    noisy = render_calibration_views(CAMERA, BOARD, 4, seed=11)
    np.testing.assert_array_equal(noisy.board_R, clean.board_R)
    np.testing.assert_array_equal(noisy.board_t_um, clean.board_t_um)


def test_the_whole_board_is_in_view_with_a_margin_in_every_view(wide):
    for v in range(wide.n_views):
        placement = wide.placement(v)
        edge = CAMERA.project(placement.outline_um() @ placement.R.T + placement.t_um)
        for q in (edge, wide.corners_px[v]):
            assert np.all(np.isfinite(q))
            assert np.all(q >= 10.0)
            assert np.all(q <= [W - 11.0, H - 11.0])
        # the board is in front of the camera, its printed side towards it
        R, t = wide.board_in_camera(v)
        assert (R.T @ -t)[2] < 0
        assert np.all((placement.points_world_um() @ R.T + t)[:, 2] > 0)


def test_wide_spread_covers_the_quadrants_and_reaches_the_corners(wide):
    centres = board_centres_px(wide)
    quadrants = {(bool(x > W / 2), bool(y > H / 2)) for x, y in centres}
    assert len(quadrants) == 4
    for corner in ([0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]):
        assert np.linalg.norm(centres - corner, axis=1).min() <= 0.25 * W


def test_wide_spread_has_squares_of_tens_of_pixels(wide):
    sizes = [np.median(np.linalg.norm(np.diff(c.reshape(5, 7, 2), axis=1), axis=2)) for c in wide.corners_px]  # fmt: skip
    assert min(sizes) > 9.0
    assert max(sizes) > 25.0


def test_centre_spread_keeps_the_board_in_the_middle_third_with_small_tilts():
    views = render_calibration_views(CAMERA, BOARD, 4, seed=2, spread="centre", noise_sigma=0.0)
    centres = board_centres_px(views)
    assert np.all(np.abs(centres - [(W - 1) / 2, (H - 1) / 2]) <= [W / 6, H / 6])
    tilts = np.degrees(np.arccos(views.board_R[:, 2, 2]))
    assert np.all(tilts <= 10.0 + 1e-9)


def test_flipped_views_are_recorded_and_keep_the_targets_numbering(wide):
    assert sum(wide.rotated_180) == 3  # round(0.3 * 10)
    last = BOARD.points_um()[-1]
    c = BOARD.centre_um
    for v in np.flatnonzero(wide.rotated_180):
        R, t = wide.board_R[v], wide.board_t_um[v]
        # the pose it was drawn in, before the turn about the board's centre
        R0 = R @ ROT_Z_180
        t0 = t - 2.0 * R0 @ c
        np.testing.assert_allclose(R0 @ c + t0, R @ c + t)  # same centre
        where_last_was = CAMERA.project(R0 @ last + t0)[0]
        np.testing.assert_allclose(wide.corners_px[v][0], where_last_was, atol=1e-9)


def test_a_turned_symmetric_board_looks_the_same(wide):
    v = int(np.flatnonzero(wide.rotated_180)[0])
    turned = wide.placement(v)
    R0 = turned.R @ ROT_Z_180
    unturned = Placement(BOARD, R0, turned.t_um - 2.0 * R0 @ BOARD.centre_um)
    q = wide.corners_px[v]
    roi = (int(q[:, 0].min()) - 5, int(q[:, 1].min()) - 5, int(q[:, 0].max()) + 6, int(q[:, 1].max()) + 6)  # fmt: skip
    a, _ = render_placement(CAMERA, turned, roi)
    b, _ = render_placement(CAMERA, unturned, roi)
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_no_flips_without_a_flip_fraction(clean):
    assert clean.rotated_180 == [False] * 4


def test_opencv_finds_the_corners_within_a_tenth_of_a_pixel_of_the_truth(clean):
    # The strong distortion is traced per pixel and linearised within it; OpenCV's refined
    # corners on noise-free, unblurred renders land within 0.1 px RMS of the true projections.
    errors = [detect(image, truth, 5) - truth for image, truth in zip(clean.images, clean.corners_px, strict=True)]  # fmt: skip
    e = np.concatenate(errors)
    assert np.sqrt(np.mean(np.sum(e**2, axis=1))) <= 0.1
    assert np.abs(e.mean(axis=0)).max() <= 0.02  # no shift of the whole pattern


def test_stereo_views_are_seen_whole_by_every_camera():
    cams = wide_angle_stereo_pair()
    stereo = render_stereo_calibration_views(cams, BOARD, 4, seed=1, flip_fraction=0.5)
    assert stereo.n_views == 4
    assert sum(stereo.rotated_180) == 2
    assert set(stereo.images) == set(stereo.corners_px) == {"left", "right"}
    depth = (stereo.board_R @ BOARD.centre_um + stereo.board_t_um)[:, 2]  # in the left camera
    assert np.all((depth > 300_000) & (depth < 1_300_000))
    for name, cam in cams.items():
        views = stereo.for_camera(name)
        assert views.camera is cam
        assert len(views.images) == 4
        for v in range(4):
            q = cam.project(stereo.placement(v).points_world_um())
            np.testing.assert_allclose(views.corners_px[v], q)
            assert np.all((q >= 10) & (q <= [W - 11, H - 11]))
            flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
            assert cv2.findChessboardCorners(views.images[v], BOARD.pattern_size, flags=flags)[0]
    with pytest.raises(InputError, match="expected one of"):
        stereo.for_camera("middle")


def test_the_wide_angle_cameras():
    cam = wide_angle_camera()
    np.testing.assert_allclose(cam.K, [[525, 0, 320], [0, 527, 245], [0, 0, 1]])
    np.testing.assert_allclose(cam.dist, [-0.37, 0.24, 5e-4, -5e-4, -0.13])
    assert cam.image_size_px == (640, 480)
    np.testing.assert_allclose(cam.centre_um, 0.0)
    pair = wide_angle_stereo_pair()
    assert list(pair) == ["left", "right"]
    np.testing.assert_allclose(pair["right"].centre_um, [120_000.0, 0, 0], atol=1e-6)
    # nearly parallel: the right camera looks along +z within a degree
    assert np.degrees(np.arccos(pair["right"].R[2, 2])) < 1.0
    with pytest.raises(InputError, match="expected a positive distance"):
        wide_angle_stereo_pair(-1.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_views": 0}, "n_views: expected an integer >= 1, got 0"),
        ({"n_views": 2.5}, "n_views: expected an integer"),
        ({"flip_fraction": 1.5}, r"flip_fraction: expected a number in \[0, 1\], got 1.5"),
        ({"flip_fraction": -0.1}, "flip_fraction: expected"),
        ({"spread": "edge"}, "spread: expected 'wide' or 'centre', got 'edge'"),
        ({"tilt_deg": 80.0}, r"tilt_deg: expected a number in \[0, 70\]"),
        ({"blur_sigma_px": -1.0}, "blur_sigma_px: expected"),
        ({"noise_sigma": float("nan")}, "noise_sigma: expected"),
        (
            {"target": parse_target("dotgrid:5x5:125")},
            "expected a chessboard or ChArUco board, got dotgrid",
        ),
        ({"camera": "left"}, "camera: expected a CameraModel, got str"),
    ],
)
def test_invalid_arguments_raise_input_error(kwargs, message):
    args = {"camera": CAMERA, "target": BOARD, "n_views": 2, "seed": 0} | kwargs
    with pytest.raises(InputError, match=message):
        render_calibration_views(**args)


def test_a_rig_needs_two_cameras():
    with pytest.raises(
        InputError, match="expected a mapping of two or more cameras by name, got 1"
    ):
        render_stereo_calibration_views({"left": CAMERA}, BOARD, 2, seed=0)
