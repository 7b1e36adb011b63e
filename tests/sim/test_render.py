"""The simulated cameras: rendering fidelity and image noise against the thesis."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import sim
from microcal.sim.render import Placement, render_placement, roi_of
from microcal.thesis.cameras import thesis_cameras
from microcal.vision.targets import parse_target

BOARD = parse_target("chessboard:4x3:400")


def detect(image_f32: np.ndarray, truth_px: np.ndarray, offset=(0, 0)) -> np.ndarray | None:
    """OpenCV's classic detector + cornerSubPix with a window scaled to the square size."""
    img8 = np.clip(np.rint(image_f32), 0, 255).astype(np.uint8)
    found, corners = cv2.findChessboardCorners(
        img8, BOARD.pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
    )
    if not found:
        return None
    square_px = float(np.linalg.norm(truth_px[1] - truth_px[0]))
    half = max(2, round(0.4 * square_px))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-5)
    c = cv2.cornerSubPix(image_f32.astype(np.float32), corners.reshape(-1, 1, 2).astype(np.float32),
                         (half, half), (-1, -1), crit).reshape(-1, 2) + np.asarray(offset)  # fmt: skip
    if np.linalg.norm(c[0] - truth_px[0]) > np.linalg.norm(c[0] - truth_px[-1]):
        c = c[::-1]
    return c


def test_noise_free_renders_detect_within_002_px_rms():
    plat = sim.platform("thesis", seed=1)
    rng = np.random.default_rng(5)
    errors = []
    for _ in range(50):
        d = rng.uniform([0, 0, 0], [8000, 8000, 4800])
        plat.manipulator.move_to_um(d)
        plat.manipulator.wait_until_stopped(plat.clock)
        plat.clock.sleep(10.0)
        for cam in plat.cameras.values():
            image, truth = cam.render_reflectance(plat.clock.now_s(), np.zeros(2))
            c = detect(image * 255.0, truth.features_px[0])
            assert c is not None
            errors.append(c - truth.features_px[0])
    e = np.concatenate(errors)
    # Metric: RMS of the Euclidean corner error over 50 poses x 2 cameras x 12 corners.
    assert np.sqrt(np.mean(np.sum(e**2, axis=1))) <= 0.02


def test_rendering_has_converged_in_the_subsamples():
    # The box-filtered subsamples make 2 x 2 sampling as good as 8 x 8: the rendering's own
    # error is far below the detection noise.
    top, _ = thesis_cameras(dist_top=np.array([0.5, 0, 1e-3, -1e-3, 0]))
    pl = Placement(BOARD, np.eye(3), np.array([4000.0, 4000.0, 2000.0]))
    roi = roi_of(top, pl, 4)
    coarse, a1 = render_placement(top, pl, roi, supersample=2)
    fine, a2 = render_placement(top, pl, roi, supersample=32)
    diff = coarse * a1 - fine * a2
    # Metric: pixel difference in reflectance (the contrast is 0.77), worst and RMS.
    assert np.abs(diff).max() < 0.01
    assert np.sqrt(np.mean(diff**2)) < 0.001


def _corner_scatter(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Std per axis over 120 frames of one corner and of the virtual point, top camera."""
    plat = sim.platform("thesis", seed=seed)
    plat.manipulator.move_to_um([4000, 4000, 2400])
    plat.manipulator.wait_until_stopped(plat.clock)
    plat.clock.sleep(10.0)
    cam = plat.cameras["top"]
    corners = []
    for _ in range(120):
        img = cam.grab()
        truth = cam.last_truth.features_px[0]
        x0, y0 = np.floor(truth.min(axis=0) - 40).astype(int)
        x1, y1 = np.ceil(truth.max(axis=0) + 40).astype(int)
        c = detect(img[y0:y1, x0:x1].astype(np.float32), truth - [x0, y0], (x0, y0))
        assert c is not None
        corners.append(c)
    corners = np.array(corners)
    return corners[:, 5].std(axis=0, ddof=1), corners.mean(axis=1).std(axis=0, ddof=1)


def test_corner_scatter_matches_thesis_table_4_1():
    # Three platforms (seeds 2-4): one estimate from 120 frames scatters ~7 % from seed to
    # seed, the mean of three ~4 %, well inside the 25 % the figures are held to.
    one, virtual = np.mean([_corner_scatter(seed) for seed in (2, 3, 4)], axis=0)
    # Thesis Table 4-1: one corner 0.207 / 0.172 px, virtual point 0.087 / 0.045 px.
    # Metric: std per axis over 120 frames (mean over the seeds), within 25 %.
    np.testing.assert_allclose(one, [0.207, 0.172], rtol=0.25)
    assert virtual[0] == pytest.approx(0.087, rel=0.25)
    assert virtual[1] < 0.08
    assert np.all(one / virtual >= 2.5)


def test_same_seed_same_frames_bit_for_bit():
    frames = []
    for _ in range(2):
        plat = sim.platform("thesis", seed=7)
        plat.manipulator.move_to_um([1234, 4321, 2222])
        plat.manipulator.wait_until_stopped(plat.clock)
        frames.append([cam.grab() for cam in plat.cameras.values()] + [plat.truth_position_um()])
    for a, b in zip(*frames, strict=True):
        np.testing.assert_array_equal(a, b)
    other = sim.platform("thesis", seed=8)
    other.manipulator.move_to_um([1234, 4321, 2222])
    other.manipulator.wait_until_stopped(other.clock)
    assert not np.array_equal(other.cameras["top"].grab(), frames[0][0])


def test_frame_format_and_twelve_bit():
    plat = sim.platform("thesis", seed=0, overrides={"top.bit_depth": 12})
    top = plat.cameras["top"].grab()
    side = plat.cameras["side"].grab()
    assert top.shape == (1200, 1600)
    assert top.dtype == np.uint16
    assert top.max() > 255
    assert top.max() <= 4095
    assert side.shape == (1028, 1226)
    assert side.dtype == np.uint8


def test_charuco_and_dot_grid_render():
    top, _ = thesis_cameras()
    for spec in ("charuco:5x4:400", "dotgrid:12x10:125"):
        t = parse_target(spec)
        pl = Placement(t, np.eye(3), np.array([3000.0, 3000.0, 1000.0]))
        roi = roi_of(top, pl, 4)
        value, _alpha = render_placement(top, pl, roi)
        assert value.shape == (roi[3] - roi[1], roi[2] - roi[0])
        assert 0.0 <= value.min() < 0.3
        assert value.max() > 0.7
    # The dots (bright chrome on dark glass) sit where they should: intensity-weighted
    # centroids of the rendered dots against the projected centres.
    n, _, _, rough = cv2.connectedComponentsWithStats((value > 0.35).astype(np.uint8))
    assert n - 1 == 120
    lit = np.clip(value - 0.06, 0.0, None)  # above the glass
    centroids = []
    for cx, cy in rough[1:]:
        x0, y0 = round(cx) - 2, round(cy) - 2
        win = lit[y0 : y0 + 5, x0 : x0 + 5]
        yy, xx = np.mgrid[y0 : y0 + 5, x0 : x0 + 5]
        centroids.append([np.sum(xx * win) / win.sum(), np.sum(yy * win) / win.sum()])
    centroids = np.array(centroids) + roi[:2]
    truth = top.project(pl.points_world_um())
    nearest = np.min(np.linalg.norm(centroids[:, None] - truth[None], axis=2), axis=1)
    assert nearest.max() < 0.05


@pytest.mark.slow
def test_a_shifted_scene_reuses_the_undistorted_grid_to_first_order():
    """Rendering keeps the ideal coordinates of a pixel box and shifts them to first order
    for the frame's vibration; against undistorting the shifted pixels, the difference is
    far below the rendering's corner bias (0.015 px)."""
    from microcal.sim.render import _ideal_grid

    top = sim.platform("thesis", seed=0).cameras["top"].model
    roi = (200, 150, 1400, 1050)  # most of the image, corners included
    ideal0, d_dx, d_dy = _ideal_grid(top, roi)
    gx, gy = np.meshgrid(np.arange(200, 1400.0), np.arange(150, 1050.0))
    for off in ([0.3, -0.2], [-1.0, 0.7]):
        exact = top.undistort_px(np.column_stack([gx.ravel() - off[0], gy.ravel() - off[1]]))
        approx = (ideal0 - d_dx * off[0] - d_dy * off[1]).reshape(-1, 2)
        assert np.abs(approx - exact).max() < 1e-4  # measured: 1.1e-5 px at a 1.2 px shift
