"""Corner refinement that adapts to the image (vision.corner_refinement): the window chosen per
board by the corners' scatter, against the truth on rendered boards and against OpenCV's
``cornerSubPix`` at its best half-window.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from microcal.sim.calibration_views import render_calibration_views, wide_angle_camera
from microcal.vision.corner_refinement import (
    WINDOW_FRACTION,
    grid_spacing_px,
    lattice_scatter_px,
    local_spacing_px,
    refine_corners,
    refine_grid_corners,
)
from microcal.vision.detect import _to_uint8, detect, to_gray
from microcal.vision.targets import parse_target

CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.001)
#: A wide-angle camera of 1280 x 960 px: squares of some 20-70 px.
LARGE = wide_angle_camera(fx=1050.0, fy=1054.0, cx=640.0, cy=490.0, image_size_px=(1280, 960))


def _rms(d):
    return float(np.sqrt(np.mean(np.sum(np.vstack(d) ** 2, axis=1))))


def _grid(cols, rows):
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.column_stack([j.ravel(), i.ravel()]).astype(float)


def test_grid_spacing_is_the_full_grids_and_a_lone_corner_has_none():
    rng = np.random.default_rng(0)
    q = _grid(5, 4) * 30.0 + rng.normal(0, 2.0, (20, 2))
    np.testing.assert_allclose(grid_spacing_px(q, _grid(5, 4)), local_spacing_px(q, 5, 4))
    part = [0, 1, 7, 19]  # (0,0)-(1,0) neighbours; (2,1) and (4,3) alone
    s = grid_spacing_px(q[part], _grid(5, 4)[part])
    assert np.isfinite(s[:2]).all()
    assert np.isinf(s[2:]).all()


def test_lattice_scatter_estimates_the_corners_noise_under_perspective_and_distortion():
    # Metric: the scatter against the noise's true standard deviation per coordinate.
    cam = wide_angle_camera()
    rng = np.random.default_rng(1)
    target = parse_target("chessboard:9x6:20000")
    R = cv2.Rodrigues(np.array([0.4, -0.3, 0.1]))[0]
    p = target.points_um() @ R.T + np.array([-20_000.0, 10_000.0, 350_000.0])
    exact = cam.project(p)
    # a cubic follows the barrel of a wide-angle lens over the board to some 0.02 px
    assert lattice_scatter_px(exact, _grid(9, 6)) < 0.03
    noisy = exact + rng.normal(0, 0.1, exact.shape)
    assert lattice_scatter_px(noisy, _grid(9, 6)) == pytest.approx(0.1, rel=0.25)
    assert np.isnan(lattice_scatter_px(exact[:3], _grid(9, 6)[:3]))


def _dotted(views, seed):
    """The rendered views with dark dots printed in the white squares (like the codes of an
    ECoCheck board): not point-symmetric about any corner."""
    rng = np.random.default_rng(seed)
    target, cam = views.target, views.camera
    pitch = target.pitch_um
    cols, rows = target.pattern_size
    out = []
    for v, image in enumerate(views.images):
        img = image.copy()
        for a in range(-1, cols):
            for b in range(-1, rows):
                if (a + b) % 2 == 0:  # square (a, b) has corner (a, b) at its top left
                    continue
                offsets = rng.uniform(0.25, 0.75, (6, 2))
                p = np.column_stack([(a + offsets) * pitch, np.zeros(6)])
                p[:, 1] = (b + offsets[:, 1]) * pitch
                q = cam.project(p @ views.board_R[v].T + views.board_t_um[v])
                r = 0.05 * float(np.median(local_spacing_px(views.corners_px[v], cols, rows)))
                for x, y in q:
                    cv2.circle(img, (int(x * 16), int(y * 16)), max(int(r * 16), 16), 30,
                               -1, cv2.LINE_AA, shift=4)  # fmt: skip
        out.append(img)
    return out


@pytest.mark.slow
def test_a_board_with_codes_in_its_squares_gets_a_window_that_avoids_them():
    target = parse_target("chessboard:9x6:20000")
    views = render_calibration_views(LARGE, target, 6, seed=11, blur_sigma_px=0.7, tilt_deg=25.0)
    images = _dotted(views, 3)
    adaptive, fixed, fractions = [], [], []
    for img, truth in zip(images, views.corners_px, strict=True):
        start = truth + np.random.default_rng(2).normal(0, 0.5, truth.shape)
        gray = to_gray(img)
        res = refine_grid_corners(gray, start, _grid(9, 6))
        adaptive.append(res.corners_px - truth)
        fractions.append(res.window_fraction)
        fixed.append(refine_corners(gray, start, 9, 6, fractions=(WINDOW_FRACTION,)) - truth)
    # Metric: RMS corner error against the truth, px.
    assert _rms(adaptive) < 0.05
    assert _rms(adaptive) < 0.5 * _rms(fixed)
    assert max(fractions) < WINDOW_FRACTION


@pytest.mark.parametrize(("blur", "quality"), [(0.7, 60), (1.5, 40)])
def test_small_compressed_squares_at_least_as_good_as_opencvs_best_window(blur, quality):
    # Squares of some 10-35 px (640 x 480 wide-angle camera), recompressed as JPEG: the
    # corners' RMS error against the truth, microcal's against cornerSubPix's with its best
    # half-window 2..8 (chosen on the truth, so the most OpenCV can do).
    target = parse_target("chessboard:9x6:20000")
    views = render_calibration_views(wide_angle_camera(), target, 8, seed=4, blur_sigma_px=blur)
    ours, theirs = [], {h: [] for h in range(2, 9)}
    for image, truth in zip(views.images, views.corners_px, strict=True):
        _ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
        gray = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
        det = detect(gray, target)
        found, raw = cv2.findChessboardCorners(gray, (9, 6))
        if not (det.found and found):
            continue
        flip = np.sum((det.q_px - truth) ** 2) > np.sum((det.q_px - truth[::-1]) ** 2)
        ours.append(det.q_px - (truth[::-1] if flip else truth))
        for h in theirs:
            c = cv2.cornerSubPix(gray, raw.copy(), (h, h), (-1, -1), CRITERIA).reshape(-1, 2)
            flip = np.sum((c - truth) ** 2) > np.sum((c - truth[::-1]) ** 2)
            theirs[h].append(c - (truth[::-1] if flip else truth))
    assert len(ours) >= 5
    best = min(_rms(d) for d in theirs.values())
    assert _rms(ours) <= best


def test_charuco_corners_are_refined_beyond_opencvs():
    # Metric: RMS corner error against the truth, px, microcal's detection against OpenCV's
    # ChArUco detector alone on the same rendered views.
    target = parse_target("charuco:5x4:20000")
    views = render_calibration_views(LARGE, target, 6, seed=5, blur_sigma_px=1.0)
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    board = cv2.aruco.CharucoBoard((target.cols, target.rows), target.pitch_um,
                                   target.feature_um, dictionary, target.marker_ids())  # fmt: skip
    ours, theirs = [], []
    for image, truth in zip(views.images, views.corners_px, strict=True):
        det = detect(image, target)
        c, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(_to_uint8(to_gray(image)))
        if not det.found or ids is None:
            continue
        ours.append(det.q_px - truth[det.ids])
        theirs.append(c.reshape(-1, 2) - truth[ids.ravel()])
    assert len(ours) >= 4
    assert _rms(ours) < 0.03
    assert _rms(ours) < 0.5 * _rms(theirs)


BUMBLEBEE = (Path(__file__).resolve().parents[2].parent / "shared" / "data"
             / "boofcv_bumblebee2_chess")  # fmt: skip


@pytest.mark.skipif(not (BUMBLEBEE / "left01.jpg").is_file(),
                    reason=f"the real stereo photographs are not here ({BUMBLEBEE} is absent)")  # fmt: skip
@pytest.mark.parametrize(("scale", "quality"), [(0.5, 75), (0.4, 60)])
def test_real_photographs_shrunk_to_webcam_squares_at_least_as_good_as_opencvs_best(scale, quality):
    # The Bumblebee2 photographs scaled down (squares of some 14-23 px at x0.5) and
    # recompressed: here OpenCV's finder puts some corners several pixels off, and a window
    # sized by their own spacing would not reach them. Metric: mono RMS reprojection error,
    # px, OpenCV's default lens model on the same views, microcal's corners against
    # cornerSubPix's at its best half-window 2..8.
    target = parse_target("chessboard:6x4:30000")
    obj = target.points_um().astype(np.float32)
    for side in ("left", "right"):
        grays = []
        for f in sorted(BUMBLEBEE.glob(f"{side}*.jpg")):
            g = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
            g = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            _, buf = cv2.imencode(".jpg", g, [cv2.IMWRITE_JPEG_QUALITY, quality])
            grays.append(cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE))
        size = grays[0].shape[::-1]
        dets = [detect(g, target) for g in grays]
        raw = [cv2.findChessboardCorners(g, (6, 4))[1] for g in grays]
        views = [i for i, d in enumerate(dets) if d.found and raw[i] is not None]
        assert len(views) >= 9
        ours = cv2.calibrateCamera([obj[dets[i].ids] for i in views],
                                   [dets[i].q_px.astype(np.float32) for i in views],
                                   size, None, None)[0]  # fmt: skip
        best = min(
            cv2.calibrateCamera([obj] * len(views),
                                [cv2.cornerSubPix(grays[i], raw[i].copy(), (h, h), (-1, -1),
                                                  CRITERIA) for i in views],
                                size, None, None)[0]
            for h in range(2, 9)
        )  # fmt: skip
        assert ours <= best, side
