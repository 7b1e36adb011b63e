"""Stereo calibration from images of a target (thesis chapter 3, section 5.1).

Two methods, both for any number of cameras seeing the same target:

(a) :func:`calibrate_known_displacements`, the thesis's: the target is moved by known
    displacements (for example z steps of a stage), so every feature has a known position in
    {V} (the target's frame at zero displacement). Each camera: DLT (Eq 3.7-3.15) on all the
    non-coplanar points, decomposition (Eq 3.16), then a non-linear refinement of the whole
    camera model with the distortion of Eq 3.3 (OpenCV's solver with the DLT as start).
(b) :func:`calibrate_unknown_poses`: the target is held in unknown poses. Each camera is
    calibrated alone, its lens model chosen by held-out error
    (:mod:`~microcal.vision.lens_models`) and diagnosed
    (:mod:`~microcal.vision.calibration_diagnostics`); the corner numbering of a board
    that looks the same turned is made to agree between the cameras by the stereo geometry
    (:mod:`~microcal.vision.view_consistency`); then the cameras are related by stereo
    calibration with those intrinsics fixed, and finally intrinsics, lens terms and poses of
    all cameras are refined together (:mod:`~microcal.vision.joint_intrinsics`). {V} is the
    target's frame in a chosen reference view.

Views whose reprojection error stands out (above 3x the median view and 0.15 px) are
rejected and reported with the reason, and the cameras are calibrated again without them;
so are view pairs whose relative pose disagrees with the others' and pairs that stand out in
the stereo solve. This module gathers them: the methods live in
:mod:`~microcal.vision.known_displacements` and :mod:`~microcal.vision.unknown_poses`, their
results in :mod:`~microcal.vision.calibration_result`.
"""

from __future__ import annotations

from .calibration_result import CameraCalibration, StereoCalibration
from .known_displacements import calibrate_known_displacements
from .unknown_poses import calibrate_unknown_poses

__all__ = [
    "CameraCalibration",
    "StereoCalibration",
    "calibrate_known_displacements",
    "calibrate_unknown_poses",
]
