"""Method (a), the thesis's: the target at known displacements (thesis section 5.1).

The target is moved by known displacements (for example z steps of a stage), so every feature
has a known position in {V} (the target's frame at zero displacement). Each camera: DLT (Eq
3.7-3.15) on all the non-coplanar points, decomposition (Eq 3.16), then a non-linear
refinement of the camera model with the distortion of Eq 3.3 (OpenCV's solver with the DLT
as start); the calibration's own projection error by the jackknife over views. Views whose
error stands out are rejected with the reason; a symmetric target's views are numbered alike.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from ..geometry import CameraModel, decompose_projection_matrix, estimate_projection_matrix
from ..geometry.reprojection import reprojection_error
from .board_symmetry import ambiguous_turns
from .calibration_result import (
    CameraCalibration,
    StereoCalibration,
    _baseline,
    _camera_model,
    _fit_rejecting_outliers,
    _renumbered,
    _residuals,
    _usable,
)
from .detect import Detection
from .lens_models import opencv_reason
from .targets import Target

__all__ = ["calibrate_known_displacements"]


def _align_views(
    detections: Sequence[Detection], used: Sequence[int], target: Target
) -> tuple[list[Detection], dict[int, int]]:
    """Number every view's features as the first used view does (method (a)).

    Between views of known displacements the target only moves, so each view's picture is
    close to the first's: of the turns its picture cannot tell apart, each view takes the one
    that puts every feature nearest, after the centroids are matched, to the same feature
    in the first view.
    """
    out = list(detections)
    turns = ambiguous_turns(target)
    if len(turns) == 1 or not used:
        return out, {}
    ref = detections[used[0]]
    ref_q = np.full((len(target.points_um()), 2), np.nan)
    ref_q[ref.ids] = ref.q_px - ref.q_px.mean(axis=0)
    turned: dict[int, int] = {}
    for i in used[1:]:
        cost = {}
        for t in turns:
            det = _renumbered(detections[i], target, t)
            d = det.q_px - det.q_px.mean(axis=0) - ref_q[det.ids]
            cost[t] = float(np.nanmean(np.sum(d**2, axis=1)))
        best = min(cost, key=lambda k: cost[k])
        if best != 0:
            out[i] = _renumbered(detections[i], target, best)
            turned[i] = best
    return out, turned


def _turn_by_steps(
    detections: list[Detection],
    used: Sequence[int],
    target: Target,
    displacements_um: FloatArray,
    turned: dict[int, int],
) -> tuple[list[Detection], dict[int, int]]:
    """Turn a camera's whole numbering to the one its steps across the target's plane fit.

    A numbering turned by 180 degrees sees a step along the target's +x as one along -x: the
    projection matrix then cannot fit the views. Without such steps nothing changes.
    """
    turns = ambiguous_turns(target)
    if len(turns) == 1 or len(used) < 2 or not _steps_in_plane(target, displacements_um):
        return detections, turned
    rms = {}
    for t in turns:
        dets = [_renumbered(detections[i], target, t) for i in used]
        p = np.vstack([target.points_um()[d.ids] + displacements_um[i]
                       for d, i in zip(dets, used, strict=True)])  # fmt: skip
        q = np.vstack([d.q_px for d in dets])
        try:
            P = estimate_projection_matrix(p, q)
        except DegenerateDataError:
            return detections, turned
        rms[t] = float(np.sqrt(np.mean(reprojection_error(P, p, q) ** 2)))
    best = min(rms, key=lambda k: rms[k])
    if best == 0:
        return detections, turned
    out = list(detections)
    for i in used:
        out[i] = _renumbered(detections[i], target, best)
    total = {i: (turned.get(i, 0) + best) % 360 for i in used}
    return out, {i: t for i, t in total.items() if t}


def _steps_in_plane(target: Target, disp: FloatArray) -> bool:
    """True if the steps move the target across its plane by more than a pitch."""
    return len(disp) > 0 and float(np.max(np.ptp(disp[:, :2], axis=0))) > target.pitch_um


def _calibrate_one_known(
    name: str,
    detections: Sequence[Detection],
    image_names: Sequence[str],
    target: Target,
    displacements_um: FloatArray,
    size: tuple[int, int],
    refine: bool,
) -> tuple[CameraCalibration, dict[int, int]]:
    used, rejected = _usable(detections, image_names)
    detections, turned = _align_views(detections, used, target)
    detections, turned = _turn_by_steps(detections, used, target, displacements_um, turned)
    points = target.points_um()

    def calibrate(views: list[int]) -> tuple[tuple[CameraModel, dict[str, list[float]],
                                             dict[int, FloatArray]], dict[int, float]]:  # fmt: skip
        if len(views) < 2:
            raise DegenerateDataError(
                f"camera {name}: the target was found in {len(views)} image(s); at least 2 at "
                f"different depths are needed"
            )
        model, std = _fit_known(*_known_points(detections, views, target, displacements_um),
                                size, name, refine)  # fmt: skip
        residuals = {
            i: _residuals(
                model.project(points[detections[i].ids] + displacements_um[i]), detections[i].q_px
            )
            for i in views
        }
        rms = {
            i: float(np.sqrt(np.mean(np.sum(r[:, 2:] ** 2, axis=1)))) for i, r in residuals.items()
        }
        return (model, std, residuals), rms

    (model, std, residuals), used, bad = _fit_rejecting_outliers(used, calibrate)
    rejected += [{"image": image_names[i], "reason": r} for i, r in bad.items()]
    all_err = np.concatenate([residuals[i][:, 2:] for i in used])
    rms_all = float(np.sqrt(np.mean(np.sum(all_err**2, axis=1))))
    rms_views = {
        image_names[i]: float(np.sqrt(np.mean(np.sum(residuals[i][:, 2:] ** 2, axis=1))))
        for i in used
    }
    sigma = _jackknife_sigma_px(detections, used, target, displacements_um, size, refine, model)
    model = dataclasses.replace(model, projection_sigma_px=sigma)
    by_name = {image_names[i]: residuals[i] for i in used}
    cal = CameraCalibration(model, rms_all, rms_views, len(used), rejected, std, by_name)
    return cal, turned


def _known_points(
    detections: Sequence[Detection], used: Sequence[int], target: Target, disp: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Target points in {V} (N, 3) and their pixels (N, 2) over the views ``used``."""
    p = np.vstack([target.points_um()[detections[i].ids] + disp[i] for i in used])
    q = np.vstack([detections[i].q_px for i in used])
    return p, q


def _fit_known(
    p: FloatArray, q: FloatArray, size: tuple[int, int], name: str, refine: bool
) -> tuple[CameraModel, dict[str, list[float]]]:
    """DLT (Eq 3.7-3.15), decomposition (Eq 3.16) and, with ``refine``, OpenCV's non-linear
    refinement with distortion (k1, k2, p1, p2) started from it."""
    P = estimate_projection_matrix(p, q)
    K, R, t = decompose_projection_matrix(P)
    K = np.triu(K) / K[2, 2]
    if refine:
        K[0, 1] = 0.0  # OpenCV's model has no skew
    model = CameraModel(K, np.zeros(5), R, t, size, name)
    if not refine:
        return model, {}
    rvec, _ = cv2.Rodrigues(R)
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3
    try:
        _, K2, d2, rvecs, tvecs, sd_in, _, _ = cv2.calibrateCameraExtended(
            [p.astype(np.float32)],
            [q.astype(np.float32)],
            size,
            model.K.copy(),
            np.zeros(5),
            rvecs=[rvec.astype(np.float64)],
            tvecs=[t.reshape(3, 1).astype(np.float64).copy()],
            flags=flags | cv2.CALIB_USE_EXTRINSIC_GUESS,
        )
    except cv2.error as exc:
        raise DegenerateDataError(
            f"camera {name}: the views do not fit one camera (OpenCV: {opencv_reason(exc)}); "
            "are the steps in µm, one row per image in the images' sorted order?"
        ) from None
    sd = np.asarray(sd_in).ravel()
    std = {"fx_fy_cx_cy_px": sd[:4].tolist(), "k1_k2_p1_p2_k3": sd[4:9].tolist()}
    return _camera_model(K2, d2, rvecs[0], tvecs[0], size, name), std


def _jackknife_sigma_px(
    detections: Sequence[Detection],
    used: Sequence[int],
    target: Target,
    disp: FloatArray,
    size: tuple[int, int],
    refine: bool,
    model: CameraModel,
) -> float:
    """The calibration's own projection error (px per axis), by the jackknife over views.

    The camera is calibrated again without each view in turn; the spread of the calibrated
    volume's projections over those calibrations, times (n - 1) / n, estimates the variance
    of the calibration made from all n views. Unlike the covariance of the fit, it counts
    what differs from view to view beyond pixel noise (a view's detection bias, the stage's
    step error). 0 with fewer than 3 views or when a reduced set cannot be calibrated.
    """
    n = len(used)
    if n < 3:
        return 0.0
    p_all, _ = _known_points(detections, used, target, disp)
    projections = []
    for j in used:
        rest = [i for i in used if i != j]
        try:
            cam, _ = _fit_known(*_known_points(detections, rest, target, disp), size,
                                model.name, refine)  # fmt: skip
        except (DegenerateDataError, cv2.error):
            return 0.0
        projections.append(cam.project(p_all))
    q = np.array(projections)
    var = (n - 1) / n * np.sum((q - q.mean(axis=0)) ** 2, axis=0).sum(axis=1) / 2.0
    return float(np.sqrt(np.mean(var)))


def calibrate_known_displacements(
    detections: Mapping[str, Sequence[Detection]],
    image_names: Mapping[str, Sequence[str]],
    target: Target,
    displacements_um: FloatArray,
    image_size_px: Mapping[str, tuple[int, int]],
    *,
    refine: bool = True,
) -> StereoCalibration:
    """Method (a): the target at known displacements (thesis 5.1).

    Parameters
    ----------
    detections : dict camera -> list of Detection
        One detection per image, the images in the order of ``displacements_um``.
    image_names : dict camera -> list of str
        For the report of rejected views.
    target : Target
    displacements_um : (V, 3) float
        Where the target was (its frame's origin in {V}) for each image, µm. They must not all
        lie in the target's plane (the points must be non-coplanar).
    image_size_px : dict camera -> (w, h)
    refine : bool
        Refine the DLT by non-linear least squares with lens distortion (default).
    """
    disp = np.asarray(displacements_um, dtype=np.float64)
    if disp.ndim != 2 or disp.shape[1] != 3:
        raise InputError(f"displacements_um: expected shape (V, 3), got {disp.shape}")
    cams = {}
    turned_views = []
    for name, dets in detections.items():
        if len(dets) != len(disp):
            raise InputError(
                f"camera {name}: {len(dets)} images but {len(disp)} displacements; one each"
            )
        cams[name], turned = _calibrate_one_known(
            name, dets, image_names[name], target, disp, image_size_px[name], refine
        )
        turned_views += [
            {"image": image_names[name][i], "camera": name, "turn_deg": t}
            for i, t in sorted(turned.items())
        ]
    rms = float(np.sqrt(np.mean([c.rms_px**2 for c in cams.values()])))
    models = {n: c.model for n, c in cams.items()}
    return StereoCalibration(
        "known displacements (DLT" + (" + refinement)" if refine else ")"),
        cams,
        rms,
        _baseline(models),
        turned_views,
        notes=_known_displacement_notes(target, disp),
    )


def _known_displacement_notes(target: Target, disp: FloatArray) -> list[str]:
    """Warn when neither the picture nor the steps can tell a symmetric target's turns apart.

    Steps across the target's plane move the features along its own x and y, which only the
    right numbering fits; steps along its normal fit every turn equally.
    """
    turns = ambiguous_turns(target)
    if len(turns) == 1 or _steps_in_plane(target, disp):
        return []
    return [
        f"the target {target.spec} looks the same turned by "
        + " or ".join(f"{t} deg" for t in turns[1:])
        + " and the steps leave its plane only: every camera must see it the same way up "
        "(or use an odd x even chessboard or a ChArUco board)"
    ]
