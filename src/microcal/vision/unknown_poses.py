"""Method (b): the target held in unknown poses; per-camera, then stereo calibration.

Each camera is calibrated alone, its lens model chosen by held-out error
(:mod:`~microcal.vision.lens_models`) and diagnosed
(:mod:`~microcal.vision.calibration_diagnostics`); the corner numbering of a board that looks
the same turned is made to agree between the cameras by the stereo geometry
(:mod:`~microcal.vision.view_consistency`); then the cameras are related by stereo
calibration with those intrinsics fixed. {V} is the target's frame in a chosen reference
view. Outlier views, view pairs whose relative pose disagrees with the others' and pairs
that stand out in the stereo solve are dropped with the reason.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from ..geometry import CameraModel
from .calibration_diagnostics import diagnose
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
from .lens_models import LENS_MODELS, LensModelChoice, choose_lens_model, dist_of_length
from .lens_models import lens_model as named_lens_model
from .targets import Target
from .view_consistency import normal_spread_deg, resolve_turns

__all__ = ["calibrate_unknown_poses"]

#: Common ids a view pair needs to enter the stereo solve.
MIN_COMMON_POINTS = 6
#: Method (b) refuses views whose board normals all lie within this angle (degrees).
MIN_TILT_SPREAD_DEG = 5.0

#: With these flags OpenCV's stereo solve reads all 14 coefficients of each camera (fixed).
_ALL_TERMS = cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL | cv2.CALIB_TILTED_MODEL


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

    def calibrate(views: list[int]) -> tuple[LensModelChoice, dict[int, float]]:
        if len(views) < 3:
            raise DegenerateDataError(
                f"camera {name}: the target was found in {len(views)} view(s); at least 3 "
                f"tilted views are needed"
            )
        obj = [points[dets[i].ids] for i in views]
        img = [dets[i].q_px for i in views]
        try:
            choice = choose_lens_model(obj, img, size, models=models)
        except DegenerateDataError as exc:
            raise DegenerateDataError(f"camera {name}: {exc}") from None
        rms = dict(zip(views, (float(e) for e in choice.fit.per_view_rms_px), strict=True))
        return choice, rms

    choice, used, bad = _fit_rejecting_outliers(used, calibrate)
    rejected += [{"image": image_names[i], "reason": r} for i, r in bad.items()]
    view_rms = {
        image_names[i]: float(e) for i, e in zip(used, choice.fit.per_view_rms_px, strict=True)
    }
    obj = [points[dets[i].ids] for i in used]
    img = [dets[i].q_px for i in used]
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

    def stereo(views: list[int]) -> tuple[tuple[float, FloatArray, FloatArray], dict[int, float]]:
        if not views:
            raise DegenerateDataError("no view is usable in both cameras for the stereo step")
        rms, _, _, _, _, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(
            [pairs[i][0].astype(np.float32) for i in views],
            [pairs[i][1].astype(np.float32) for i in views],
            [pairs[i][2].astype(np.float32) for i in views],
            fa.K, dist_of_length(fa.dist, 14), fb.K, dist_of_length(fb.dist, 14),
            image_size_px[a], None, None,
            flags=cv2.CALIB_FIX_INTRINSIC | _ALL_TERMS,
        )  # fmt: skip
        errors = np.asarray(per_view, dtype=np.float64).reshape(len(views), -1)
        by_view = {i: float(np.sqrt(np.mean(e**2))) for i, e in zip(views, errors, strict=True)}
        return (float(rms), R, T), by_view

    (rms, R, T), kept, bad = _fit_rejecting_outliers(sorted(pairs), stereo)
    rejected += [{"view": pair[i], "reason": "stereo " + r} for i, r in bad.items()]
    pairs = {i: pairs[i] for i in kept}
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
        rms,
        _baseline({"a": m1, "b": m2}),
        turned,
        rejected,
        notes=[resolution.note] if resolution.note else [],
    )
