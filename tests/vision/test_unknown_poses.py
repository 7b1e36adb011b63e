"""Camera calibration on rendered photographs with known truth (microcal.sim.calibration_views).

The sets reproduce what real photographs of a printed board by a wide-angle camera bring:
strong distortion (k1..k3 and tangential), a symmetric board seen turned, blur, noise.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal.errors import DegenerateDataError
from microcal.sim.calibration_views import (
    render_calibration_views,
    render_stereo_calibration_views,
    wide_angle_camera,
    wide_angle_stereo_pair,
)
from microcal.vision.board_symmetry import turn_ids
from microcal.vision.calibration_diagnostics import diagnose
from microcal.vision.detect import Detection, detect
from microcal.vision.lens_models import LENS_MODELS, choose_lens_model
from microcal.vision.stereo_calibration import calibrate_unknown_poses
from microcal.vision.targets import parse_target

SIZE = (640, 480)
#: k1, k2, p1, p2, k3 of a strongly distorting lens (about the Bumblebee2's).
WIDE = (-0.37, 0.24, 5e-4, -5e-4, -0.13)


def _views(target, n, seed, dist=WIDE, **kw):
    cam = wide_angle_camera(dist=dist)
    return cam, render_calibration_views(cam, target, n, seed=seed, **kw)


def _detected(views, target):
    """The views in which the board was found (nearly all: the smallest boards near the
    image's corners may be missed)."""
    dets = [d for d in (detect(im, target) for im in views.images) if d.found]
    assert len(dets) >= 0.8 * len(views.images)
    return [target.points_um()[d.ids] for d in dets], [d.q_px for d in dets], dets


@pytest.mark.parametrize("blur", [0.0, 0.7, 1.5])
def test_corners_are_at_least_as_accurate_as_cornersubpix_with_its_best_window(blur):
    target = parse_target("chessboard:6x4:30000")
    _, views = _views(target, 10, seed=3, blur_sigma_px=blur, noise_sigma=0.0 if blur == 0 else 2.0)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
    ours, theirs = [], {h: [] for h in (2, 3, 4, 5, 6, 7, 8)}
    for image, truth in zip(views.images, views.corners_px, strict=True):
        det = detect(image, target)
        assert det.found, det.reason
        # Metric: distance of each numbered corner to the true projection of that corner
        # (a turned view is numbered in the board's other order: match by position).
        ours.append(np.linalg.norm(det.q_px[:, None] - truth[None], axis=2).min(axis=1))
        ok, start = cv2.findChessboardCorners(image, target.pattern_size)
        assert ok
        for h in theirs:
            q = cv2.cornerSubPix(image, start.copy(), (h, h), (-1, -1), crit).reshape(-1, 2)
            theirs[h].append(np.linalg.norm(q[:, None] - truth[None], axis=2).min(axis=1))
    rms = float(np.sqrt(np.mean(np.concatenate(ours) ** 2)))
    best = min(float(np.sqrt(np.mean(np.concatenate(e) ** 2))) for e in theirs.values())
    assert rms <= best
    assert rms < 0.03  # px


def test_symmetric_board_numbered_by_colour_when_the_picture_tells():
    # 7 x 4 inner corners (odd x even): a board turned by 180 degrees still gets its own
    # numbering, so every detected corner is the true one of that number.
    target = parse_target("chessboard:7x4:25000")
    _, views = _views(target, 6, seed=5, flip_fraction=0.5)
    assert any(views.rotated_180)
    for image, truth in zip(views.images, views.corners_px, strict=True):
        det = detect(image, target)
        # Metric: worst distance of corner k to the true corner k, px.
        assert np.linalg.norm(det.q_px - truth[det.ids], axis=1).max() < 0.2


@pytest.mark.slow
def test_recovered_intrinsics_lie_within_their_reported_3_sigma():
    target = parse_target("chessboard:9x6:20000")
    z = []
    for seed in range(3):
        cam, views = _views(target, 15, seed=seed)
        obj, img, _ = _detected(views, target)
        choice = choose_lens_model(obj, img, SIZE)
        diag = diagnose(choice.fit, obj, img, SIZE)
        K, std = choice.fit.K, diag.std_intrinsics
        truth = {"fx": cam.K[0, 0], "fy": cam.K[1, 1], "cx": cam.K[0, 2], "cy": cam.K[1, 2]}
        est = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
        z += [(est[k] - truth[k]) / std[k] for k in truth]
        for k, true in zip(("k1", "k2", "p1", "p2", "k3"), WIDE, strict=True):
            if k in std:
                z.append((choice.fit.dist[("k1", "k2", "p1", "p2", "k3").index(k)] - true) / std[k])
    # Metric: every parameter's error in units of its reported standard deviation.
    assert np.max(np.abs(z)) < 3.0, np.round(z, 2)


#: Lens families and the ladder's name for them (all distortion terms non-zero).
FAMILIES = {
    "radial2": (-0.30, 0.12, 0.0, 0.0, 0.0),
    "radial3-tangential": WIDE,
}


@pytest.mark.slow
@pytest.mark.parametrize("family", list(FAMILIES))
def test_lens_model_selection_picks_the_true_family(family):
    target = parse_target("chessboard:9x6:20000")
    picked = []
    for seed in range(6):
        _, views = _views(target, 10, seed=100 + seed, dist=FAMILIES[family])
        obj, img, _ = _detected(views, target)
        choice = choose_lens_model(obj, img, SIZE)
        picked.append(choice.fit.model.name)
        held = {c["name"]: c["held_out_rms_px"] for c in choice.candidates}
        chosen = [m.name for m in LENS_MODELS].index(choice.fit.model.name)
        # Never a richer model whose held-out error is worse than a simpler one's.
        for m in LENS_MODELS[:chosen]:
            assert held[m.name] is None or held[m.name] >= held[choice.fit.model.name]
    assert picked.count(family) >= 5, picked


@pytest.mark.slow
def test_split_half_flags_few_clustered_views_and_passes_many_spread_ones():
    target = parse_target("chessboard:9x6:20000")
    _, few = _views(target, 5, seed=11, spread="centre")
    obj, img, _ = _detected(few, target)
    choice = choose_lens_model(obj, img, SIZE)
    diag = diagnose(choice.fit, obj, img, SIZE)
    assert diag.split_half is not None
    assert diag.split_half.flags
    assert any("too few views" in v for v in diag.verdict)

    _, many = _views(target, 20, seed=12, spread="wide")
    obj, img, _ = _detected(many, target)
    choice = choose_lens_model(obj, img, SIZE)
    diag = diagnose(choice.fit, obj, img, SIZE)
    assert diag.split_half is not None
    assert diag.split_half.flags == [], diag.verdict
    assert diag.verdict[0].startswith("no limit found")


@pytest.mark.slow
def test_stereo_with_a_symmetric_board_seen_turned():
    target = parse_target("chessboard:6x4:30000")  # looks the same turned by 180 degrees
    cams = wide_angle_stereo_pair()
    views = render_stereo_calibration_views(cams, target, 12, seed=21, flip_fraction=0.4)
    dets = {n: [detect(im, target) for im in views.images[n]] for n in cams}
    names = {n: [f"{n}{k:02d}" for k in range(12)] for n in cams}
    cal = calibrate_unknown_poses(dets, names, target, dict.fromkeys(cams, SIZE))
    # Metric: stereo RMS, px; baseline against the true 120 mm; rotation between the cameras
    # against the truth, deg.
    assert cal.rms_px < 0.05
    assert cal.baseline_um == pytest.approx(120_000.0, rel=0.005)
    left, right = (cams[n] for n in cams)
    R_true = right.R @ left.R.T
    assert cal.angle_deg == pytest.approx(
        np.degrees(np.arccos((np.trace(R_true) - 1) / 2)), abs=0.05
    )
    assert cal.views_rejected == []
    # Whatever each camera's detector numbered, the pairs now agree: in every view, the
    # right camera's numbering (turned where reported) relates to the true corners as the
    # left camera's does, and only such views were turned.
    turned = {t["image"] for t in cal.turned_views}
    assert all(t["turn_deg"] == 180 for t in cal.turned_views)
    n = len(target.points_um())

    def reversed_from_truth(det, truth):  # detected corner k is true corner n - 1 - k
        return np.linalg.norm(det.q_px - truth[::-1][det.ids], axis=1).max() < 1.0

    for k in range(12):
        left = reversed_from_truth(dets["left"][k], views.corners_px["left"][k])
        right = reversed_from_truth(dets["right"][k], views.corners_px["right"][k])
        assert (f"right{k:02d}" in turned) == (left != right), k
    assert n == 24


@pytest.mark.slow
def test_stereo_drops_a_pair_whose_pose_disagrees_and_says_why():
    target = parse_target("chessboard:7x4:25000")
    cams = wide_angle_stereo_pair()
    views = render_stereo_calibration_views(cams, target, 10, seed=31)
    a, b = list(cams)
    dets = {n: [detect(im, target) for im in views.images[n]] for n in cams}
    dets[b][4] = dets[b][7]  # a mixed-up file: camera b's view 4 is another pose
    names = {n: [f"{n}{k:02d}" for k in range(10)] for n in cams}
    cal = calibrate_unknown_poses(dets, names, target, dict.fromkeys(cams, SIZE))
    assert [r["view"] for r in cal.views_rejected] == [f"{a}04 + {b}04"]
    assert "relative rotation" in cal.views_rejected[0]["reason"]
    assert cal.baseline_um == pytest.approx(120_000.0, rel=0.005)


def _three_cameras():
    cams = wide_angle_stereo_pair()
    R, _ = cv2.Rodrigues(np.deg2rad([4.0, -6.0, 1.0]).reshape(3, 1))
    centre = np.array([60_000.0, -50_000.0, 0.0])
    cams["low"] = wide_angle_camera(
        "low",
        fx=530.0,
        fy=531.0,
        cx=322.0,
        cy=242.0,
        dist=(-0.35, 0.2, 2e-4, 3e-4, -0.1),
        R=R,
        t_um=-R @ centre,
    )
    return cams  # fmt: skip


@pytest.mark.slow
def test_three_cameras_in_one_joint_refinement_with_views_each_seen_by_a_subset():
    target = parse_target("chessboard:7x4:25000")
    cams = _three_cameras()
    n = 15
    views = render_stereo_calibration_views(cams, target, n, seed=41, flip_fraction=0.3)
    dets = {c: [detect(im, target) for im in views.images[c]] for c in cams}
    for k in range(0, 5):  # the third camera misses the first views, the second the last
        dets["low"][k] = Detection.none("target not found")
    for k in range(10, n):
        dets["right"][k] = Detection.none("target not found")
    names = {c: [f"{c}{k:02d}" for k in range(n)] for c in cams}
    cal = calibrate_unknown_poses(dets, names, target, dict.fromkeys(cams, SIZE))
    assert "joint refinement" in cal.method
    assert cal.views_rejected == []
    # Metric: each camera's pose relative to the first against the truth: rotation angle, deg;
    # distance between the projection centres' errors, µm (over 60-120 mm baselines).
    got = cal.models()
    for c in ("right", "low"):
        R_true = cams[c].R @ cams["left"].R.T
        R_got = got[c].R @ got["left"].R.T
        angle = np.degrees(np.arccos(np.clip((np.trace(R_got @ R_true.T) - 1) / 2, -1, 1)))
        assert angle < 0.15, c
        d_true = cams[c].centre_um - cams["left"].centre_um
        d_got = got[c].centre_um - got["left"].centre_um
        assert np.linalg.norm(d_got) == pytest.approx(np.linalg.norm(d_true), rel=0.005), c
    assert cal.rms_px < 0.08
    # Each camera's numbering agrees with the truth's relation in the views it saw.
    turned = {t["image"] for t in cal.turned_views}
    for c in ("right", "low"):
        for k in range(n):
            if not dets[c][k].found or not dets["left"][k].found:
                continue
            left_rev = _reversed(dets["left"][k], views.corners_px["left"][k])
            this_rev = _reversed(dets[c][k], views.corners_px[c][k])
            assert (f"{c}{k:02d}" in turned) == (left_rev != this_rev), (c, k)


@pytest.mark.slow
def test_a_camera_that_shares_no_view_with_the_others_is_refused_with_its_name():
    target = parse_target("chessboard:7x4:25000")
    cams = _three_cameras()
    views = render_stereo_calibration_views(cams, target, 10, seed=43)
    dets = {c: [detect(im, target) for im in views.images[c]] for c in cams}
    for k in range(10):  # "low" sees only the views nobody else sees
        if k < 5:
            dets["low"][k] = Detection.none("target not found")
        else:
            dets["left"][k] = dets["right"][k] = Detection.none("target not found")
    names = {c: [f"{c}{k:02d}" for k in range(10)] for c in cams}
    with pytest.raises(DegenerateDataError, match="low share no usable view"):
        calibrate_unknown_poses(dets, names, target, dict.fromkeys(cams, SIZE))


def _reversed(det, truth):
    """Detected corner k is true corner n - 1 - k (the board's numbering turned by 180)."""
    return np.linalg.norm(det.q_px - truth[::-1][det.ids], axis=1).max() < 1.0


@pytest.mark.slow
def test_three_cameras_agree_on_a_symmetric_board_through_one_another():
    target = parse_target("chessboard:6x4:30000")  # looks the same turned by 180 degrees
    cams = _three_cameras()
    n = 16
    views = render_stereo_calibration_views(cams, target, n, seed=45, flip_fraction=0.4)
    dets = {c: [detect(im, target) for im in views.images[c]] for c in cams}
    for k in range(11, n):  # views 11-15: seen by "right" and "low" only
        dets["left"][k] = Detection.none("target not found")
    for k in range(0, 5):
        dets["low"][k] = Detection.none("target not found")
    for k in range(5, 11):  # "right" numbered the views all three see from the other end
        d = dets["right"][k]
        ids = turn_ids(target, 180)[d.ids]
        order = np.argsort(ids)
        dets["right"][k] = Detection(True, ids[order], d.q_px[order], d.quality_px)
    names = {c: [f"{c}{k:02d}" for k in range(n)] for c in cams}
    cal = calibrate_unknown_poses(dets, names, target, dict.fromkeys(cams, SIZE))
    assert cal.views_rejected == []
    turned = {t["image"] for t in cal.turned_views}
    rev = {c: [_reversed(dets[c][k], views.corners_px[c][k]) if dets[c][k].found else None
               for k in range(n)] for c in cams}  # fmt: skip
    # The numbering each view follows: the left camera's, else the right one's as turned.
    reference = [
        rev["left"][k] if rev["left"][k] is not None else rev["right"][k] != (f"right{k:02d}" in turned)
        for k in range(n)
    ]  # fmt: skip
    composed = 0
    for c in ("right", "low"):
        for k in range(n):
            if rev[c][k] is None:
                continue
            assert (f"{c}{k:02d}" in turned) == (rev[c][k] != reference[k]), (c, k)
            composed += c == "low" and 5 <= k <= 10 and f"right{k:02d}" in turned
    # "low" shares most views with "right": its views 5-10 were numbered through right's
    # turned ones (the turns composed).
    assert composed == 6
    got = cal.models()
    for c in ("right", "low"):  # Metric: distance from the first camera, relative.
        d_true = np.linalg.norm(cams[c].centre_um - cams["left"].centre_um)
        d_got = np.linalg.norm(got[c].centre_um - got["left"].centre_um)
        assert d_got == pytest.approx(d_true, rel=0.005), c
