"""Method (b): the target held in unknown poses; per-camera calibration, then one joint
refinement of all cameras.

Each camera is calibrated alone, its lens model chosen by held-out error
(:mod:`~microcal.vision.lens_models`) and diagnosed
(:mod:`~microcal.vision.calibration_diagnostics`); the corner numbering of a board that looks
the same turned is made to agree between the cameras by the stereo geometry
(:mod:`~microcal.vision.view_consistency`); then all cameras' poses and the target's pose in
every view are refined together with those intrinsics fixed
(:mod:`~microcal.vision.joint_poses`), each view seen by any two or more of the cameras, and
from there every camera's intrinsics and lens terms with all the poses
(:mod:`~microcal.vision.joint_intrinsics`; a view one camera alone saw constrains that
camera). {V} is the target's frame in a chosen reference view. Outlier views, observations whose
relative pose disagrees with the other views' and views that stand out in the joint
refinement are dropped with the reason.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import DegenerateDataError, InputError
from ..geometry import CameraModel
from .board_symmetry import ambiguous_turns, turn_transform
from .calibration_consistency import consistency
from .calibration_diagnostics import diagnose
from .calibration_result import (
    CameraCalibration,
    StereoCalibration,
    TurnedView,
    _baseline,
    _camera_model,
    _fit_rejecting_outliers,
    _renumbered,
    _residuals,
    _usable,
)
from .detect import Detection
from .joint_intrinsics import JointCalibration, refine_intrinsics_jointly
from .joint_poses import Observation, Pose, _compose, _inverse, initial_poses, refine_jointly
from .lens_models import LENS_MODELS, LensModelChoice, choose_lens_model
from .lens_models import lens_model as named_lens_model
from .targets import Target
from .view_consistency import normal_spread_deg, resolve_turns

__all__ = ["calibrate_unknown_poses"]

#: Common ids a view pair needs to enter the stereo solve.
MIN_COMMON_POINTS = 6
#: A symmetric board's turn is told between two cameras from at least this many shared views.
MIN_SHARED_VIEWS_FOR_TURNS = 2
#: Method (b) refuses views whose board normals all lie within this angle (degrees).
MIN_TILT_SPREAD_DEG = 5.0


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


def _agree_numbering(
    target: Target,
    mono: Mapping[str, _Mono],
    detections: Mapping[str, Sequence[Detection]],
    image_names: Mapping[str, Sequence[str]],
) -> tuple[dict[str, dict[int, Detection]], dict[str, dict[int, Pose]], list[TurnedView],
           list[dict[str, str]], list[str]]:  # fmt: skip
    """Number each camera's corners as the first camera that saw the same view does.

    Camera by camera, each view is resolved against the earlier cameras, the one sharing most
    views first, then the others for the views it left (turns compose: they are all about the
    board's normal through its centre); a view no earlier camera saw keeps its numbering. For
    a board that looks the same turned, a camera pair sharing fewer than
    :data:`MIN_SHARED_VIEWS_FOR_TURNS` views cannot tell the turn: such observations are
    refused with the reason. Returns the renumbered detections and board
    poses per camera and view, the turned images, the refused observations and notes.
    """
    names = list(mono)
    raw = {c: {i: (m.choice.fit.rvecs[k], np.ravel(m.choice.fit.tvecs[k]))
               for k, i in enumerate(m.used)} for c, m in mono.items()}  # fmt: skip
    symmetric = len(ambiguous_turns(target)) > 1
    turns: dict[str, dict[int, int]] = {}
    rejected: list[dict[str, str]] = []
    notes: list[str] = []
    for idx, c in enumerate(names):
        turns[c] = {}
        refusal: dict[int, dict[str, str]] = {}  # the first reason per view; others may agree
        for r in sorted(names[:idx], key=lambda r: -len(set(turns[r]) & set(raw[c]))):
            todo = [v for v in raw[c] if v not in turns[c] and v in turns[r]]
            if not todo:
                continue
            shared = sorted(set(turns[r]) & set(raw[c]))
            pair = {v: f"{image_names[r][v]} + {image_names[c][v]}" for v in todo}
            if symmetric and len(shared) < MIN_SHARED_VIEWS_FOR_TURNS:
                for v in todo:
                    refusal.setdefault(v, {"view": pair[v], "reason": (
                        f"camera {c} shares {len(shared)} view with camera {r}: too few to tell "
                        f"how a board that looks the same turned is numbered (at least "
                        f"{MIN_SHARED_VIEWS_FOR_TURNS})")})  # fmt: skip
                continue
            res = resolve_turns(
                target,
                {v: raw[r][v][0] for v in shared},
                {v: raw[c][v][0] for v in shared},
                ({v: raw[r][v][1] for v in shared}, {v: raw[c][v][1] for v in shared}),
            )
            if res.note and res.note not in notes:
                notes.append(res.note)
            for v in todo:
                if v in res.turns:
                    turns[c][v] = (res.turns[v] + turns[r][v]) % 360
                else:
                    reason = res.disagree.get(v, "no turn agrees")
                    refusal.setdefault(v, {"view": pair[v], "reason": reason})
        for v in raw[c]:
            if v in turns[c]:
                continue
            if v in refusal:
                rejected.append(refusal[v])
            else:  # no earlier camera saw it: its numbering is the one the others follow
                turns[c][v] = 0
    dets: dict[str, dict[int, Detection]] = {}
    poses: dict[str, dict[int, Pose]] = {}
    for c in names:
        dets[c], poses[c] = {}, {}
        for v, t in turns[c].items():
            Rs, ts = turn_transform(target, t)
            R = cv2.Rodrigues(np.asarray(raw[c][v][0], dtype=np.float64))[0] @ Rs.T
            dets[c][v] = _renumbered(detections[c][v], target, t)
            poses[c][v] = (R, raw[c][v][1] - R @ ts)
    turned = [
        TurnedView(image=image_names[c][v], camera=c, turn_deg=t)
        for c in names
        for v, t in sorted(turns[c].items())
        if t != 0
    ]
    return dets, poses, turned, rejected, notes


def calibrate_unknown_poses(
    detections: Mapping[str, Sequence[Detection]],
    image_names: Mapping[str, Sequence[str]],
    target: Target,
    image_size_px: Mapping[str, tuple[int, int]],
    *,
    reference_view: int = 0,
    lens_model: str = "auto",
) -> StereoCalibration:
    """Method (b): the target in unknown poses; per-camera calibration, then one joint
    refinement of all cameras' poses.

    Parameters
    ----------
    detections : dict camera -> list of Detection
        Two or more cameras; view i of every camera shows the target in the same pose (a
        camera that did not find it in a view leaves the others to relate it).
    image_names, target, image_size_px
        As for :func:`calibrate_known_displacements`.
    reference_view : int
        The view whose target frame (as the first camera numbers it) becomes {V}; the first
        camera must see it.
    lens_model : str
        ``"auto"`` (chosen per camera by held-out error) or the name of one of
        :data:`~microcal.vision.lens_models.LENS_MODELS`.
    """
    names = list(detections)
    if not names:
        raise InputError("calibrate_unknown_poses: expected 1 or more cameras, got none")
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
    for name, m in mono.items():
        spread = normal_spread_deg(dict(enumerate(m.choice.fit.rvecs)))
        if spread < MIN_TILT_SPREAD_DEG:
            raise DegenerateDataError(
                f"camera {name}: the target's tilt varies by only {spread:.1f} deg over the "
                f"views; tilt it by 20 to 40 degrees in different directions between views "
                "(method b cannot tell focal length from distance otherwise)"
            )
    if len(names) == 1:
        return _one_camera(mono[names[0]], names[0], detections[names[0]], target, reference_view,
                           image_size_px[names[0]])  # fmt: skip
    dets, poses, turned, rejected, notes = _agree_numbering(target, mono, detections, image_names)
    first = names[0]
    if reference_view not in poses[first]:
        raise DegenerateDataError(
            f"reference view {reference_view} is not usable in camera {first}; usable: "
            f"{sorted(poses[first])}"
        )
    obj = target.points_um()
    seen: dict[int, list[Observation]] = {}
    for c in names:
        for v, d in dets[c].items():
            if len(d.ids) >= MIN_COMMON_POINTS:
                seen.setdefault(v, []).append(Observation(c, v, obj[d.ids], d.q_px))
    joint = {v: o for v, o in seen.items() if len(o) >= 2}
    if not joint:
        raise DegenerateDataError(
            f"cameras {', '.join(names)} share no view of the target (no view has it found by "
            "two or more of them), so nothing relates them; take views that two or more "
            "cameras see at once, or calibrate each camera alone (one --images each)"
        )
    if reference_view not in joint:
        raise DegenerateDataError(
            f"reference view {reference_view} is usable in fewer than two cameras; choose one "
            f"that two or more see (--reference-view; such views: {sorted(joint)})"
        )
    label = {v: " + ".join(image_names[o.camera][v] for o in obs) for v, obs in joint.items()}
    alone = {v: o for v, o in seen.items() if len(o) == 1}
    intrinsics = {c: (m.choice.fit.K, m.choice.fit.dist) for c, m in mono.items()}
    lens = {c: m.choice.fit.model for c, m in mono.items()}
    left_out = len(rejected)

    def refine(views: list[int]) -> tuple[JointCalibration, dict[int, float]]:
        observations = [o for v in views for o in joint[v]]
        lost = [c for c in names if c not in {o.camera for o in observations}]
        if lost:
            n_out = left_out + len(joint) - len(views)
            why = f" ({n_out} views or observations left out as disagreeing or outliers)"
            raise DegenerateDataError(
                f"camera(s) {', '.join(lost)} share no usable view of the target with another "
                f"camera{why if n_out else ''}; take views that two or more cameras see at once"
            )
        by_camera: dict[str, dict[int, Pose]] = {c: {} for c in names}
        for o in observations:  # only what the refinement sees links the cameras
            by_camera[o.camera][o.view] = poses[o.camera][o.view]
        result = refine_jointly(observations, intrinsics, *initial_poses(by_camera, first),
                                first=first)  # fmt: skip
        # Then the intrinsics too, each view's board pose shared by the cameras that saw it;
        # a view one camera alone saw constrains that camera, with its own board pose.
        views_start = dict(result.views)
        for v, (o,) in alone.items():
            if o.camera in result.cameras:
                views_start[v] = _compose(_inverse(result.cameras[o.camera]), poses[o.camera][v])
        extra = [o for v, (o,) in alone.items() if v in views_start]
        adjusted = refine_intrinsics_jointly(observations + extra, intrinsics, lens, result.cameras,
                                             views_start, first)  # fmt: skip
        return adjusted, {v: adjusted.per_view_rms_px[v] for v in views}

    fit, kept, bad = _fit_rejecting_outliers(sorted(joint), refine)
    rejected += [{"view": label[i], "reason": "joint refinement " + r} for i, r in bad.items()]
    if reference_view not in kept:
        raise DegenerateDataError(
            f"reference view {reference_view} was left out of the joint refinement as an "
            "outlier; choose another (--reference-view)"
        )
    models = {}
    for c in names:
        R, t = (
            fit.cameras[c][0] @ fit.views[reference_view][0],
            (fit.cameras[c][0] @ fit.views[reference_view][1] + fit.cameras[c][1]),
        )
        K, dist = fit.intrinsics[c]
        rvec, _ = cv2.Rodrigues(R)
        models[c] = _camera_model(K, dist, rvec, t, image_size_px[c], c)
    cams = {name: m.calibration for name, m in mono.items()}
    for name, cal in cams.items():  # the intrinsics' share of the projection error, per axis
        cal.model = models[name]
        diag = cal.diagnostics
        if diag is not None and np.isfinite(diag.uncertainty_map_px).any():
            sigma = float(np.sqrt(np.nanmean(diag.uncertainty_map_px**2) / 2.0))
            cal.model = dataclasses.replace(cal.model, projection_sigma_px=sigma)
    figures = consistency(
        target,
        dets,
        poses,
        {c: m.choice.fit.model for c, m in mono.items()},
        models,
        kept,
        first,
    )
    return StereoCalibration(
        "unknown poses (per-camera + joint refinement)",
        cams,
        fit.rms_px,
        _baseline(models),
        turned,
        rejected,
        notes=notes,
        consistency=figures,
    )


def _one_camera(
    mono: _Mono,
    name: str,
    detections: Sequence[Detection],
    target: Target,
    reference_view: int,
    size: tuple[int, int],
) -> StereoCalibration:
    """One camera alone: its own calibration, {V} the target's frame in the reference view."""
    fit = mono.choice.fit
    if reference_view not in mono.used:
        raise DegenerateDataError(
            f"reference view {reference_view} is not usable in camera {name}; usable: "
            f"{sorted(mono.used)} (--reference-view)"
        )
    k = mono.used.index(reference_view)
    cal = mono.calibration
    cal.model = _camera_model(fit.K, fit.dist, fit.rvecs[k], fit.tvecs[k], size, name)
    diag = cal.diagnostics
    if diag is not None and np.isfinite(diag.uncertainty_map_px).any():
        sigma = float(np.sqrt(np.nanmean(diag.uncertainty_map_px**2) / 2.0))
        cal.model = dataclasses.replace(cal.model, projection_sigma_px=sigma)
    dets = {name: {v: detections[v] for v in mono.used}}
    poses = {name: {v: (cv2.Rodrigues(np.asarray(fit.rvecs[i]))[0], np.ravel(fit.tvecs[i]))
                    for i, v in enumerate(mono.used)}}  # fmt: skip
    figures = consistency(target, dets, poses, {name: fit.model}, {name: cal.model}, mono.used,
                          name)  # fmt: skip
    return StereoCalibration("unknown poses (one camera)", {name: cal}, cal.rms_px, 0.0,
                             consistency=figures)  # fmt: skip
