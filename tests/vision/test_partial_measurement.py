"""Measurement of an end-effector whose target, numbered from markers, is partly out of the
field: the virtual point is the same target point whatever part is seen."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import sim
from microcal.errors import DetectionError
from microcal.sim.platforms import MARKED_END_EFFECTOR
from microcal.sim.render import Placement
from microcal.vision.detection import Detection
from microcal.vision.measurement import measure_poses
from microcal.vision.targets import parse_target
from microcal.vision.virtual_point import virtual_point

MARKED = parse_target("chessboard:10x8:400:markers=4,4/5,4/4,5")
TARGET = parse_target(MARKED_END_EFFECTOR)


def _pictures(target):
    """A tilted board's corners through a pinhole camera, px, and its centre's picture."""
    K = np.array([[3000.0, 0, 640], [0, 3000, 480], [0, 0, 1]])
    R = cv2.Rodrigues(np.array([0.3, -0.2, 0.4]))[0]
    t = np.array([-1800.0, -1400.0, 60000.0])

    def project(X):
        Y = X @ R.T + t
        return (Y[:, :2] / Y[:, 2:]) @ K[:2, :2].T + K[:2, 2]

    return project(target.points_um()), project(target.centre_um[None])[0]


def test_the_virtual_point_of_a_marked_target_is_its_centre_whatever_part_is_seen():
    q, centre = _pictures(MARKED)
    plane = MARKED.points_um()
    everything = np.arange(len(q))
    parts = {"whole": everything, "right": everything[plane[:, 0] > 1500],
             "top": everything[plane[:, 1] < 1000], "corner": everything[(plane[:, 0] > 2000) &
                                                                         (plane[:, 1] > 1500)]}  # fmt: skip
    for name, ids in parts.items():
        vp = virtual_point(Detection(True, ids, q[ids]), MARKED)
        # noise-free: the homography of the features seen carries the centre exactly
        assert np.allclose(vp.q_px, centre, atol=1e-6), name
    # the mean of the corners (a board without markers) is not the centre's picture under
    # perspective: the marked target's point is the truer one
    assert np.linalg.norm(q.mean(axis=0) - centre) > 0.1
    # with noise: unbiased, and the covariance the scatter's (whole board and a part of it)
    rng = np.random.default_rng(0)
    for ids in (everything, parts["right"]):
        got, covs = [], []
        for _ in range(300):
            vp = virtual_point(Detection(True, ids, q[ids] + 0.05 * rng.standard_normal((len(ids), 2))),
                               MARKED)  # fmt: skip
            got.append(vp.q_px - centre)
            covs.append(vp.cov_px2)
        scatter = np.cov(np.array(got).T)
        predicted = np.mean(covs, axis=0)
        # Metric: predicted against observed variance per axis (300 draws: +-20 %)
        assert np.allclose(np.diag(predicted), np.diag(scatter), rtol=0.25)
        assert np.all(np.abs(np.mean(got, axis=0)) < 3 * np.sqrt(np.diag(scatter) / 300))


def test_too_few_features_of_a_marked_target_say_so():
    q, _ = _pictures(MARKED)
    with pytest.raises(DetectionError, match="7 features of the target seen, 8 or more"):
        virtual_point(Detection(True, np.arange(7), q[:7]), MARKED)
    with pytest.raises(DetectionError, match="lie on one line"):
        virtual_point(Detection(True, np.arange(10), q[:10]), MARKED)


def _place_cut(plat, z_um):
    """A point of {G} where the side camera sees the markers and 30-90 % of the target, the
    top camera all of it, in focus in both."""
    models = [plat.cameras["top"].model, plat.cameras["side"].model]
    base = plat.truth_position_um()
    pts = TARGET.points_um() - TARGET.centre_um
    marks = np.array([pts[r * TARGET.cols + c] for c, r in TARGET.markers])

    def share(m, p, margin):
        w, h = m.image_size_px
        q = m.project(p)
        return np.mean((q[:, 0] > margin) & (q[:, 1] > margin) & (q[:, 0] < w - margin) &
                       (q[:, 1] < h - margin))  # fmt: skip

    steps = np.arange(-20000.0, 20001.0, 500.0)
    xy = np.stack(np.meshgrid(steps, steps), axis=-1).reshape(-1, 2)
    for d in xy[np.argsort(np.linalg.norm(xy, axis=1))]:  # the nearest such point
        p = base + np.array([d[0], d[1], z_um])
        placed = Placement(TARGET, np.eye(3), p - TARGET.centre_um)
        if (share(models[0], pts + p, 2) == 1 and 0.3 <= share(models[1], pts + p, 2) <= 0.9
                and share(models[1], marks + p, 30) == 1
                and max(c._blur_sigma(placed) for c in plat.cameras.values()) < 1.9):  # fmt: skip
            return p
    raise AssertionError("no such point")


@pytest.mark.slow
def test_a_marked_end_effector_partly_out_of_the_field_is_measured_as_the_whole_one():
    plat = sim.platform("thesis", seed=3, overrides={"board": MARKED_END_EFFECTOR})
    plat.scene.show_board = False
    base = plat.truth_position_um()
    points = [
        base + [dx, dy, dz] for dx, dy, dz in [(0, 0, 0), (600, -400, 200), (-500, 300, -200)]
    ]
    points += [_place_cut(plat, dz) for dz in (0.0, 200.0, -200.0)]
    frames = {}
    for k, p in enumerate(points):
        plat.scene.fixed = Placement(TARGET, np.eye(3), p - TARGET.centre_um)
        for name, cam in plat.cameras.items():
            frames[(k, name)] = [cam.grab() for _ in range(3)]
    got = measure_poses(list(range(len(points))), np.array(points), lambda k, n: frames[(k, n)],
                        plat.camera_models, TARGET)  # fmt: skip
    assert all(m.status == "ok" for m in got), [m.reason for m in got]
    seen = np.array([len(m.corners_px["side"]) for m in got]) / len(TARGET.points_um())
    assert np.all(seen[:3] == 1.0), seen
    assert np.all(seen[3:] < 0.95), seen
    err = np.array([m.p_um - p for m, p in zip(got, points, strict=True)])
    whole, cut = np.linalg.norm(err[:3], axis=1), np.linalg.norm(err[3:], axis=1)
    # Metric: 3D distance to the true end-effector, µm (4.5 px per 100 µm; 3 frames a pose):
    # the target partly out of the side camera's field is measured as well as the whole one
    assert np.sqrt(np.mean(cut**2)) < 1.0
    assert np.sqrt(np.mean(cut**2)) < 2.0 * np.sqrt(np.mean(whole**2)) + 0.2
    # a marker spec the target contradicts: every pose fails, naming the markers that fit
    wrong = parse_target(MARKED_END_EFFECTOR.replace("10,6/5,3", "11,6/5,2"))
    refused = measure_poses([0, 3], np.array(points)[[0, 3]], lambda k, n: frames[(k, n)],
                            plat.camera_models, wrong)  # fmt: skip
    for m in refused:
        assert m.status == "failed"
        assert "do not match the spec's markers" in m.reason
        assert "markers=5,6/10,6/5,3 would fit" in m.reason
        assert "\n" not in m.reason
    # the covariance grows where the centre is extrapolated, and stays honest
    sd = np.array([np.sqrt(np.trace(m.cov_um2)) for m in got])
    assert np.all(np.linalg.norm(err, axis=1) < 5 * sd + 0.3)


def test_a_small_target_is_searched_in_its_textured_region_and_a_slide_in_the_whole_image():
    from microcal.vision.marker_grid import _spectral_pitch_px
    from microcal.vision.target_region import textured_box

    plat = sim.platform("thesis", seed=1, overrides={"board": MARKED_END_EFFECTOR})
    cam = plat.cameras["top"]
    gray = cam.grab().astype(np.float32)
    box = textured_box(gray, _spectral_pitch_px(gray))
    assert box is not None
    q = cam.last_truth.features_px[0]
    # every dot inside, with room for its window; the box a small part of the frame
    assert box[0] < q[:, 0].min() - 10
    assert q[:, 0].max() + 10 < box[2]
    assert box[1] < q[:, 1].min() - 10
    assert q[:, 1].max() + 10 < box[3]
    w, h = cam.model.image_size_px
    assert (box[2] - box[0]) * (box[3] - box[1]) < 0.1 * w * h
    # a slide that fills the image (dots everywhere, large or small): the whole image
    yy, xx = np.mgrid[0:600, 0:800].astype(np.float32)
    for pitch in (23.0, 160.0):
        dots = np.hypot((xx % pitch) - pitch / 2, (yy % pitch) - pitch / 2) < 0.3 * pitch
        slide = cv2.GaussianBlur(np.where(dots, 40.0, 200.0).astype(np.float32), (0, 0), 1.0)
        assert textured_box(slide, pitch) is None
