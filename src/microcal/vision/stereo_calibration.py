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
    calibration with those intrinsics fixed. {V} is the target's frame in a chosen reference
    view.

Views whose reprojection error stands out (above 3x the median view and 0.15 px) are
rejected and reported with the reason, and the cameras are calibrated again without them;
so are view pairs whose relative pose disagrees with the others' and pairs that stand out in
the stereo solve.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from ..geometry import CameraModel, decompose_projection_matrix, estimate_projection_matrix
from .board_symmetry import ambiguous_turns, turn_ids
from .calibration_diagnostics import CameraDiagnostics, diagnose
from .detect import Detection
from .lens_models import (
    LENS_MODELS,
    LensModelChoice,
    choose_lens_model,
    dist_of_length,
    opencv_reason,
)
from .lens_models import lens_model as named_lens_model
from .targets import Target
from .view_consistency import normal_spread_deg, resolve_turns

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
#: Rounds of rejection at most; the fit after the last round is the one returned.
OUTLIER_ROUNDS = 3
#: Common ids a view pair needs to enter the stereo solve.
MIN_COMMON_POINTS = 6
#: Method (b) refuses views whose board normals all lie within this angle (degrees).
MIN_TILT_SPREAD_DEG = 5.0


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
    lens_model: dict[str, object] = field(default_factory=dict)
    """Method (b): ``name``, ``reason``, ``field_of_view_deg`` and the ``candidates`` tried
    (each with its training and held-out RMS)."""
    diagnostics: CameraDiagnostics | None = None
    """Method (b): uncertainty, split-half check, coverage and verdict."""


@dataclass
class StereoCalibration:
    """All cameras, in one {V}."""

    method: str
    cameras: dict[str, CameraCalibration]
    rms_px: float
    baseline_um: float
    turned_views: list[dict[str, Any]] = field(default_factory=list)
    """Images whose corner numbering was turned (a symmetric board): ``image``, ``camera``,
    ``turn_deg``. Method (b): to agree with the first camera's in the same view; method (a):
    with the same camera's first view, or as its steps across the target's plane fit."""
    views_rejected: list[dict[str, str]] = field(default_factory=list)
    """View pairs left out of the stereo solve: ``view`` (both images) and ``reason``."""
    notes: list[str] = field(default_factory=list)
    """Warnings about the calibration as a whole, one sentence each."""

    def models(self) -> dict[str, CameraModel]:
        """The camera models by name."""
        return {name: c.model for name, c in self.cameras.items()}

    @property
    def angle_deg(self) -> float:
        """Angle between the first two cameras' optical axes' frames (rotation angle), deg."""
        models = list(self.models().values())
        if len(models) < 2:
            return 0.0
        R = models[1].R @ models[0].R.T
        return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _camera_model(
    K: Any, dist: Any, rvec: Any, tvec: Any, size: tuple[int, int], name: str
) -> CameraModel:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    K = np.asarray(K, dtype=np.float64).copy()
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    K[2, 2] = 1.0
    size_in = np.asarray(dist).size
    d = dist_of_length(dist, next((k for k in (5, 8, 12, 14) if size_in <= k), 14))
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


#: With these flags OpenCV's stereo solve reads all 14 coefficients of each camera (fixed).
_ALL_TERMS = cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL | cv2.CALIB_TILTED_MODEL


def _renumbered(det: Detection, target: Target, turn_deg: int) -> Detection:
    """The detection with its ids renumbered as the board turned by ``turn_deg``."""
    if turn_deg == 0:
        return det
    ids = turn_ids(target, turn_deg)[det.ids]
    order = np.argsort(ids)
    return Detection(True, ids[order], det.q_px[order], det.quality_px, method=det.method)


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
        proj = p @ P[:, :3].T + P[:, 3]
        rms[t] = float(np.sqrt(np.mean(np.sum((proj[:, :2] / proj[:, 2:] - q) ** 2, axis=1))))
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
    for round_ in range(OUTLIER_ROUNDS + 1):
        if len(used) < 2:
            raise DegenerateDataError(
                f"camera {name}: the target was found in {len(used)} image(s); at least 2 at "
                f"different depths are needed"
            )
        p, q = _known_points(detections, used, target, displacements_um)
        model, std = _fit_known(p, q, size, name, refine)
        rms_views = {
            image_names[i]: _view_rms(
                model,
                target.points_um()[detections[i].ids] + displacements_um[i],
                detections[i].q_px,
            )
            for i in used
        }
        bad = _outliers(rms_views)
        if not bad or round_ == OUTLIER_ROUNDS:  # the last fit is of the views kept
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
    sigma = _jackknife_sigma_px(detections, used, target, displacements_um, size, refine, model)
    model = dataclasses.replace(model, projection_sigma_px=sigma)
    cal = CameraCalibration(model, rms_all, rms_views, len(used), rejected, std, residuals)
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


@dataclass
class _Mono:
    calibration: CameraCalibration
    choice: LensModelChoice
    used: list[int]


def _calibrate_one_unknown(
    name: str,
    dets: Sequence[Detection],
    image_names: Sequence[str],
    target: Target,
    size: tuple[int, int],
    model_name: str,
) -> _Mono:
    used, rejected = _usable(dets, image_names)
    models = LENS_MODELS if model_name == "auto" else (named_lens_model(model_name),)
    points = target.points_um()
    for round_ in range(OUTLIER_ROUNDS + 1):
        if len(used) < 3:
            raise DegenerateDataError(
                f"camera {name}: the target was found in {len(used)} view(s); at least 3 "
                f"tilted views are needed"
            )
        obj = [points[dets[i].ids] for i in used]
        img = [dets[i].q_px for i in used]
        try:
            choice = choose_lens_model(obj, img, size, models=models)
        except DegenerateDataError as exc:
            raise DegenerateDataError(f"camera {name}: {exc}") from None
        view_rms = {
            image_names[i]: float(e) for i, e in zip(used, choice.fit.per_view_rms_px, strict=True)
        }
        bad = _outliers(view_rms)
        if not bad or round_ == OUTLIER_ROUNDS:  # the last fit is of the views kept
            break
        rejected += [{"image": v, "reason": r} for v, r in bad.items()]
        used = [i for i in used if image_names[i] not in bad]
    fit = choice.fit
    residuals = {}
    for k, i in enumerate(used):
        projected, _ = cv2.projectPoints(points[dets[i].ids], fit.rvecs[k], fit.tvecs[k], fit.K,
                                         fit.dist)  # fmt: skip
        residuals[image_names[i]] = _residuals(projected.reshape(-1, 2), dets[i].q_px)
    richest = len(models) > 1 and fit.model == models[-1]
    diagnostics = diagnose(fit, obj, img, size, richest_offered=richest)
    sd = fit.std_intrinsics
    std = {
        "fx_fy_cx_cy_px": sd[:4].tolist(),
        "k1_k2_p1_p2_k3": sd[4:9].tolist(),
        "dist": sd[4:].tolist(),
    }
    cal = CameraCalibration(
        CameraModel(np.eye(3), np.zeros(5), np.eye(3), np.zeros(3), size, name),
        fit.rms_px,
        view_rms,
        len(used),
        rejected,
        std,
        residuals,
        {
            "name": fit.model.name,
            "terms": list(fit.model.terms),
            "reason": choice.reason,
            "field_of_view_deg": choice.field_of_view_deg,
            "candidates": choice.candidates,
        },
        diagnostics,
    )
    return _Mono(cal, choice, used)


def calibrate_unknown_poses(
    detections: Mapping[str, Sequence[Detection]],
    image_names: Mapping[str, Sequence[str]],
    target: Target,
    image_size_px: Mapping[str, tuple[int, int]],
    *,
    reference_view: int = 0,
    lens_model: str = "auto",
) -> StereoCalibration:
    """Method (b): the target in unknown poses; per-camera then stereo calibration.

    Parameters
    ----------
    detections : dict camera -> list of Detection
        View i of every camera shows the target in the same pose.
    image_names, target, image_size_px
        As for :func:`calibrate_known_displacements`.
    reference_view : int
        The view whose target frame (as the first camera numbers it) becomes {V}.
    lens_model : str
        ``"auto"`` (chosen per camera by held-out error) or the name of one of
        :data:`~microcal.vision.lens_models.LENS_MODELS`.
    """
    names = list(detections)
    if len(names) != 2:
        raise InputError(f"calibrate_unknown_poses: expected 2 cameras, got {len(names)}")
    if len(target.points_um()) < MIN_COMMON_POINTS:
        raise InputError(
            f"target {target.spec}: {len(target.points_um())} features are too few for method "
            f"(b); use a target with at least {MIN_COMMON_POINTS} (e.g. chessboard:7x4:PITCH)"
        )
    n_views = len(detections[names[0]])
    if any(len(d) != n_views for d in detections.values()):
        raise InputError("calibrate_unknown_poses: every camera needs one image per view")
    mono = {
        name: _calibrate_one_unknown(
            name, detections[name], image_names[name], target, image_size_px[name], lens_model
        )
        for name in names
    }
    a, b = names
    for name, m in mono.items():
        spread = normal_spread_deg(dict(enumerate(m.choice.fit.rvecs)))
        if spread < MIN_TILT_SPREAD_DEG:
            raise DegenerateDataError(
                f"camera {name}: the target's tilt varies by only {spread:.1f} deg over the "
                f"views; tilt it by 20 to 40 degrees in different directions between views "
                "(method b cannot tell focal length from distance otherwise)"
            )
    view_names = image_names[a]
    poses = {
        name: {i: m.choice.fit.rvecs[k] for k, i in enumerate(m.used)} for name, m in mono.items()
    }
    tvecs = {
        name: {i: m.choice.fit.tvecs[k] for k, i in enumerate(m.used)} for name, m in mono.items()
    }
    rejected: list[dict[str, str]] = []
    resolution = resolve_turns(target, poses[a], poses[b], (tvecs[a], tvecs[b]))
    pair = {i: f"{view_names[i]} + {image_names[b][i]}" for i in range(n_views)}
    rejected += [{"view": pair[i], "reason": r} for i, r in resolution.disagree.items()]
    det_b = {i: _renumbered(detections[b][i], target, t) for i, t in resolution.turns.items()}
    turned = [
        {"image": image_names[b][i], "camera": b, "turn_deg": t}
        for i, t in sorted(resolution.turns.items())
        if t != 0
    ]
    common = sorted(resolution.turns)
    if reference_view not in common:
        raise DegenerateDataError(
            f"reference view {reference_view} is not usable in both cameras; "
            f"usable in both: {common}"
        )
    obj = target.points_um()
    fa, fb = mono[a].choice.fit, mono[b].choice.fit
    pairs: dict[int, tuple[FloatArray, FloatArray, FloatArray]] = {}
    for i in common:
        d1, d2 = detections[a][i], det_b[i]
        ids = np.intersect1d(d1.ids, d2.ids)
        if len(ids) < MIN_COMMON_POINTS:
            rejected.append({"view": pair[i], "reason": f"only {len(ids)} points seen by both"})
            continue
        pairs[i] = (obj[ids], d1.q_px[np.searchsorted(d1.ids, ids)],
                    d2.q_px[np.searchsorted(d2.ids, ids)])  # fmt: skip
    for round_ in range(OUTLIER_ROUNDS + 1):
        if len(pairs) < 1:
            raise DegenerateDataError("no view is usable in both cameras for the stereo step")
        keys = sorted(pairs)
        rms, _, _, _, _, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(
            [pairs[i][0].astype(np.float32) for i in keys],
            [pairs[i][1].astype(np.float32) for i in keys],
            [pairs[i][2].astype(np.float32) for i in keys],
            fa.K, dist_of_length(fa.dist, 14), fb.K, dist_of_length(fb.dist, 14),
            image_size_px[a], None, None,
            flags=cv2.CALIB_FIX_INTRINSIC | _ALL_TERMS,
        )  # fmt: skip
        errors = np.asarray(per_view, dtype=np.float64).reshape(len(keys), -1)
        view_rms = {
            pair[i]: float(np.sqrt(np.mean(e**2))) for i, e in zip(keys, errors, strict=True)
        }
        bad = _outliers(view_rms)
        if not bad or round_ == OUTLIER_ROUNDS:  # the last fit is of the views kept
            break
        rejected += [{"view": v, "reason": "stereo " + r} for v, r in bad.items()]
        pairs = {i: p for i, p in pairs.items() if pair[i] not in bad}
    if reference_view not in pairs:
        raise DegenerateDataError(
            f"reference view {reference_view} was left out of the stereo step; choose another"
        )
    k_ref = mono[a].used.index(reference_view)
    m1 = _camera_model(fa.K, fa.dist, fa.rvecs[k_ref], tvecs[a][reference_view],
                       image_size_px[a], a)  # fmt: skip
    R2 = R @ m1.R
    t2 = R @ m1.t_um + np.ravel(T)
    rvec2, _ = cv2.Rodrigues(R2)
    m2 = _camera_model(fb.K, fb.dist, rvec2, t2, image_size_px[b], b)
    cams = {name: m.calibration for name, m in mono.items()}
    cams[a].model, cams[b].model = m1, m2
    for cal in cams.values():  # the intrinsics' share of the projection error, per axis
        d = cal.diagnostics
        if d is not None and np.isfinite(d.uncertainty_map_px).any():
            sigma = float(np.sqrt(np.nanmean(d.uncertainty_map_px**2) / 2.0))
            cal.model = dataclasses.replace(cal.model, projection_sigma_px=sigma)
    return StereoCalibration(
        "unknown poses (per-camera + stereo)",
        cams,
        float(rms),
        _baseline({"a": m1, "b": m2}),
        turned,
        rejected,
        notes=[resolution.note] if resolution.note else [],
    )
