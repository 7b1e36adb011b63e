"""One joint refinement of all cameras' intrinsics, lens terms and poses (method (b)).

Calibrated alone, each camera fits its own board pose in every view: its focal lengths,
principal point and lens terms trade off against poses that nothing ties to the other
cameras'. A small shift of one camera's principal point (on a wide-angle lens, traded with
its tangential terms) then turns and moves the transform between the cameras. Refined
together, the views seen by two or more cameras share one board pose, so each camera's
intrinsics must agree with the others' view of the same board: the shared geometry
constrains them, and the transform between the cameras no longer depends on how each camera
split its intrinsics from its poses (on the Bumblebee2 photographs the baseline moved by
0.24 % with the right camera's tangential terms with its intrinsics fixed, by 0.09 % refined
jointly; docs/vision.md).

The unknowns are, per camera, fx, fy, cx, cy (no skew) and the free terms of its chosen lens
model (the others stay zero), the pose of every camera but the first relative to the first,
and the target's pose in every view, in the first camera's frame. The residual of a corner
is its projection through ``R_c (R_v p + t_v) + t_c`` minus its detection, px; the
Jacobian is analytic (OpenCV's projection derivatives, chained through the pose
composition), checked against finite differences in the tests. A view that one camera alone
saw keeps its own board pose and constrains that camera's intrinsics, as in its own
calibration.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from .._validation import FloatArray
from ..errors import DegenerateDataError
from .joint_poses import (
    Observation,
    Pose,
    _pack_poses,
    _pose_columns,
    _unpack_poses,
    _view_in_camera,
)
from .lens_models import LensModel

__all__ = ["DIST_INDEX", "JointCalibration", "refine_intrinsics_jointly", "residuals_px"]

#: Position of each distortion term in OpenCV's coefficient vector.
DIST_INDEX = {"k1": 0, "k2": 1, "p1": 2, "p2": 3, "k3": 4, "k4": 5, "k5": 6, "k6": 7,
              "s1": 8, "s2": 9, "s3": 10, "s4": 11, "tau_x": 12, "tau_y": 13}  # fmt: skip

Intrinsics = tuple[FloatArray, FloatArray]


@dataclass(frozen=True)
class JointCalibration:
    """The refined intrinsics and poses.

    Attributes
    ----------
    intrinsics : dict camera -> (K (3, 3), dist (n,))
        Each camera's refined intrinsics; dist keeps its length and the model's fixed terms.
    cameras : dict camera -> (R (3, 3), t (3,) µm)
        Each camera's frame from the first camera's (the first's is the identity).
    views : dict view -> (R (3, 3), t (3,) µm)
        The target's frame into the first camera's, per view.
    rms_px : float
        RMS of the corners' reprojection error (length of the 2D residual) over the views
        two or more cameras saw, px (all views when none is shared).
    per_view_rms_px : dict view -> float
        The same over each view's observations (every view).
    """

    intrinsics: dict[str, Intrinsics]
    cameras: dict[str, Pose]
    views: dict[int, Pose]
    rms_px: float
    per_view_rms_px: dict[int, float]


class _Problem:
    """The parameter vector and the residuals with their Jacobian."""

    def __init__(
        self,
        observations: Sequence[Observation],
        intrinsics: Mapping[str, Intrinsics],
        models: Mapping[str, LensModel],
        first: str,
    ) -> None:
        self.obs = list(observations)
        self.first = first
        cameras = list(dict.fromkeys(o.camera for o in self.obs))
        views = list(dict.fromkeys(o.view for o in self.obs))
        offset = 0
        self.free: dict[str, list[int]] = {}
        self.intr_index: dict[str, int] = {}
        self.dist0: dict[str, FloatArray] = {}
        for c in cameras:
            self.dist0[c] = np.asarray(intrinsics[c][1], dtype=np.float64).ravel().copy()
            self.free[c] = [DIST_INDEX[t] for t in models[c].terms
                            if DIST_INDEX[t] < self.dist0[c].size]  # fmt: skip
            self.intr_index[c] = offset
            offset += 4 + len(self.free[c])
        self.cam_index: dict[str, int] = {}
        for c in cameras:
            if c != first:
                self.cam_index[c] = offset
                offset += 6
        self.view_index: dict[int, int] = {}
        for v in views:
            self.view_index[v] = offset
            offset += 6
        self.n_params = offset
        self.rows = np.cumsum([0] + [2 * len(o.object_um) for o in self.obs])

    def pack(
        self,
        intrinsics: Mapping[str, Intrinsics],
        cameras: Mapping[str, Pose],
        views: Mapping[int, Pose],
    ) -> FloatArray:
        x = np.zeros(self.n_params)
        for c, i in self.intr_index.items():
            K = np.asarray(intrinsics[c][0], dtype=np.float64)
            x[i : i + 4] = [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
            x[i + 4 : i + 4 + len(self.free[c])] = self.dist0[c][self.free[c]]
        _pack_poses(x, self.cam_index, self.view_index, cameras, views)
        return x

    def intrinsics(self, x: FloatArray) -> dict[str, Intrinsics]:
        out: dict[str, Intrinsics] = {}
        for c, i in self.intr_index.items():
            K = np.array([[x[i], 0.0, x[i + 2]], [0.0, x[i + 1], x[i + 3]], [0.0, 0.0, 1.0]])
            dist = self.dist0[c].copy()
            dist[self.free[c]] = x[i + 4 : i + 4 + len(self.free[c])]
            out[c] = (K, dist)
        return out

    def unpack(self, x: FloatArray) -> tuple[dict[str, Pose], dict[int, Pose]]:
        return _unpack_poses(x, self.first, self.cam_index, self.view_index)

    def evaluate(self, x: FloatArray, jacobian: bool) -> tuple[FloatArray, FloatArray | None]:
        res = np.zeros(self.rows[-1])
        jac = np.zeros((self.rows[-1], self.n_params)) if jacobian else None
        intr = self.intrinsics(x)
        for k, o in enumerate(self.obs):
            iv = self.view_index[o.view]
            ic = self.cam_index.get(o.camera)
            r3, t3, d = _view_in_camera(x, iv, ic)
            K, dist = intr[o.camera]
            q, J = cv2.projectPoints(o.object_um.astype(np.float64), r3, t3, K, dist)
            lo, hi = self.rows[k], self.rows[k + 1]
            res[lo:hi] = (q.reshape(-1, 2) - o.image_px).ravel()
            if jac is None:
                continue
            ii, free = self.intr_index[o.camera], self.free[o.camera]
            jac[lo:hi, ii : ii + 2] = J[:, 6:8]  # fx, fy
            jac[lo:hi, ii + 2 : ii + 4] = J[:, 8:10]  # cx, cy
            jac[lo:hi, ii + 4 : ii + 4 + len(free)] = J[:, 10:][:, free]
            _pose_columns(jac, lo, hi, J, iv, ic, d)
        return res, jac


def residuals_px(
    x: FloatArray,
    observations: Sequence[Observation],
    intrinsics: Mapping[str, Intrinsics],
    models: Mapping[str, LensModel],
    first: str,
) -> tuple[FloatArray, FloatArray]:
    """The stacked residuals (2N,) px and their Jacobian (2N, P) at the parameters ``x``.

    ``x`` holds, per camera in order of first appearance in ``observations``: fx, fy, cx, cy
    and the model's free lens terms (``intrinsics`` gives the fixed ones); then (Rodrigues
    vector, translation µm) per camera but the first; then per view, in order of first
    appearance.
    """
    res, jac = _Problem(observations, intrinsics, models, first).evaluate(x, True)
    assert jac is not None
    return res, jac


def refine_intrinsics_jointly(
    observations: Sequence[Observation],
    intrinsics: Mapping[str, Intrinsics],
    models: Mapping[str, LensModel],
    cameras: Mapping[str, Pose],
    views: Mapping[int, Pose],
    first: str,
) -> JointCalibration:
    """Refine every camera's intrinsics and pose and every view's target pose together.

    Parameters
    ----------
    observations : list of Observation
        Every camera's detections; a view one camera alone saw constrains that camera only.
    intrinsics : dict camera -> (K (3, 3), distortion coefficients in OpenCV's order)
        Start values (each camera's own calibration).
    models : dict camera -> LensModel
        Each camera's lens model: its free terms are refined, the others kept.
    cameras, views
        Start values, as :func:`~microcal.vision.joint_poses.refine_jointly` gives them;
        every view that ``observations`` names needs one.
    first : str
        The camera whose frame fixes the gauge.

    Returns
    -------
    JointCalibration

    Raises
    ------
    DegenerateDataError
        Fewer residuals than unknowns, or the refinement does not converge to finite values.
    """
    problem = _Problem(observations, intrinsics, models, first)
    if problem.rows[-1] < problem.n_params:
        raise DegenerateDataError("too few corners for the joint refinement of the cameras")
    x0 = problem.pack(intrinsics, cameras, views)
    sol = least_squares(
        lambda x: problem.evaluate(x, False)[0],
        x0,
        jac=lambda x: problem.evaluate(x, True)[1],
        method="lm",
        xtol=1e-12,
        ftol=1e-12,
    )
    if not np.all(np.isfinite(sol.x)):
        raise DegenerateDataError("the joint refinement of the cameras did not converge")
    sq = np.sum(sol.fun.reshape(-1, 2) ** 2, axis=1)
    per_view: dict[int, list[float]] = {}
    seen_by: dict[int, set[str]] = {}
    start = 0
    for o in problem.obs:
        n = len(o.object_um)
        per_view.setdefault(o.view, []).extend(sq[start : start + n].tolist())
        seen_by.setdefault(o.view, set()).add(o.camera)
        start += n
    shared = [e for v, e in per_view.items() if len(seen_by[v]) >= 2]
    pooled = [x for e in (shared or list(per_view.values())) for x in e]
    cams, poses = problem.unpack(sol.x)
    return JointCalibration(
        problem.intrinsics(sol.x),
        cams,
        poses,
        float(np.sqrt(np.mean(pooled))),
        {v: float(np.sqrt(np.mean(e))) for v, e in per_view.items()},
    )
