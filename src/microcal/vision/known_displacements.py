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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from ..geometry import (
    AffineCamera,
    AnyCamera,
    CameraModel,
    decompose_projection_matrix,
    estimate_projection_matrix,
)
from ..geometry.affine_estimation import estimate_affine_matrix, refine_affine_camera
from ..geometry.reprojection import reprojection_error
from .board_symmetry import ambiguous_turns
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
from .lens_models import opencv_reason, predicts_better
from .targets import Target
from .view_order import check_view_order

__all__ = [
    "CAMERA_MODEL_CHOICES",
    "ILL_CONDITIONED_FOCAL_SD",
    "calibrate_known_displacements",
    "fit_known_points",
]


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


def _numbered(
    detections: Sequence[Detection], target: Target, displacements_um: FloatArray
) -> list[Detection]:
    """One camera's detections numbered as its calibration numbers them (a symmetric board)."""
    used = [i for i, d in enumerate(detections) if d.found]
    dets, turned = _align_views(detections, used, target)
    return _turn_by_steps(dets, used, target, displacements_um, turned)[0]


def _steps_in_plane(target: Target, disp: FloatArray) -> bool:
    """True if the steps move the target across its plane by more than a pitch."""
    return len(disp) > 0 and float(np.max(np.ptp(disp[:, :2], axis=0))) > target.pitch_um


#: The camera models method (a) fits, and ``"auto"``: both, the better kept.
CAMERA_MODEL_CHOICES = ("pinhole", "affine", "auto")

#: A pinhole fit whose focal length is uncertain by more than this fraction (1 sigma) is
#: ill-conditioned: the views cannot tell its distance from its focal length (a telecentric
#: lens, or a field of a degree or two).
ILL_CONDITIONED_FOCAL_SD = 0.02


@dataclass
class _KindFit:
    """One camera model fitted to one camera's views, with its held-out figures."""

    cal: CameraCalibration
    held_out_mse_px2: FloatArray | None  # per used view, fitted without it
    rejected: list[dict[str, str]]
    ill_conditioned: str = ""


def _calibrate_one_known(
    name: str,
    detections: Sequence[Detection],
    image_names: Sequence[str],
    target: Target,
    displacements_um: FloatArray,
    size: tuple[int, int],
    refine: bool,
    camera_model: str = "pinhole",
) -> tuple[CameraCalibration, dict[int, int]]:
    used, rejected = _usable(detections, image_names)
    detections, turned = _align_views(detections, used, target)
    detections, turned = _turn_by_steps(detections, used, target, displacements_um, turned)
    kinds = ("pinhole", "affine") if camera_model == "auto" else (camera_model,)
    fits: dict[str, _KindFit | DegenerateDataError] = {}
    for kind in kinds:
        try:
            fits[kind] = _calibrate_kind(kind, name, detections, used, image_names, target,
                                         displacements_um, size, refine)  # fmt: skip
        except DegenerateDataError as exc:
            fits[kind] = exc
    chosen, choice = _choose_camera_model(fits, camera_model)
    fit = fits[chosen]
    assert isinstance(fit, _KindFit)
    if fit.ill_conditioned:  # the pinhole model asked for: auto never keeps such a fit
        raise DegenerateDataError(
            f"camera {name}: the views do not fit one camera ({fit.ill_conditioned}); are the "
            "steps in µm, one row per image in the images' sorted order? (for a telecentric "
            "lens: --camera-model affine)"
        )
    fit.cal.views_rejected = rejected + fit.rejected
    if camera_model == "auto":
        fit.cal.model_choice = choice
    return fit.cal, turned


def _calibrate_kind(
    kind: str,
    name: str,
    detections: Sequence[Detection],
    used: list[int],
    image_names: Sequence[str],
    target: Target,
    displacements_um: FloatArray,
    size: tuple[int, int],
    refine: bool,
) -> _KindFit:
    """One camera model fitted to the views ``used``, outlier views dropped, and its
    leave-one-view-out figures (held-out error, the calibration's projection sigma)."""
    points = target.points_um()
    fitter = _FITTERS[kind]

    def calibrate(views: list[int]) -> tuple[tuple[AnyCamera, dict[str, list[float]],
                                             dict[int, FloatArray]], dict[int, float]]:  # fmt: skip
        if len(views) < 2:
            raise DegenerateDataError(
                f"camera {name}: the target was found in {len(views)} image(s); at least 2 at "
                f"different depths are needed"
            )
        model, std = fitter(*_known_points(detections, views, target, displacements_um),
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

    (model, std, residuals), kept, bad = _fit_rejecting_outliers(used, calibrate)
    rejected = [{"image": image_names[i], "reason": r} for i, r in bad.items()]
    all_err = np.concatenate([residuals[i][:, 2:] for i in kept])
    rms_all = float(np.sqrt(np.mean(np.sum(all_err**2, axis=1))))
    rms_views = {
        image_names[i]: float(np.sqrt(np.mean(np.sum(residuals[i][:, 2:] ** 2, axis=1))))
        for i in kept
    }
    sigma, held_out, reduced = _leave_one_out(kind, detections, kept, target,
                                              displacements_um, size, refine, model)  # fmt: skip
    model = dataclasses.replace(model, projection_sigma_px=sigma)
    by_name = {image_names[i]: residuals[i] for i in kept}
    cal = CameraCalibration(model, rms_all, rms_views, len(kept), [], std, by_name)
    return _KindFit(cal, held_out, rejected, _ill_conditioned(model, std, reduced, rms_all))


def _ill_conditioned(
    model: AnyCamera, std: dict[str, list[float]], reduced: list[AnyCamera], rms_px: float
) -> str:
    """Why a pinhole fit cannot be trusted, or ``""``: points behind it, or a focal length
    that the views do not determine (its standard deviation, the larger of the fit's and the
    jackknife's over the fits without each view, above :data:`ILL_CONDITIONED_FOCAL_SD`)."""
    if not isinstance(model, CameraModel):
        return ""
    f = float(model.K[0, 0])
    if not np.isfinite(rms_px):
        return (
            f"ill-conditioned: the fit (focal length {f:.3g} px) puts the camera behind the "
            "target; its distance and focal length cannot be told apart"
        )
    sds = [float(std["fx_fy_cx_cy_px"][0])] if std.get("fx_fy_cx_cy_px") else []
    fs = np.array([m.K[0, 0] for m in reduced])
    if len(fs) >= 3:
        n = len(fs)
        sds.append(float(np.sqrt((n - 1) / n * np.sum((fs - fs.mean()) ** 2))))
    sd = max(sds, default=0.0)
    if np.isfinite(sd) and sd <= ILL_CONDITIONED_FOCAL_SD * f:
        return ""
    fov = float(np.degrees(2 * np.arctan(np.hypot(*model.image_size_px) / 2 / f)))
    return (
        f"ill-conditioned: focal length {f:.4g} +- {sd:.2g} px ({sd / f:.0%}), diagonal field "
        f"{fov:.2g} deg; its distance and focal length cannot be told apart"
    )


def _choose_camera_model(
    fits: Mapping[str, _KindFit | DegenerateDataError], camera_model: str
) -> tuple[str, dict[str, object]]:
    """The model kept and the figures behind the choice (cameras.json's ``model_choice``).

    ``auto``: the affine model (8 parameters without distortion) unless the pinhole model (11)
    predicts the held-out views better beyond chance (the test that chooses lens models) and
    its fit is not ill-conditioned.
    """
    candidates: list[dict[str, object]] = []
    for kind, fit in fits.items():
        if isinstance(fit, DegenerateDataError):
            candidates.append({"model": kind, "failed": str(fit)})
            continue
        held = fit.held_out_mse_px2
        held_rms = None if held is None else float(np.sqrt(np.mean(held)))
        candidates.append({
            "model": kind,
            "train_rms_px": fit.cal.rms_px if np.isfinite(fit.cal.rms_px) else None,
            "held_out_rms_px": held_rms if held_rms is not None and np.isfinite(held_rms) else None,
            "ill_conditioned": fit.ill_conditioned or None,
        })  # fmt: skip
    ok = {k: f for k, f in fits.items() if isinstance(f, _KindFit)}
    if not ok:
        raise next(iter(fits.values()))  # type: ignore[misc]
    if camera_model != "auto" or len(ok) == 1:
        kind = next(iter(ok))
        return kind, {"chosen": kind, "reason": "the only model that could be fitted",
                      "candidates": candidates}  # fmt: skip
    pin, aff = ok["pinhole"].held_out_mse_px2, ok["affine"].held_out_mse_px2
    if pin is None or aff is None:
        kind = "pinhole"
        reason = "too few views to compare held-out errors; the pinhole model kept"
    elif (
        not ok["pinhole"].ill_conditioned and np.all(np.isfinite(pin)) and predicts_better(pin, aff)
    ):
        kind = "pinhole"
        reason = "the pinhole model predicts the held-out views better beyond chance"
    else:
        kind = "affine"
        reason = "the pinhole model does not predict the held-out views better beyond chance"
        if ok["pinhole"].ill_conditioned:
            reason += f" and its fit is {ok['pinhole'].ill_conditioned.split(':')[0]}"
    return kind, {"chosen": kind, "reason": reason, "candidates": candidates}


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
        w, h = size
        if not (0 <= K[0, 2] < w and 0 <= K[1, 2] < h):
            # An ill-posed DLT (a telecentric lens, a narrow field) puts the principal point
            # anywhere; OpenCV starts only from inside the image: the image centre, and the
            # translation that keeps the points' centroid where the DLT projects it.
            centroid = p.mean(axis=0)
            depth = float((R @ centroid + t)[2])
            shift = np.array([(w - 1) / 2 - K[0, 2], (h - 1) / 2 - K[1, 2]])
            K[0, 2], K[1, 2] = (w - 1) / 2, (h - 1) / 2
            t = t - depth * np.array([shift[0] / K[0, 0], shift[1] / K[1, 1], 0.0])
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
            "are the steps in µm, one row per image in the images' sorted order? (for a "
            "telecentric lens: --camera-model affine)"
        ) from None
    sd = np.asarray(sd_in).ravel()
    std = {"fx_fy_cx_cy_px": sd[:4].tolist(), "k1_k2_p1_p2_k3": sd[4:9].tolist()}
    return _camera_model(K2, d2, rvecs[0], tvecs[0], size, name), std


def _fit_known_affine(
    p: FloatArray, q: FloatArray, size: tuple[int, int], name: str, refine: bool
) -> tuple[AffineCamera, dict[str, list[float]]]:
    """The linear affine estimate and, with ``refine``, its non-linear refinement with the
    distortion terms the pinhole refinement frees (k1, k2, p1, p2)."""
    start = AffineCamera.from_projection_matrix(estimate_affine_matrix(p, q), size, name=name)
    if not refine:
        return start, {}
    fit = refine_affine_camera(p, q, start, ("k1", "k2", "p1", "p2"))
    std = {
        "mx_my_px_per_um": [fit.std["mx_px_per_um"], fit.std["my_px_per_um"]],
        "k1_k2_p1_p2": [fit.std[k] for k in ("k1", "k2", "p1", "p2")],
    }
    return fit.camera, std


_FITTERS: dict[str, Callable[..., tuple[AnyCamera, dict[str, list[float]]]]] = {
    "pinhole": _fit_known,
    "affine": _fit_known_affine,
}


def fit_known_points(
    kind: str, p_um: FloatArray, q_px: FloatArray, size: tuple[int, int], name: str = "camera"
) -> tuple[AnyCamera, dict[str, list[float]]]:
    """One camera of ``kind`` (``"pinhole"`` or ``"affine"``) fitted to known points as
    method (a) fits it (linear, then refined with distortion), with no view rejected and no
    check of its conditioning: for studies of a model on data it may not suit.

    Parameters
    ----------
    kind : str
    p_um : (N, 3) float
        Target points in {V}, µm.
    q_px : (N, 2) float
        Their detected pixels.
    size : (int, int)
        Image width and height.

    Returns
    -------
    camera, standard deviations of its parameters
    """
    if kind not in _FITTERS:
        raise InputError(f"kind: expected one of {', '.join(_FITTERS)}, got {kind!r}")
    return _FITTERS[kind](np.asarray(p_um, float), np.asarray(q_px, float), size, name, True)


def _leave_one_out(
    kind: str,
    detections: Sequence[Detection],
    used: Sequence[int],
    target: Target,
    disp: FloatArray,
    size: tuple[int, int],
    refine: bool,
    model: AnyCamera,
) -> tuple[float, FloatArray | None, list[AnyCamera]]:
    """The calibration's own projection error (px per axis) by the jackknife over views, and
    each view's held-out mean squared error (px²), from the same fits without each view.

    Unlike the covariance of the fit, the jackknife counts what differs from view to view
    beyond pixel noise (a view's detection bias, the stage's step error): the spread of the
    calibrated volume's projections over the reduced calibrations, times (n - 1) / n,
    estimates the variance of the calibration made from all n views. (0, None, []) with fewer
    than 3 views or when a reduced set cannot be calibrated. The reduced fits come last.
    """
    n = len(used)
    if n < 3:
        return 0.0, None, []
    p_all, _ = _known_points(detections, used, target, disp)
    projections, held_out, reduced = [], [], []
    for j in used:
        rest = [i for i in used if i != j]
        try:
            cam, _ = _FITTERS[kind](*_known_points(detections, rest, target, disp), size,
                                    model.name, refine)  # fmt: skip
        except (DegenerateDataError, cv2.error):
            return 0.0, None, []
        reduced.append(cam)
        projections.append(cam.project(p_all))
        p_j, q_j = _known_points(detections, [j], target, disp)
        mse = float(np.mean(np.sum((cam.project(p_j) - q_j) ** 2, axis=1)))
        held_out.append(mse if np.isfinite(mse) else np.inf)  # a point behind the camera
    q = np.array(projections)
    with np.errstate(invalid="ignore"):  # NaN where a reduced fit put a point behind it
        var = (n - 1) / n * np.sum((q - q.mean(axis=0)) ** 2, axis=0).sum(axis=1) / 2.0
    var = var[np.isfinite(var)]
    sigma = float(np.sqrt(np.mean(var))) if var.size else 0.0
    return sigma, np.array(held_out), reduced


def calibrate_known_displacements(
    detections: Mapping[str, Sequence[Detection]],
    image_names: Mapping[str, Sequence[str]],
    target: Target,
    displacements_um: FloatArray,
    image_size_px: Mapping[str, tuple[int, int]],
    *,
    refine: bool = True,
    camera_model: str = "pinhole",
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
    camera_model : {"pinhole", "affine", "auto"}
        The model of every camera: perspective (a lens with a projection centre), affine
        (telecentric, or weak perspective), or ``"auto"``: both fitted, the affine kept unless
        the pinhole predicts each view left out of its fit better beyond chance (the
        candidates, their training and held-out RMS, in each camera's ``model_choice``).
    """
    if camera_model not in CAMERA_MODEL_CHOICES:
        raise InputError(
            f"camera_model: expected one of {', '.join(CAMERA_MODEL_CHOICES)}, got {camera_model!r}"
        )
    disp = np.asarray(displacements_um, dtype=np.float64)
    if disp.ndim != 2 or disp.shape[1] != 3:
        raise InputError(f"displacements_um: expected shape (V, 3), got {disp.shape}")
    for name, dets in detections.items():
        if len(dets) != len(disp):
            raise InputError(
                f"camera {name}: {len(dets)} images but {len(disp)} displacements; one each"
            )
    check_view_order(
        {name: _numbered(dets, target, disp) for name, dets in detections.items()},
        image_names, target, disp, image_size_px,
    )  # fmt: skip
    cams = {}
    turned_views: list[TurnedView] = []
    for name, dets in detections.items():
        cams[name], turned = _calibrate_one_known(
            name, dets, image_names[name], target, disp, image_size_px[name], refine, camera_model
        )
        turned_views += [
            TurnedView(image=image_names[name][i], camera=name, turn_deg=t)
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
