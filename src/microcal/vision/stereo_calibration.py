"""Stereo calibration from images of a target (thesis chapter 3, section 5.1).

Two methods, both for any number of cameras seeing the same target:

(a) :func:`calibrate_known_displacements`, the thesis's: the target is moved by known
    displacements (for example z steps of a stage), so every feature has a known position in
    {V} (the target's frame at zero displacement). Each camera: DLT (Eq 3.7-3.15) on all the
    non-coplanar points, decomposition (Eq 3.16), then a non-linear refinement of the whole
    camera model with the distortion of Eq 3.3 (OpenCV's solver with the DLT as start).
(b) :func:`calibrate_unknown_poses`: the target is held in unknown poses. Each camera is
    calibrated alone (OpenCV, full distortion model), then the cameras are related by stereo
    calibration with those intrinsics fixed; {V} is the target's frame in a chosen reference
    view.

Views whose reprojection error stands out (above 3x the median view and 0.15 px) are
rejected and reported with the reason, and the cameras are calibrated again without them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from ..geometry import CameraModel, decompose_projection_matrix, estimate_projection_matrix
from .detect import Detection
from .targets import Target

__all__ = [
    "CameraCalibration",
    "StereoCalibration",
    "calibrate_known_displacements",
    "calibrate_unknown_poses",
]

#: A view is an outlier when its RMS exceeds this many times the median view's ...
OUTLIER_FACTOR = 3.0
#: ... and this many pixels.
OUTLIER_FLOOR_PX = 0.15
#: Method (b) estimates k1 only: with the narrow field of a microscope, k2, k3 and the
#: tangential terms trade off against the principal point and are not observable.
UNKNOWN_POSE_FLAGS = cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST


@dataclass
class CameraCalibration:
    """One calibrated camera and the figures that qualify it."""

    model: CameraModel
    rms_px: float
    per_view_rms_px: dict[str, float]
    views_used: int
    views_rejected: list[dict[str, str]] = field(default_factory=list)
    std: dict[str, list[float]] = field(default_factory=dict)
    residuals_px: dict[str, FloatArray] = field(default_factory=dict)
    """Per used view, (N, 4): detected x, y and reprojection residual dx, dy (projected
    minus detected), px."""


@dataclass
class StereoCalibration:
    """All cameras, in one {V}."""

    method: str
    cameras: dict[str, CameraCalibration]
    rms_px: float
    baseline_um: float

    def models(self) -> dict[str, CameraModel]:
        """The camera models by name."""
        return {name: c.model for name, c in self.cameras.items()}


def _camera_model(
    K: Any, dist: Any, rvec: Any, tvec: Any, size: tuple[int, int], name: str
) -> CameraModel:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    K = np.asarray(K, dtype=np.float64).copy()
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    K[2, 2] = 1.0
    d = np.zeros(5)
    flat = np.asarray(dist, dtype=np.float64).ravel()
    d[: min(5, flat.size)] = flat[:5]
    # Re-orthonormalise R against rounding in Rodrigues.
    u, _, vt = np.linalg.svd(R)
    return CameraModel(K, d, u @ vt, np.asarray(tvec, dtype=np.float64).ravel(), size, name)


def _view_rms(model: CameraModel, p_um: FloatArray, q_px: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.sum((model.project(p_um) - q_px) ** 2, axis=1))))


def _residuals(projected_px: FloatArray, detected_px: FloatArray) -> FloatArray:
    return np.hstack([detected_px, projected_px - detected_px])


def _outliers(rms: dict[str, float]) -> dict[str, str]:
    if len(rms) < 3:
        return {}
    median = float(np.median(list(rms.values())))
    limit = max(OUTLIER_FACTOR * median, OUTLIER_FLOOR_PX)
    return {
        view: f"reprojection RMS {value:.3f} px > {limit:.3f} px "
        f"({OUTLIER_FACTOR:g}x the median view)"
        for view, value in rms.items()
        if value > limit
    }


def _usable(
    detections: Sequence[Detection], names: Sequence[str]
) -> tuple[list[int], list[dict[str, str]]]:
    used, rejected = [], []
    for i, (det, name) in enumerate(zip(detections, names, strict=True)):
        if det.found:
            used.append(i)
        else:
            rejected.append({"image": name, "reason": det.reason or "target not found"})
    return used, rejected


def _calibrate_one_known(
    name: str,
    detections: Sequence[Detection],
    image_names: Sequence[str],
    target: Target,
    displacements_um: FloatArray,
    size: tuple[int, int],
    refine: bool,
) -> CameraCalibration:
    used, rejected = _usable(detections, image_names)
    for _ in range(3):
        if len(used) < 2:
            raise DegenerateDataError(
                f"camera {name}: the target was found in {len(used)} image(s); at least 2 at "
                f"different depths are needed"
            )
        p = np.vstack([target.points_um()[detections[i].ids] + displacements_um[i] for i in used])
        q = np.vstack([detections[i].q_px for i in used])
        P = estimate_projection_matrix(p, q)
        K, R, t = decompose_projection_matrix(P)
        K = np.triu(K) / K[2, 2]
        if refine:
            K[0, 1] = 0.0  # OpenCV's model has no skew
        model = CameraModel(K, np.zeros(5), R, t, size, name)
        std: dict[str, list[float]] = {}
        if refine:
            rvec, _ = cv2.Rodrigues(R)
            flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3
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
            model = _camera_model(K2, d2, rvecs[0], tvecs[0], size, name)
            sd = np.asarray(sd_in).ravel()
            std = {"fx_fy_cx_cy_px": sd[:4].tolist(), "k1_k2_p1_p2_k3": sd[4:9].tolist()}
        rms_views = {
            image_names[i]: _view_rms(
                model,
                target.points_um()[detections[i].ids] + displacements_um[i],
                detections[i].q_px,
            )
            for i in used
        }
        bad = _outliers(rms_views)
        if not bad:
            break
        rejected += [{"image": v, "reason": r} for v, r in bad.items()]
        used = [i for i in used if image_names[i] not in bad]
    all_err = np.concatenate(
        [
            model.project(target.points_um()[detections[i].ids] + displacements_um[i])
            - detections[i].q_px
            for i in used
        ]
    )
    rms_all = float(np.sqrt(np.mean(np.sum(all_err**2, axis=1))))
    residuals = {
        image_names[i]: _residuals(
            model.project(target.points_um()[detections[i].ids] + displacements_um[i]),
            detections[i].q_px,
        )
        for i in used
    }
    return CameraCalibration(model, rms_all, rms_views, len(used), rejected, std, residuals)


def _baseline(models: dict[str, CameraModel]) -> float:
    centres = [m.centre_um for m in models.values()]
    if len(centres) < 2:
        return 0.0
    return float(np.linalg.norm(centres[0] - centres[1]))


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
    for name, dets in detections.items():
        if len(dets) != len(disp):
            raise InputError(
                f"camera {name}: {len(dets)} images but {len(disp)} displacements; one each"
            )
        cams[name] = _calibrate_one_known(
            name, dets, image_names[name], target, disp, image_size_px[name], refine
        )
    rms = float(np.sqrt(np.mean([c.rms_px**2 for c in cams.values()])))
    models = {n: c.model for n, c in cams.items()}
    return StereoCalibration(
        "known displacements (DLT" + (" + refinement)" if refine else ")"),
        cams,
        rms,
        _baseline(models),
    )


def calibrate_unknown_poses(
    detections: Mapping[str, Sequence[Detection]],
    image_names: Mapping[str, Sequence[str]],
    target: Target,
    image_size_px: Mapping[str, tuple[int, int]],
    *,
    reference_view: int = 0,
) -> StereoCalibration:
    """Method (b): the target in unknown poses; per-camera then stereo calibration (OpenCV).

    Parameters
    ----------
    detections : dict camera -> list of Detection
        View i of every camera shows the target in the same pose.
    image_names, target, image_size_px
        As for :func:`calibrate_known_displacements`.
    reference_view : int
        The view whose target frame becomes {V}.
    """
    names = list(detections)
    if len(names) != 2:
        raise InputError(f"calibrate_unknown_poses: expected 2 cameras, got {len(names)}")
    n_views = len(detections[names[0]])
    if any(len(d) != n_views for d in detections.values()):
        raise InputError("calibrate_unknown_poses: every camera needs one image per view")
    obj = target.points_um().astype(np.float32)
    cams: dict[str, CameraCalibration] = {}
    intr: dict[str, tuple[FloatArray, FloatArray]] = {}
    poses: dict[str, dict[int, tuple[FloatArray, FloatArray]]] = {}
    for name in names:
        dets = detections[name]
        used, rejected = _usable(dets, image_names[name])
        for _ in range(3):
            if len(used) < 3:
                raise DegenerateDataError(
                    f"camera {name}: the target was found in {len(used)} view(s); at least 3 "
                    f"tilted views are needed"
                )
            rms, K, dist, rvecs, tvecs, sd_in, _, per_view = cv2.calibrateCameraExtended(
                [obj[dets[i].ids] for i in used],
                [dets[i].q_px.astype(np.float32) for i in used],
                image_size_px[name],
                None,
                None,
                flags=UNKNOWN_POSE_FLAGS,
            )
            view_rms = {
                image_names[name][i]: float(e)
                for i, e in zip(used, np.ravel(per_view), strict=True)
            }
            bad = _outliers(view_rms)
            if not bad:
                break
            rejected += [{"image": v, "reason": r} for v, r in bad.items()]
            used = [i for i in used if image_names[name][i] not in bad]
        intr[name] = (K, dist)
        poses[name] = {i: (rvecs[k], tvecs[k]) for k, i in enumerate(used)}
        residuals = {}
        for k, i in enumerate(used):
            projected, _ = cv2.projectPoints(obj[dets[i].ids], rvecs[k], tvecs[k], K, dist)
            residuals[image_names[name][i]] = _residuals(projected.reshape(-1, 2), dets[i].q_px)
        sd = np.asarray(sd_in).ravel()
        cams[name] = CameraCalibration(
            CameraModel(np.eye(3), np.zeros(5), np.eye(3), np.zeros(3), image_size_px[name], name),
            float(rms),
            view_rms,
            len(used),
            rejected,
            {"fx_fy_cx_cy_px": sd[:4].tolist(), "k1_k2_p1_p2_k3": sd[4:9].tolist()},
            residuals,
        )
    common = sorted(set(poses[names[0]]) & set(poses[names[1]]))
    if reference_view not in common:
        raise DegenerateDataError(
            f"reference view {reference_view} is not usable in both cameras; "
            f"usable in both: {common}"
        )
    obj_pts, q1, q2 = [], [], []
    for i in common:
        d1, d2 = detections[names[0]][i], detections[names[1]][i]
        ids = np.intersect1d(d1.ids, d2.ids)
        if len(ids) < 6:
            continue
        obj_pts.append(obj[ids])
        q1.append(d1.q_px[np.searchsorted(d1.ids, ids)].astype(np.float32))
        q2.append(d2.q_px[np.searchsorted(d2.ids, ids)].astype(np.float32))
    (K1, D1), (K2, D2) = intr[names[0]], intr[names[1]]
    rms, *_, R, T, _, _ = cv2.stereoCalibrate(
        obj_pts, q1, q2, K1, D1, K2, D2, image_size_px[names[0]], flags=cv2.CALIB_FIX_INTRINSIC
    )
    rvec, tvec = poses[names[0]][reference_view]
    m1 = _camera_model(K1, D1, rvec, tvec, image_size_px[names[0]], names[0])
    R2 = R @ m1.R
    t2 = R @ m1.t_um + np.ravel(T)
    rvec2, _ = cv2.Rodrigues(R2)
    m2 = _camera_model(K2, D2, rvec2, t2, image_size_px[names[1]], names[1])
    cams[names[0]].model, cams[names[1]].model = m1, m2
    return StereoCalibration(
        "unknown poses (per-camera + stereo)", cams, float(rms), _baseline({"a": m1, "b": m2})
    )
