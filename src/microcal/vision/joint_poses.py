"""One joint refinement of all cameras' poses and all the target's poses (method (b)).

Each camera's intrinsics are fixed (from its own calibration). The unknowns are the pose of
every camera but the first relative to the first, and the target's pose in every view, in
the first camera's frame; the first camera's frame fixes the gauge. Each observation is one
camera's detection of the target in one view: any subset of the cameras may see a view, and
each sees the corners it found (they need not be common to the others). The residual of a
corner is its projection through ``R_c (R_v p + t_v) + t_c`` minus its detection, px; the
Jacobian is analytic (OpenCV's projection and pose-composition derivatives, chained), checked
against finite differences in the tests.

:func:`initial_poses` starts the cameras from the views each shares with one already placed
(the chordal mean of the per-view relative rotations, the median of the translations),
joining cameras that share no view through those that do.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from .._validation import FloatArray
from ..errors import DegenerateDataError

__all__ = ["JointPoses", "Observation", "initial_poses", "refine_jointly", "residuals_px"]

Pose = tuple[FloatArray, FloatArray]
"""A rigid motion: rotation (3, 3) and translation (3,) µm, ``x -> R x + t``."""


@dataclass(frozen=True)
class Observation:
    """One camera's detection of the target in one view.

    Attributes
    ----------
    camera : str
    view : int
    object_um : (N, 3) float
        The detected features' positions in the target's frame, µm.
    image_px : (N, 2) float
        Their detected image positions, px.
    """

    camera: str
    view: int
    object_um: FloatArray
    image_px: FloatArray


@dataclass(frozen=True)
class JointPoses:
    """The refined poses.

    Attributes
    ----------
    cameras : dict camera -> (R (3, 3), t (3,) µm)
        Each camera's frame from the first camera's (the first's is the identity).
    views : dict view -> (R (3, 3), t (3,) µm)
        The target's frame into the first camera's, per view.
    rms_px : float
        RMS of the corners' reprojection error (length of the 2D residual), px.
    per_view_rms_px : dict view -> float
        The same over each view's observations.
    """

    cameras: dict[str, Pose]
    views: dict[int, Pose]
    rms_px: float
    per_view_rms_px: dict[int, float]


def _rvec(R: FloatArray) -> FloatArray:
    r, _ = cv2.Rodrigues(np.asarray(R, dtype=np.float64))
    return np.asarray(r, dtype=np.float64).ravel()


def _matrix(rvec: FloatArray) -> FloatArray:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return np.asarray(R, dtype=np.float64)


def _inverse(pose: Pose) -> Pose:
    R, t = pose
    return R.T, -R.T @ t


def _compose(outer: Pose, inner: Pose) -> Pose:
    """``outer o inner``: x -> R_o (R_i x + t_i) + t_o."""
    return outer[0] @ inner[0], outer[0] @ inner[1] + outer[1]


def _mean_pose(poses: Sequence[Pose]) -> Pose:
    """Chordal mean of the rotations, median of the translations."""
    u, _, vt = np.linalg.svd(np.sum([R for R, _ in poses], axis=0))
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return R, np.median([t for _, t in poses], axis=0)


def initial_poses(
    poses: Mapping[str, Mapping[int, Pose]], first: str
) -> tuple[dict[str, Pose], dict[int, Pose]]:
    """Start values for :func:`refine_jointly` from each camera's own pose of the target.

    Parameters
    ----------
    poses : dict camera -> dict view -> (R (3, 3), t (3,) µm)
        The target's frame into each camera's, per view it saw, from its own calibration (its
        numbering already agreeing with the others').
    first : str
        The camera whose frame the result is expressed in.

    Returns
    -------
    cameras : dict camera -> pose from the first camera's frame
    views : dict view -> the target's pose in the first camera's frame

    Raises
    ------
    DegenerateDataError
        A camera shares no view with the first, directly or through other cameras.
    """
    placed: dict[str, Pose] = {first: (np.eye(3), np.zeros(3))}
    while len(placed) < len(poses):
        best: tuple[int, str, str] | None = None
        for c in poses:
            if c in placed:
                continue
            for r in placed:
                shared = len(set(poses[c]) & set(poses[r]))
                if shared and (best is None or shared > best[0]):
                    best = (shared, c, r)
        if best is None:
            lost = ", ".join(c for c in poses if c not in placed)
            raise DegenerateDataError(
                f"camera(s) {lost} share no view of the target with camera {first}, directly "
                "or through another camera; take views that two cameras see at once"
            )
        _, c, r = best
        views = sorted(set(poses[c]) & set(poses[r]))
        c_from_r = _mean_pose([_compose(poses[c][v], _inverse(poses[r][v])) for v in views])
        placed[c] = _compose(c_from_r, placed[r])
    views_out: dict[int, Pose] = {}
    for c, by_view in poses.items():
        for v, pose in by_view.items():
            if v not in views_out:
                views_out[v] = _compose(_inverse(placed[c]), pose)
    return placed, views_out


PoseDerivatives = list[FloatArray] | None


def _pack_poses(
    x: FloatArray,
    cam_index: Mapping[str, int],
    view_index: Mapping[int, int],
    cameras: Mapping[str, Pose],
    views: Mapping[int, Pose],
) -> None:
    """Write the cameras' and views' poses (rotation vector, translation) into ``x``."""
    for c, i in cam_index.items():
        x[i : i + 6] = np.concatenate([_rvec(cameras[c][0]), cameras[c][1]])
    for v, i in view_index.items():
        x[i : i + 6] = np.concatenate([_rvec(views[v][0]), views[v][1]])


def _unpack_poses(
    x: FloatArray, first: str, cam_index: Mapping[str, int], view_index: Mapping[int, int]
) -> tuple[dict[str, Pose], dict[int, Pose]]:
    """The cameras' poses (``first`` at the origin) and the views' poses held in ``x``."""
    cameras: dict[str, Pose] = {first: (np.eye(3), np.zeros(3))}
    for c, i in cam_index.items():
        cameras[c] = (_matrix(x[i : i + 3]), x[i + 3 : i + 6].copy())
    views = {v: (_matrix(x[i : i + 3]), x[i + 3 : i + 6].copy()) for v, i in view_index.items()}
    return cameras, views


def _view_in_camera(
    x: FloatArray, iv: int, ic: int | None
) -> tuple[FloatArray, FloatArray, PoseDerivatives]:
    """The board's pose in a camera (rvec, tvec) from the view's pose at ``iv`` and, unless
    the camera is the first (``ic`` None), the camera's pose at ``ic``; with the composition's
    derivatives (``cv2.composeRT``'s), None for the first camera."""
    rv, tv = x[iv : iv + 3], x[iv + 3 : iv + 6]
    if ic is None:
        return rv, tv, None
    r3, t3, *d = cv2.composeRT(rv, tv, x[ic : ic + 3], x[ic + 3 : ic + 6])
    return r3, t3, d


def _pose_columns(
    jac: FloatArray, lo: int, hi: int, J: FloatArray, iv: int, ic: int | None,
    d: PoseDerivatives,
) -> None:  # fmt: skip
    """Fill the view's and camera's columns of rows ``lo:hi`` of ``jac`` from
    ``cv2.projectPoints``' Jacobian ``J`` through the composition's derivatives ``d``."""
    Jr, Jt = J[:, 0:3], J[:, 3:6]
    if d is None or ic is None:
        jac[lo:hi, iv : iv + 3], jac[lo:hi, iv + 3 : iv + 6] = Jr, Jt
        return
    dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = d
    jac[lo:hi, iv : iv + 3] = Jr @ dr3dr1 + Jt @ dt3dr1
    jac[lo:hi, iv + 3 : iv + 6] = Jr @ dr3dt1 + Jt @ dt3dt1
    jac[lo:hi, ic : ic + 3] = Jr @ dr3dr2 + Jt @ dt3dr2
    jac[lo:hi, ic + 3 : ic + 6] = Jr @ dr3dt2 + Jt @ dt3dt2


class _Problem:
    """The parameter vector and the residuals with their Jacobian."""

    def __init__(
        self,
        observations: Sequence[Observation],
        intrinsics: Mapping[str, tuple[FloatArray, FloatArray]],
        first: str,
        cameras: Sequence[str],
        views: Sequence[int],
    ) -> None:
        self.obs = list(observations)
        self.intrinsics = intrinsics
        self.first = first
        free = [c for c in cameras if c != first]
        self.cam_index = {c: 6 * k for k, c in enumerate(free)}
        self.view_index = {v: 6 * (len(free) + k) for k, v in enumerate(views)}
        self.n_params = 6 * (len(free) + len(views))
        self.rows = np.cumsum([0] + [2 * len(o.object_um) for o in self.obs])

    def pack(self, cameras: Mapping[str, Pose], views: Mapping[int, Pose]) -> FloatArray:
        x = np.zeros(self.n_params)
        _pack_poses(x, self.cam_index, self.view_index, cameras, views)
        return x

    def unpack(self, x: FloatArray) -> tuple[dict[str, Pose], dict[int, Pose]]:
        return _unpack_poses(x, self.first, self.cam_index, self.view_index)

    def evaluate(self, x: FloatArray, jacobian: bool) -> tuple[FloatArray, FloatArray | None]:
        res = np.zeros(self.rows[-1])
        jac = np.zeros((self.rows[-1], self.n_params)) if jacobian else None
        for k, o in enumerate(self.obs):
            iv = self.view_index[o.view]
            ic = self.cam_index.get(o.camera)
            r3, t3, d = _view_in_camera(x, iv, ic)
            K, dist = self.intrinsics[o.camera]
            q, J = cv2.projectPoints(o.object_um.astype(np.float64), r3, t3, K, dist)
            lo, hi = self.rows[k], self.rows[k + 1]
            res[lo:hi] = (q.reshape(-1, 2) - o.image_px).ravel()
            if jac is not None:
                _pose_columns(jac, lo, hi, J, iv, ic, d)
        return res, jac


def residuals_px(
    x: FloatArray,
    observations: Sequence[Observation],
    intrinsics: Mapping[str, tuple[FloatArray, FloatArray]],
    first: str,
) -> tuple[FloatArray, FloatArray]:
    """The stacked residuals (2N,) px and their Jacobian (2N, P) at the parameters ``x``.

    ``x`` holds (Rodrigues vector, translation µm) per camera but the first, in order of
    first appearance in ``observations``, then per view, in the same order.
    """
    cams = list(dict.fromkeys(o.camera for o in observations))
    views = list(dict.fromkeys(o.view for o in observations))
    res, jac = _Problem(observations, intrinsics, first, cams, views).evaluate(x, True)
    assert jac is not None
    return res, jac


def refine_jointly(
    observations: Sequence[Observation],
    intrinsics: Mapping[str, tuple[FloatArray, FloatArray]],
    cameras: Mapping[str, Pose],
    views: Mapping[int, Pose],
    first: str,
) -> JointPoses:
    """Refine every camera's pose and every view's target pose together.

    Parameters
    ----------
    observations : list of Observation
    intrinsics : dict camera -> (K (3, 3), distortion coefficients in OpenCV's order)
        Fixed.
    cameras, views
        Start values, as :func:`initial_poses` gives them; only the cameras and views that
        ``observations`` name are refined and returned.
    first : str
        The camera whose frame fixes the gauge.

    Returns
    -------
    JointPoses
    """
    used_cams = list(dict.fromkeys(o.camera for o in observations))
    used_views = list(dict.fromkeys(o.view for o in observations))
    problem = _Problem(observations, intrinsics, first, used_cams, used_views)
    x0 = problem.pack(cameras, views)
    if len(problem.rows) - 1 == 0 or problem.rows[-1] < problem.n_params:
        raise DegenerateDataError("too few corners for the joint refinement of the poses")
    sol = least_squares(
        lambda x: problem.evaluate(x, False)[0],
        x0,
        jac=lambda x: problem.evaluate(x, True)[1],
        method="lm",
        xtol=1e-12,
        ftol=1e-12,
    )
    res = sol.fun.reshape(-1, 2)
    sq = np.sum(res**2, axis=1)
    per_view: dict[int, list[float]] = {}
    start = 0
    for o in problem.obs:
        n = len(o.object_um)
        per_view.setdefault(o.view, []).extend(sq[start : start + n].tolist())
        start += n
    cams, poses = problem.unpack(sol.x)
    return JointPoses(
        cams,
        poses,
        float(np.sqrt(np.mean(sq))),
        {v: float(np.sqrt(np.mean(e))) for v, e in per_view.items()},
    )
