"""A real slide that overfills the field: the DICe dot-grid stereo set (14 pairs of 2448 x 2048
photographs, dots of 3.5 mm pitch running past every edge, three hollow marker dots).

Four of the pairs, to stay fast; ``scripts/dice_dotgrid_figures.py`` measures all 14 (the
figures in docs/vision.md). The tests skip with the reason when the data is absent.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from microcal.errors import InputError
from microcal.geometry import triangulate
from microcal.vision.detect import Detection, detect
from microcal.vision.targets import parse_target

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "dice_dotgrid_stereo"
SPEC = "dotgrid:13x11:3500:1400:markers=3,7/8,7/3,4"
VIEWS = (1, 5, 9, 13)
SIZE = (2448, 2048)

pytestmark = [
    pytest.mark.skipif(
        not (DATA / "CalB-sys2-0001_0.jpeg").is_file(),
        reason=f"the real dot-grid photographs are not here ({DATA} is absent)",
    ),
    # the module's tests share what a fixture makes once: one worker runs them all
    pytest.mark.xdist_group("dice-dotgrid"),
]


def _name(view: int, side: int) -> str:
    return f"CalB-sys2-{view:04d}_{side}.jpeg"


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    from microcal.workflows.stereo import stereo_calibrate_images

    folder = tmp_path_factory.mktemp("dice")
    for v in VIEWS:
        for s in (0, 1):
            (folder / _name(v, s)).symlink_to(DATA / _name(v, s))
    out = folder / "cameras.json"
    seen: list[tuple[np.ndarray, Detection]] = []  # each image as detected by the command

    def recording(image, target, **kwargs):
        det = detect(image, target, **kwargs)
        seen.append((np.asarray(image, dtype=np.float32), det))
        return det

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("microcal.procedures.stereo.detect", recording)
        cal = stereo_calibrate_images(
            SPEC,
            [f"left={folder}/CalB-sys2-*_0.jpeg", f"right={folder}/CalB-sys2-*_1.jpeg"],
            out,
        )  # the automatic lens choice, as a user gets it
    target = parse_target(SPEC)
    assert len(seen) == 2 * len(VIEWS)  # camera by camera, views in order
    images = {(v, s): seen[s * len(VIEWS) + k][0] for k, v in enumerate(VIEWS) for s in (0, 1)}
    dets = {cam: [seen[s * len(VIEWS) + k][1] for k in range(len(VIEWS))]
            for s, cam in ((0, "left"), (1, "right"))}  # fmt: skip
    return cal, out, target, images, dets


@pytest.mark.slow
def test_the_partial_grids_calibrate_a_stereo_pair_below_a_third_of_a_pixel(calibrated):
    cal, out, _, _, dets = calibrated
    assert out.is_file()
    for cam in ("left", "right"):
        assert all(d.found for d in dets[cam]), [d.reason for d in dets[cam]]
        assert min(len(d.ids) for d in dets[cam]) >= 70
        assert cal.cameras[cam].views_used == len(VIEWS)
    # Metric: stereo RMS reprojection error over both cameras, px (the makers' own tool
    # passes this set at 0.75 px)
    assert cal.rms_px <= 0.3
    assert any("measured" in n for n in cal.notes)


@pytest.mark.slow
def test_the_triangulated_pitch_is_the_slides_along_both_axes(calibrated):
    cal, _, target, _, dets = calibrated
    left, right = cal.cameras["left"].model, cal.cameras["right"].model
    steps: dict[str, list[float]] = {"x": [], "y": []}
    for a, b in zip(dets["left"], dets["right"], strict=True):
        common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
        p = triangulate(left.P, right.P, left.undistort_px(a.q_px[ia]),
                        right.undistort_px(b.q_px[ib]))  # fmt: skip
        where = {int(i): k for k, i in enumerate(common)}
        for i, k in where.items():
            if i + 1 in where and (i % target.cols) + 1 < target.cols:
                steps["x"].append(float(np.linalg.norm(p[where[i + 1]] - p[k])))
            if i + target.cols in where:
                steps["y"].append(float(np.linalg.norm(p[where[i + target.cols]] - p[k])))
    for axis, d in steps.items():
        # Metric: mean triangulated neighbour distance over the field against 3.5 mm, %
        error = (np.mean(d) / target.pitch_um - 1.0) * 100.0
        assert abs(error) < 0.1, axis
        assert len(d) > 200


@pytest.mark.slow
def test_cameras_json_states_the_pitch_against_the_slides_stated_one(calibrated):
    """The consistency figures compare with the stated 3.5 mm, though the plate's own dots
    were measured off their lattice (the print's error)."""
    _, out, target, _, _ = calibrated
    pitch = json.loads(out.read_text())["stereo"]["consistency"]["pitch"]
    for axis in ("x", "y"):
        assert pitch[axis]["nominal_um"] == target.pitch_um
        assert abs(pitch[axis]["error"]) < 1e-3, axis  # 0.1 %
        assert pitch[axis]["segments"] > 200


def _opencv_centres(gray: np.ndarray, det: Detection) -> Detection:
    """The same dots at the centres OpenCV's blob detector gives (``findCirclesGrid``'s)."""
    params = cv2.SimpleBlobDetector_Params()
    params.minArea, params.maxArea = 500, 60000
    params.filterByConvexity = params.filterByInertia = False
    keys = cv2.SimpleBlobDetector_create(params).detect(np.clip(gray, 0, 255).astype(np.uint8))
    pts = np.array([k.pt for k in keys])
    d = np.linalg.norm(det.q_px[:, None, :] - pts[None, :, :], axis=2)
    nearest = d.argmin(axis=1)
    ok = d[np.arange(len(nearest)), nearest] < 10.0
    return Detection(True, det.ids[ok], pts[nearest[ok]])


@pytest.mark.slow
def test_microcal_is_at_least_as_good_as_opencv_given_the_same_dots(calibrated):
    """OpenCV cannot find a partial grid; it is given microcal's numbering with its own blob
    centres, and its best of calibrateCamera / calibrateCameraRO (which also refines the
    target's points), with the same lens terms."""
    cal, _, target, images, dets = calibrated
    P = target.points_um().astype(np.float32)
    flags = cv2.CALIB_FIX_K3
    mono = {}
    for s, cam in ((0, "left"), (1, "right")):
        ocv = [_opencv_centres(images[v, s], d) for v, d in zip(VIEWS, dets[cam], strict=True)]
        obj = [P[d.ids] for d in ocv]
        img = [d.q_px.astype(np.float32) for d in ocv]
        plain = cv2.calibrateCamera(obj, img, SIZE, None, None, flags=flags)
        common = sorted(set.intersection(*[set(d.ids.tolist()) for d in ocv]))
        img_c = [d.q_px[np.searchsorted(d.ids, common)].astype(np.float32) for d in ocv]
        ro = cv2.calibrateCameraRO([P[common]] * len(ocv), img_c, SIZE, len(common) - 1, None,
                                   None, flags=flags)  # fmt: skip
        best = min(plain[0], ro[0])
        mono[cam] = (plain[1], plain[2]) if plain[0] <= ro[0] else (ro[1], ro[2])
        # Metric: mono RMS reprojection error, px, microcal against OpenCV's best
        assert cal.cameras[cam].rms_px <= best, cam
        dets[f"ocv-{cam}"] = ocv
    obj, left, right = [], [], []
    for a, b in zip(dets["ocv-left"], dets["ocv-right"], strict=True):
        common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
        obj.append(P[common])
        left.append(a.q_px[ia].astype(np.float32))
        right.append(b.q_px[ib].astype(np.float32))
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-9)
    ways = (cv2.CALIB_FIX_INTRINSIC, cv2.CALIB_USE_INTRINSIC_GUESS | flags)
    runs = [cv2.stereoCalibrate(obj, left, right, *mono["left"], *mono["right"], SIZE, flags=f,
                                criteria=crit) for f in ways]  # fmt: skip
    stereo = min(r[0] for r in runs)
    # Metric: stereo RMS reprojection error, px, microcal against OpenCV's best
    assert cal.rms_px <= stereo


@pytest.mark.slow
def test_a_marker_spec_that_does_not_match_the_plate_names_the_fix(tmp_path):
    from microcal.workflows.stereo import stereo_calibrate_images

    for v in VIEWS[:3]:
        for s in (0, 1):
            (tmp_path / _name(v, s)).symlink_to(DATA / _name(v, s))
    out = tmp_path / "cameras.json"
    # the makers' file counts 6 and 4 dots from the origin to the markers, both ends
    # included: 5 and 3 steps
    wrong = "dotgrid:13x11:3500:1400:markers=3,7/9,7/3,3"
    with pytest.raises(InputError) as err:
        stereo_calibrate_images(wrong, [f"left={tmp_path}/*_0.jpeg",
                                        f"right={tmp_path}/*_1.jpeg"], out)  # fmt: skip
    assert "\n" not in str(err.value)
    assert "markers=3,7/8,7/3,4 would fit" in str(err.value)
    assert not out.exists()
