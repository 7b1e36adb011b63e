"""Figures a calibration can be trusted by without a reference (method (b)).

Three checks that need no ground truth, only the views the calibration was made from:

- **Held-out views** (:func:`held_out_error`): the views are split in four interleaved folds
  (fewer with fewer than eight views); all but one calibrate the cameras (each camera's
  chosen lens model, then the joint refinement of poses and intrinsics) and the one left
  out is predicted: a held-out view's board pose is solved with the calibration fixed, and
  its reprojection error measured. A calibration that fits its views
  but not the camera (too rich a model, too few views, a corner bias that differs from view
  to view) predicts held-out views worse than it fits its own: the ratio says by how much.
- **The target's pitch** (:func:`triangulated_pitch`): the corners of every view two or more
  cameras saw are triangulated and the distances between neighbours along the target's x and
  y axes compared with its pitch, over all of the field (worst cell of a 3 x 3 grid over the
  first camera's image). Scale comes from the target spec, so this checks the cameras'
  relative geometry and lenses, not the spec.
- **Three cameras** (:func:`transform_closure`): for each pair of cameras, the transform from
  one to the other calibrated from the views the two share alone, against the one composed
  through a third camera (each of its legs calibrated alike). They agree when the lens
  models and the corners are right; a bias in either shows as a gap.

:func:`consistency` gathers them as the dict written to cameras.json (``stereo.consistency``,
docs/formats.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import permutations

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from .._validation import FloatArray
from ..errors import DegenerateDataError
from ..geometry import CameraModel
from ..geometry.triangulation import triangulate_views
from ..json_value import JsonValue
from .detect import Detection
from .joint_intrinsics import refine_intrinsics_jointly
from .joint_poses import Observation, Pose, _compose, _inverse, initial_poses, refine_jointly
from .lens_models import LensModel, fit_camera
from .targets import Target
from .view_consistency import rotation_angle_deg

__all__ = ["consistency", "held_out_error", "transform_closure", "triangulated_pitch"]

#: Common corners a view needs in a camera to count for it.
MIN_POINTS = 6
#: Views two cameras must share for their transform to be calibrated from them alone.
MIN_SHARED_VIEWS = 3
#: The views are split into this many interleaved folds (fewer with few views), each held
#: out in turn while the others calibrate.
HELD_OUT_FOLDS = 4
#: The field is split into this many cells per side for the worst local pitch error.
FIELD_CELLS = 3

Intrinsics = tuple[FloatArray, FloatArray]


def _rms(sq: Sequence[float]) -> float:
    return float(np.sqrt(np.mean(sq))) if len(sq) else float("nan")


def _solve_board(
    obs: Sequence[Observation],
    intrinsics: Mapping[str, Intrinsics],
    cameras: Mapping[str, Pose],
) -> FloatArray:
    """Squared reprojection errors of one view whose board pose is solved, cameras fixed."""
    o0 = obs[0]
    K, d = intrinsics[o0.camera]
    _, rvec, tvec = cv2.solvePnP(o0.object_um, o0.image_px, K, d)
    Rc, tc = cameras[o0.camera]
    Rv0 = Rc.T @ cv2.Rodrigues(rvec)[0]
    x0 = np.concatenate([cv2.Rodrigues(Rv0)[0].ravel(), Rc.T @ (np.ravel(tvec) - tc)])

    def residuals(x: FloatArray) -> FloatArray:
        Rv = cv2.Rodrigues(x[:3])[0]
        out = []
        for o in obs:
            Rc, tc = cameras[o.camera]
            K, d = intrinsics[o.camera]
            R = Rc @ Rv
            t = Rc @ x[3:] + tc
            p, _ = cv2.projectPoints(o.object_um, cv2.Rodrigues(R)[0], t, K, d)
            out.append((p.reshape(-1, 2) - o.image_px).ravel())
        return np.concatenate(out)

    sol = least_squares(residuals, x0, method="lm")
    res: FloatArray = np.sum(sol.fun.reshape(-1, 2) ** 2, axis=1)
    return res


def held_out_error(
    observations: Mapping[int, Sequence[Observation]],
    models: Mapping[str, LensModel],
    sizes: Mapping[str, tuple[int, int]],
    first: str,
    start: Mapping[str, Intrinsics] | None = None,
) -> dict[str, JsonValue]:
    """Training and held-out RMS over interleaved folds of the views (:data:`HELD_OUT_FOLDS`).

    Parameters
    ----------
    observations : dict view -> list of Observation
        Every usable view of every camera (a view one camera alone saw counts for that
        camera's own figures).
    models : dict camera -> LensModel
        Each camera's chosen lens model.
    sizes : dict camera -> (w, h)
    first : str
        The camera whose frame fixes the gauge of the joint refinement.
    start : dict camera -> (K, dist), optional
        Intrinsics each fold's calibration starts from (the whole calibration's).

    Returns
    -------
    dict
        ``cameras``: per camera ``training_rms_px``, ``held_out_rms_px``, ``ratio``; and
        ``joint`` (two cameras or more): the same for the views two or more cameras saw,
        each held-out view's board pose solved from all the cameras that saw it.
    """
    views = sorted(observations)
    n_folds = max(2, min(HELD_OUT_FOLDS, len(views) // 2))
    folds = [views[k::n_folds] for k in range(n_folds)]
    train_sq: dict[str, list[float]] = {c: [] for c in models}
    held_sq: dict[str, list[float]] = {c: [] for c in models}
    joint_train: list[float] = []
    joint_held: list[float] = []
    for k in range(n_folds):
        held = folds[k]
        train = [v for v in views if v not in set(held)]
        intrinsics: dict[str, Intrinsics] = {}
        poses: dict[str, dict[int, Pose]] = {c: {} for c in models}
        for c, model in models.items():
            mine = [(v, o) for v in train for o in observations[v] if o.camera == c]
            if len(mine) < 3:
                continue
            try:
                guess = None if start is None else start.get(c)
                fit = fit_camera([o.object_um for _, o in mine], [o.image_px for _, o in mine],
                                 sizes[c], model, guess=guess)  # fmt: skip
            except DegenerateDataError:
                continue
            intrinsics[c] = (fit.K, fit.dist)
            for (v, _), rv, tv in zip(mine, fit.rvecs, fit.tvecs, strict=True):
                poses[c][v] = (cv2.Rodrigues(np.asarray(rv))[0], np.ravel(tv))
            train_sq[c] += [float(fit.rms_px) ** 2] * sum(len(o.object_um) for _, o in mine)
            for v in held:
                for o in observations[v]:
                    if o.camera != c:
                        continue
                    ok, rv, tv = cv2.solvePnP(o.object_um, o.image_px, fit.K, fit.dist)
                    if not ok:
                        continue
                    p, _ = cv2.projectPoints(o.object_um, rv, tv, fit.K, fit.dist)
                    held_sq[c] += np.sum((p.reshape(-1, 2) - o.image_px) ** 2, axis=1).tolist()
        if len(models) < 2 or first not in intrinsics:
            continue
        multi = [v for v in train
                 if sum(o.camera in intrinsics for o in observations[v]) >= 2]  # fmt: skip
        obs = [o for v in multi for o in observations[v] if o.camera in intrinsics]
        try:
            by_camera = {c: {o.view: poses[c][o.view] for o in obs if o.camera == c}
                         for c in intrinsics}  # fmt: skip
            start_cams, start_views = initial_poses(by_camera, first)
            fit_p = refine_jointly(obs, intrinsics, start_cams, start_views, first=first)
            # then the intrinsics too, as the calibration itself (joint_intrinsics)
            views_start = dict(fit_p.views)
            alone = []
            for v in train:
                sole = [o for o in observations[v] if o.camera in intrinsics]
                if len(sole) == 1 and sole[0].camera in fit_p.cameras:
                    cam = sole[0].camera
                    views_start[v] = _compose(_inverse(fit_p.cameras[cam]), poses[cam][v])
                    alone.append(sole[0])
            fit_j = refine_intrinsics_jointly(obs + alone, intrinsics, models, fit_p.cameras,
                                              views_start, first)  # fmt: skip
        except DegenerateDataError:
            continue
        joint_train += [fit_j.rms_px**2] * sum(len(o.object_um) for o in obs)
        for v in held:
            seen = [o for o in observations[v] if o.camera in fit_j.cameras]
            if len(seen) >= 2:
                joint_held += _solve_board(seen, fit_j.intrinsics, fit_j.cameras).tolist()
    out: dict[str, JsonValue] = {}
    cams: dict[str, JsonValue] = {}
    for c in models:
        tr, he = _rms(train_sq[c]), _rms(held_sq[c])
        cams[c] = {"training_rms_px": _finite(tr), "held_out_rms_px": _finite(he),
                   "ratio": _finite(he / tr) if tr > 0 else None}  # fmt: skip
    out["cameras"] = cams
    if len(models) >= 2:
        tr, he = _rms(joint_train), _rms(joint_held)
        out["joint"] = {"training_rms_px": _finite(tr), "held_out_rms_px": _finite(he),
                        "ratio": _finite(he / tr) if tr > 0 else None}  # fmt: skip
    return out


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def triangulated_pitch(
    target: Target,
    detections: Mapping[str, Mapping[int, Detection]],
    cameras: Mapping[str, CameraModel],
    views: Sequence[int],
) -> dict[str, JsonValue]:
    """The target's pitch between neighbouring corners, triangulated, along its x and y.

    Parameters
    ----------
    target : Target
    detections : dict camera -> dict view -> Detection
        Numbered alike in every camera.
    cameras : dict camera -> CameraModel
        The calibrated cameras.
    views : list of int
        The views to triangulate (two or more cameras saw each).

    Returns
    -------
    dict
        ``x`` and ``y``: ``nominal_um`` (the target's), ``mean_um``, ``error`` (mean / nominal
        - 1), ``rms_error`` (of single neighbour distances, relative), ``worst_cell_error``
        (the mean's relative error in the worst cell of a 3 x 3 grid over the first camera's
        image) and ``segments``.
    """
    # neighbours and the pitch from the nominal lattice: a slide whose dots were measured
    # (its points off the lattice by the print's error) is compared with its stated pitch
    obj = Target.points_um(target)
    names = list(cameras)
    first = names[0]
    w, h = cameras[first].image_size_px
    seg: dict[str, list[tuple[float, float, float]]] = {"x": [], "y": []}
    nominal: dict[str, float] = {}
    pairs = {axis: found for axis, k in (("x", 0), ("y", 1))
             if (found := _lattice_neighbours(obj, k)) is not None}  # fmt: skip
    for v in views:
        seen = [c for c in names if v in detections[c]]
        if len(seen) < 2:
            continue
        q = []
        for c in names:
            qc = np.full((len(obj), 2), np.nan)
            if v in detections[c]:
                d = detections[c][v]
                qc[d.ids] = cameras[c].undistort_px(d.q_px)
            q.append(qc)
        p, _, _ = triangulate_views([cameras[c] for c in names], q, [1.0] * len(names))
        where = q[0] if v in detections[first] else np.full((len(obj), 2), np.nan)
        for axis, (pitch, i, j) in pairs.items():
            nominal[axis] = pitch
            ok = np.all(np.isfinite(p[i]), axis=1) & np.all(np.isfinite(p[j]), axis=1)
            dist = np.linalg.norm(p[j[ok]] - p[i[ok]], axis=1)
            mid = 0.5 * (where[i[ok]] + where[j[ok]])
            seg[axis] += [
                (float(a), float(b), float(c)) for a, (b, c) in zip(dist, mid, strict=True)
            ]
    out: dict[str, JsonValue] = {}
    for axis, rows in seg.items():
        if not rows:
            continue
        a = np.array(rows)
        rel = a[:, 0] / nominal[axis] - 1.0
        cells = []
        fin = np.all(np.isfinite(a[:, 1:]), axis=1)
        cx = np.clip((a[fin, 1] / w * FIELD_CELLS).astype(int), 0, FIELD_CELLS - 1)
        cy = np.clip((a[fin, 2] / h * FIELD_CELLS).astype(int), 0, FIELD_CELLS - 1)
        for gx in range(FIELD_CELLS):
            for gy in range(FIELD_CELLS):
                pick = (cx == gx) & (cy == gy)
                if np.count_nonzero(pick) >= 5:
                    cells.append(float(np.mean(rel[fin][pick])))
        out[axis] = {
            "nominal_um": nominal[axis],
            "mean_um": float(np.mean(a[:, 0])),
            "error": float(np.mean(rel)),
            "rms_error": float(np.sqrt(np.mean(rel**2))),
            "worst_cell_error": max(cells, key=abs) if cells else None,
            "segments": len(rows),
        }
    return out


def _lattice_neighbours(
    obj: FloatArray, k: int, rows: int = 256
) -> tuple[float, NDArray[np.intp], NDArray[np.intp]] | None:
    """The lattice's pitch along axis ``k`` and its neighbour pairs ``(i, j)`` along it.

    ``obj`` (N, 3): the target's points. The pitch is the smallest positive difference of
    their coordinates ``k``; a pair is two points one pitch apart along ``k`` (``j`` after
    ``i``) and level across it (within 1e-6 of the pitch), listed in the order of ``i``, then
    ``j``. None when every point has the same coordinate ``k``. Compared a block of ``rows``
    points at a time with all, so its memory stays ``rows x N``.
    """
    values = np.unique(obj[:, k])
    if values.size < 2:
        return None
    pitch = float(np.min(np.diff(values)))
    step = np.zeros(3)
    step[k] = 1.0
    found_i, found_j = [], []
    for start in range(0, len(obj), rows):
        diffs = obj[None, :, :] - obj[start : start + rows, None, :]
        along = diffs[..., k]
        across = np.linalg.norm(diffs - diffs * step, axis=2)
        i, j = np.nonzero((np.abs(np.abs(along) - pitch) < 1e-6 * pitch)
                          & (across < 1e-6 * pitch) & (along > 0))  # fmt: skip
        found_i.append(i + start)
        found_j.append(j)
    return pitch, np.concatenate(found_i), np.concatenate(found_j)


def _pair_transform(
    a: str,
    b: str,
    observations: Mapping[int, Sequence[Observation]],
    intrinsics: Mapping[str, Intrinsics],
    poses: Mapping[str, Mapping[int, Pose]],
) -> Pose | None:
    """Camera b's frame from camera a's, calibrated from the views the two share alone."""
    shared = [v for v, obs in observations.items()
              if {a, b} <= {o.camera for o in obs}]  # fmt: skip
    if len(shared) < MIN_SHARED_VIEWS:
        return None
    obs = [o for v in shared for o in observations[v] if o.camera in (a, b)]
    by_camera = {c: {v: poses[c][v] for v in shared} for c in (a, b)}
    try:
        fit = refine_jointly(obs, {c: intrinsics[c] for c in (a, b)},
                             *initial_poses(by_camera, a), first=a)  # fmt: skip
    except DegenerateDataError:
        return None
    return fit.cameras[b]


def transform_closure(
    observations: Mapping[int, Sequence[Observation]],
    intrinsics: Mapping[str, Intrinsics],
    poses: Mapping[str, Mapping[int, Pose]],
) -> list[JsonValue]:
    """Each pair's transform calibrated directly against the one composed through a third.

    Parameters
    ----------
    observations : dict view -> list of Observation
        The views the joint refinement kept, numbered alike in every camera.
    intrinsics : dict camera -> (K, dist)
    poses : dict camera -> dict view -> (R, t)
        The board's pose in each camera per view (each camera's own calibration), to start
        from.

    Returns
    -------
    list of dict
        One per pair (a, c) and third camera b whose three legs could be calibrated:
        ``cameras`` [a, b, c], ``baseline_um`` (the direct one's length),
        ``translation_gap`` (the distance between the direct and the composed translation
        over the direct one's length) and ``rotation_gap_deg``.
    """
    names = list(intrinsics)
    legs: dict[tuple[str, str], Pose | None] = {}
    for a, b in permutations(names, 2):
        if (b, a) in legs:
            inv = legs[(b, a)]
            legs[(a, b)] = None if inv is None else (inv[0].T, -inv[0].T @ inv[1])
        else:
            legs[(a, b)] = _pair_transform(a, b, observations, intrinsics, poses)
    out: list[JsonValue] = []
    for i, a in enumerate(names):
        for c in names[i + 1 :]:
            direct = legs[(a, c)]
            for b in names:
                if b in (a, c) or direct is None:
                    continue
                ab, bc = legs[(a, b)], legs[(b, c)]
                if ab is None or bc is None:
                    continue
                R = bc[0] @ ab[0]
                t = bc[0] @ ab[1] + bc[1]
                length = float(np.linalg.norm(direct[1]))
                out.append({
                    "cameras": [a, b, c],
                    "baseline_um": length,
                    "translation_gap": float(np.linalg.norm(t - direct[1]) / length),
                    "rotation_gap_deg": rotation_angle_deg(R, direct[0]),
                })  # fmt: skip
    return out


def consistency(
    target: Target,
    detections: Mapping[str, Mapping[int, Detection]],
    poses: Mapping[str, Mapping[int, Pose]],
    models: Mapping[str, LensModel],
    cameras: Mapping[str, CameraModel],
    joint_views: Sequence[int],
    first: str,
) -> dict[str, JsonValue]:
    """The consistency figures of a calibration from unknown poses (cameras.json's
    ``stereo.consistency``).

    Parameters
    ----------
    target : Target
    detections : dict camera -> dict view -> Detection
        Every usable view of every camera, numbered alike in every camera.
    poses : dict camera -> dict view -> (R, t)
        The board's pose in each camera per view, from each camera's own calibration.
    models : dict camera -> LensModel
    cameras : dict camera -> CameraModel
        The calibration.
    joint_views : list of int
        The views the joint refinement kept.
    first : str
        The camera whose frame fixes the gauge.
    """
    obj = target.points_um()
    observations: dict[int, list[Observation]] = {}
    for c, by_view in detections.items():
        for v, d in by_view.items():
            if len(d.ids) >= MIN_POINTS:
                observations.setdefault(v, []).append(Observation(c, v, obj[d.ids], d.q_px))
    sizes = {c: m.image_size_px for c, m in cameras.items()}
    out: dict[str, JsonValue] = {
        "held_out": held_out_error(
            observations, models, sizes, first, {c: (m.K, m.dist) for c, m in cameras.items()}
        )
    }
    if len(cameras) >= 2:
        kept = {c: {v: d for v, d in by_view.items() if v in set(joint_views)}
                for c, by_view in detections.items()}  # fmt: skip
        out["pitch"] = triangulated_pitch(target, kept, cameras, joint_views)
    if len(cameras) >= 3:
        intrinsics = {c: (m.K, m.dist) for c, m in cameras.items()}
        joint = {v: o for v, o in observations.items() if v in set(joint_views)}
        out["closure"] = transform_closure(joint, intrinsics, poses)
    return out
