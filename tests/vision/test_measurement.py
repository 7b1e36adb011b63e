"""Stereo calibration from rendered images and 3D measurement, against the simulator's truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import sim
from microcal.experiments.demo import calibrate_on_platform
from microcal.sim.render import Placement
from microcal.vision.corner_refinement import WINDOW_FRACTION, _gradient_step, local_spacing_px
from microcal.vision.detect import detect, to_gray
from microcal.vision.measurement import measure_poses
from microcal.vision.stereo_calibration import (
    calibrate_unknown_poses,
)
from microcal.vision.targets import parse_target
from microcal.vision.virtual_point import virtual_point

BOARD = parse_target("chessboard:4x3:400")
GRID = parse_target("dotgrid:40x30:250")
STEPS_UM = np.array([[0.0, 0.0, z] for z in (0.0, 1000.0, 2000.0, 3000.0, 4000.0)])
FRAMES_PER_VIEW = 8


def sizes(plat):
    return {n: c.model.image_size_px for n, c in plat.cameras.items()}


def truth_reprojection_px(model, truth_model, pts_v, pts_g):
    """RMS distance between where the calibrated and the true camera put the same points."""
    return float(
        np.sqrt(np.mean(np.sum((model.project(pts_v) - truth_model.project(pts_g)) ** 2, axis=1)))
    )


def workspace_points(n=500):
    return np.random.default_rng(0).uniform([0, 0, 0], [9000, 9000, 5000], (n, 3))


# the module's tests share what a fixture makes once: one worker runs them all
pytestmark = pytest.mark.xdist_group("vision-measurement")


@pytest.fixture(scope="module")
def known_calibration():
    """Method (a): the dot grid at five known heights (stage steps), {V} = {G}."""
    plat = sim.platform("thesis", seed=21)
    return plat, calibrate_on_platform(plat, GRID, STEPS_UM, FRAMES_PER_VIEW)


@pytest.mark.slow
def test_known_displacements_calibration(known_calibration):
    plat, cal = known_calibration
    pts = workspace_points()
    for name, c in cal.cameras.items():
        assert c.views_used == 5
        # Thesis: 0.091 / 0.054 px. Metric: RMS reprojection error of the detected dots.
        assert c.rms_px <= 0.1
        # Recovered camera vs truth: RMS px over points filling the travel.
        assert truth_reprojection_px(c.model, plat.cameras[name].model, pts, pts) <= 0.1


@pytest.mark.slow
def test_unknown_poses_calibration():
    plat = sim.platform("thesis", seed=22)
    plat.scene.show_board = False
    target = parse_target("chessboard:9x7:500")
    rng = np.random.default_rng(3)
    dets = {n: [] for n in plat.cameras}
    names = {n: [] for n in plat.cameras}
    poses = []
    for k in range(16):
        R, _ = cv2.Rodrigues(np.deg2rad(rng.uniform(-35, 35, 3)) * [1, 1, 0.5])
        t = rng.uniform([1000, 1000, 500], [6000, 5000, 4000]) - R @ target.centre_um
        poses.append((R, t))
        plat.scene.fixed = Placement(target, R, t)
        for n, cam in plat.cameras.items():
            image = np.mean([cam.grab().astype(np.float32) for _ in range(FRAMES_PER_VIEW)], axis=0)
            dets[n].append(detect(image, target))
            names[n].append(f"{n}_{k}")
    cal = calibrate_unknown_poses(dets, names, target, sizes(plat))
    R0, t0 = poses[0]
    pts_g = workspace_points()
    pts_v = (pts_g - t0) @ R0  # {V} is the target's frame in view 0
    for name, c in cal.cameras.items():
        assert c.rms_px <= 0.1
        # A microscope's field is a few degrees wide: k1 only, and said so.
        assert c.lens_model["name"] == "radial1"
        assert c.lens_model["reason"].startswith("narrow field")
        assert c.lens_model["field_of_view_deg"] < 10.0
        for r in c.views_rejected:  # outlier views are reported with the reason
            assert "reprojection RMS" in r["reason"]
        # Planar targets leave a microscope's principal point weakly determined (docs):
        # the recovered camera is held to 2 px over the travel, method (a) to 0.1 px.
        assert truth_reprojection_px(c.model, plat.cameras[name].model, pts_v, pts_g) <= 2.0


@pytest.mark.slow
def test_3d_measurement_of_100_poses(known_calibration):
    _, cal = known_calibration
    plat = sim.platform("thesis", seed=23)
    m = plat.manipulator
    d = np.random.default_rng(4).uniform([0, 0, 0], [8000, 8000, 4800], (100, 3))
    frames, truth = {}, []
    for i, di in enumerate(d):
        m.move_to_um(di)
        m.wait_until_stopped(plat.clock)
        plat.clock.sleep(5.0)
        truth.append(plat.truth_position_um())
        for n, cam in plat.cameras.items():
            frames[(i, n)] = [cam.grab() for _ in range(5)]
    res = measure_poses(list(range(100)), d, lambda i, n: frames[(i, n)], cal.models(), BOARD)
    assert all(r.status == "ok" for r in res)
    e = np.array([r.p_um for r in res]) - np.array(truth)
    cov = np.array([r.cov_um2 for r in res])
    # Metric: RMS of the 3D error against ground truth (the thesis claimed ±3 µm unmeasured).
    assert np.sqrt(np.mean(np.sum(e**2, axis=1))) <= 2.0
    # The reported covariance is nearly honest: normalised errors have a mean square near 3
    # (3.3 with the true cameras). With the calibrated ones it is about 4.1: the cameras'
    # own error (0.007-0.014 px per axis against the true cameras, mostly an offset common to
    # all views, which the jackknife behind projection_sigma_px cannot see: it finds 0.002-
    # 0.005 px) has become comparable with the noise of five averaged frames (docs/vision.md).
    m2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e)
    assert 2.4 <= m2.mean() <= 4.5
    # the cameras measured in two processes at once: the very same numbers
    again = measure_poses(list(range(100)), d, lambda i, n: frames[(i, n)], cal.models(), BOARD,
                          workers=2)  # fmt: skip
    np.testing.assert_array_equal([r.p_um for r in again], [r.p_um for r in res])
    np.testing.assert_array_equal([r.cov_um2 for r in again], [r.cov_um2 for r in res])


@pytest.mark.slow
def test_table_4_1_with_the_library_detector():
    plat = sim.platform("thesis", seed=24)
    plat.manipulator.move_to_um([4000, 4000, 2400])
    plat.manipulator.wait_until_stopped(plat.clock)
    plat.clock.sleep(10.0)
    cam = plat.cameras["top"]
    corners, vps, gradient = [], [], []
    for _ in range(100):
        image = cam.grab()
        det = detect(image, BOARD)
        corners.append(det.q_px)
        vps.append(virtual_point(det, BOARD).q_px)
        # cornerSubPix alone (the refinement's first step), the kind of refiner the thesis's
        # toolbox had.
        half = WINDOW_FRACTION * local_spacing_px(det.q_px, *BOARD.pattern_size)
        gradient.append(_gradient_step(to_gray(image), det.q_px, half))
    by_gradient = np.array(gradient)[:, 5].std(axis=0, ddof=1)
    one = np.array(corners)[:, 5].std(axis=0, ddof=1)
    vp = np.array(vps).std(axis=0, ddof=1)
    # Thesis Table 4-1: one corner 0.207 / 0.172 px, the virtual point 0.087 / 0.045 px, at
    # least 2.5x steadier. The simulated images give that scatter to a gradient refiner;
    # microcal's symmetry fit halves it. What is left of the virtual point's scatter is
    # mostly the whole board's vibration, which no refiner removes, so it stays at the
    # thesis's figure and only a little steadier than one microcal corner.
    np.testing.assert_allclose(by_gradient, [0.207, 0.172], rtol=0.30)
    assert np.all(by_gradient / vp >= 2.5)
    assert np.all(one <= 0.6 * by_gradient)
    assert np.all(vp <= one)
    assert np.all(vp <= 1.3 * np.array([0.087, 0.045]))


@pytest.mark.slow
def test_a_failed_view_is_a_status_not_an_exception(known_calibration):
    _, cal = known_calibration
    blank = np.full((1200, 1600), 90, np.uint8)
    res = measure_poses([1], np.zeros((1, 3)), lambda i, n: [blank], cal.models(), BOARD)
    assert res[0].status == "failed"
    assert "no 4x3 chessboard found" in res[0].reason
    wrong = np.zeros((100, 100), np.uint8)
    res = measure_poses([1], np.zeros((1, 3)), lambda i, n: [wrong], cal.models(), BOARD)
    assert "image is 100x100 px" in res[0].reason
