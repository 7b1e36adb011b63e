"""Three real cameras in one calibration (procedures.stereo): the BoofCV trinocular ECoCheck
set, 30 views of three converging cameras, its 13 x 9 inner-corner board (codes printed in the
white squares) seen partly or not at all in some views and numbered from either end (the board
looks the same turned).

The images are not in the repository: they are read from ``../shared/data`` beside it (see
that folder's PROVENANCE.md), and the tests skip with the reason when it is absent. The square
size is unknown: lengths are in squares (the spec's pitch 1000 "µm" is one square).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from microcal.procedures.stereo import calibrate_views
from microcal.vision.targets import parse_target
from support.opencv_best_window import OpenCVReference

DATA = (Path(__file__).resolve().parents[2].parent / "shared" / "data"
        / "boofcv_trinocular_ecocheck")  # fmt: skip
TARGET = "chessboard:13x9:1000"
CAMERAS = ("left", "middle", "right")

pytestmark = [
    pytest.mark.skipif(not (DATA / "left" / "left1.jpg").is_file(),
                       reason=f"the real trinocular photographs are not here ({DATA} is absent)"),
    pytest.mark.slow,
]  # fmt: skip


def _files() -> dict[str, list[Path]]:
    return {cam: sorted((DATA / cam).glob(f"{cam}*.jpg")) for cam in CAMERAS}


def test_three_real_cameras_in_one_calibration():
    # One test, so that the set is detected and calibrated once (about a minute) whichever
    # worker runs it.
    files = _files()
    calibration = calibrate_views(
        {cam: [f.name for f in fs] for cam, fs in files.items()},
        lambda cam, i: [cv2.imread(str(files[cam][i]), cv2.IMREAD_GRAYSCALE)],
        parse_target(TARGET),
    )
    opencv = OpenCVReference(files, (13, 9))

    # Metric: mono RMS reprojection error, px, against OpenCV's at its best cornerSubPix
    # half-window (computed here, 0.093-0.095 px).
    for cam in CAMERAS:
        best, _ = opencv.best_mono_rms_px(cam)
        assert calibration.cameras[cam].rms_px <= best, cam
    # Metric: the three cameras' joint RMS, px, against OpenCV's three stereo pairs pooled
    # (each pair at its best half-window; OpenCV calibrates two cameras at a time).
    pairs = [opencv.best_stereo_rms_px(a, b)[0]
             for a, b in (("left", "middle"), ("left", "right"), ("middle", "right"))]  # fmt: skip
    assert calibration.rms_px <= float(np.sqrt(np.mean(np.square(pairs))))

    # Views seen by some cameras only are used: each camera calibrates from every view it
    # found the whole board in (the left camera one more than the three share).
    found = {cam: {i for i, r in enumerate(opencv.raw[cam]) if r is not None} for cam in CAMERAS}
    for cam in CAMERAS:
        assert calibration.cameras[cam].views_used == len(found[cam]), cam
    assert calibration.cameras["left"].views_used > len(set.intersection(*found.values()))
    assert calibration.views_rejected == []
    # the board was numbered from the other end in some views of the middle and right cameras
    assert calibration.turned_views
    assert {t["camera"] for t in calibration.turned_views} <= {"middle", "right"}

    figures = calibration.consistency
    closure = {tuple(c["cameras"]): c for c in figures["closure"]}
    lr = closure[("left", "middle", "right")]
    # Metric: left-right directly against composed through the middle camera:
    # |T_direct - T_composed| / |T_direct|, and the angle between the rotations.
    assert lr["translation_gap"] <= 0.005
    assert lr["rotation_gap_deg"] <= 0.1
    # PROVENANCE.md's OpenCV pairs: |T| 9.71 squares left-right, 4.94 left-middle.
    assert lr["baseline_um"] == pytest.approx(9710.0, rel=0.01)
    assert calibration.baseline_um == pytest.approx(4940.0, rel=0.01)
    # Metric: held-out views' RMS over the training views' (four interleaved folds).
    for cam in CAMERAS:
        assert figures["held_out"]["cameras"][cam]["ratio"] <= 1.2, cam
    assert figures["held_out"]["joint"]["ratio"] <= 1.2
    for axis in ("x", "y"):
        # Metric: the triangulated square along each axis against the spec's, relative.
        assert abs(figures["pitch"][axis]["error"]) <= 0.001
