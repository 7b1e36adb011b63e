"""The tool-centre point from a few poses of a tool that carries a board and a tip.

At each pose every camera's frames are measured twice: the board (its virtual point and,
from its corners triangulated, its orientation: :func:`~microcal.vision.board_pose.board_pose`)
and the tool's tip (its apex in each camera, triangulated:
:func:`~microcal.vision.measurement.measure_one`). Before the tip is searched, the board
(its printed pattern and white margin, mapped from its corners by a homography) is painted
over with the frame's background level in each camera (:func:`hide_board`), so that its dark
squares and bright margin are neither taken for tools nor pull the tip's outline. A pose
where either is missing is kept with its reason and left out of the fit.

The fit (:func:`fit_carried`): when the board's orientation is the same at every pose within
:data:`TURNING_RAD` (a manipulator that only translates, as the thesis's), the tip's offset
is the weighted mean of ``tip - board`` in {G} turned into the board's mean orientation, and
its covariance adds the mean orientation's own uncertainty (from the poses' scatter). A
board that turns is fitted pose by pose (``tip_i = board_i + R_i o``).

Applied (:func:`tip_calibration`): the board's kinematic model with its base offset moved by
the offset in {G} predicts the tip; the compensator then drives the tip. A changed tool needs
only a new offset (``microcal tool-centre``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import DetectionError, InputError
from ..geometry import AnyCamera
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..vision.board_pose import board_pose, mean_rotation
from ..vision.measurement import measure_one
from ..vision.targets import Target
from ..vision.tip_target import TipTarget
from ..vision.tip_vertex import (
    camera_vertex,
    takes_3d_vertex_path,
    tip_from_vertices,
    vertex_model_cov_um2,
)
from ..vision.tool_centre import ToolCentre, fit_tool_centre
from .check import offset_updated

__all__ = [
    "BOARD_HIDE_MARGIN",
    "TURNING_RAD",
    "CarriedPose",
    "fit_carried",
    "hide_board",
    "measure_carried",
    "tip_calibration",
]

#: How far beyond its printed pattern the board is painted over before the tip is searched,
#: in pitches (its white margin, one pitch, and its blur).
BOARD_HIDE_MARGIN = 1.4

#: A board whose orientation differs between poses by more than this turns, rad (the
#: orientation from one pose's corners scatters by some 5 mrad on the thesis's cameras).
TURNING_RAD = 0.05


def _nan(*shape: int) -> FloatArray:
    return np.full(shape, np.nan)


@dataclass
class CarriedPose:
    """The board and the tip measured at one pose.

    Attributes
    ----------
    status : {"ok", "failed"}
    reason : str
        Why the pose failed ("board: ..." or "tip: ..."), "" when ok.
    board_um, tip_um : (3,) float
        The board's virtual point and the tip point in {G}, µm.
    board_cov_um2, tip_cov_um2 : (3, 3) float
    R : (3, 3) float
        The board's orientation in {G}.
    tip_model_cov_um2 : (3, 3) float or None
        The part of the tip's error that is the same over frames and nearby poses (the
        vertex fit's own, :func:`~microcal.vision.tip_vertex.vertex_model_cov_um2`); the fit
        adds its mean over the poses to the offset's covariance without dividing it.
    """

    status: str
    reason: str = ""
    board_um: FloatArray = field(default_factory=lambda: _nan(3))
    board_cov_um2: FloatArray = field(default_factory=lambda: _nan(3, 3))
    R: FloatArray = field(default_factory=lambda: _nan(3, 3))
    tip_um: FloatArray = field(default_factory=lambda: _nan(3))
    tip_cov_um2: FloatArray = field(default_factory=lambda: _nan(3, 3))
    tip_model_cov_um2: FloatArray | None = None


def hide_board(
    frames: Sequence[NDArray[np.generic]], corners_px: FloatArray, board: Target
) -> list[NDArray[np.generic]]:
    """The frames with the board painted over by each frame's median (its background).

    ``corners_px`` (N, 2): the board's corners in the first frame (it stands still during a
    pose); the board's outline, :data:`BOARD_HIDE_MARGIN` pitches beyond its pattern, is
    mapped into the image by the homography from the board's plane to its corners.
    """
    model = board.points_um()[:, :2].astype(np.float32)
    H, _ = cv2.findHomography(model, np.asarray(corners_px, dtype=np.float32).reshape(-1, 2))
    if H is None:
        return list(frames)
    x0, x1, y0, y1 = board.extent_um()
    m = BOARD_HIDE_MARGIN * board.pitch_um
    outline = np.array([[x0 - m, y0 - m], [x1 + m, y0 - m], [x1 + m, y1 + m], [x0 - m, y1 + m]])
    poly = cv2.perspectiveTransform(outline.reshape(-1, 1, 2).astype(np.float64), H)
    out = []
    for image in frames:
        painted = np.array(image, copy=True)
        fill = float(np.median(painted))
        cv2.fillConvexPoly(painted, np.round(poly.reshape(-1, 2)).astype(np.int32), fill)
        out.append(painted)
    return out


def measure_carried(
    frames: Mapping[str, Sequence[NDArray[np.generic]]],
    cameras: Mapping[str, AnyCamera],
    board: Target,
    tip: TipTarget,
    *,
    near: FloatArray | None = None,
) -> CarriedPose:
    """The board (point and orientation) and the tip at one pose, from each camera's frames.

    ``near``: the board's orientation to stay nearest to where its symmetry allows two.
    """
    if not isinstance(board, Target) or not isinstance(tip, TipTarget):
        raise InputError(
            f"tool centre: expected a board's spec and a tip's spec, got "
            f"{getattr(board, 'spec', board)!r} and {getattr(tip, 'spec', tip)!r}"
        )
    mb = measure_one(frames, cameras, board)
    if mb.status != "ok":
        return CarriedPose("failed", f"board: {mb.reason}")
    try:
        pose = board_pose(mb.corners_px, cameras, board, near=near)
    except DetectionError as exc:
        return CarriedPose("failed", f"board: {exc}")
    hidden = {
        n: hide_board(frames[n], mb.corners_px[n], board) if n in mb.corners_px else frames[n]
        for n in frames
    }
    if takes_3d_vertex_path(tip):
        got = _tip_by_vertex(hidden, cameras, tip)
        if isinstance(got, str):
            return CarriedPose("failed", f"tip: {got}")
        return CarriedPose("ok", "", mb.p_um, mb.cov_um2, pose.R, *got)
    mt = measure_one(hidden, cameras, tip)
    if mt.status != "ok":
        return CarriedPose("failed", f"tip: {mt.reason}")
    return CarriedPose("ok", "", mb.p_um, mb.cov_um2, pose.R, mt.p_um, mt.cov_um2)


def _tip_by_vertex(
    frames: Mapping[str, Sequence[NDArray[np.generic]]],
    cameras: Mapping[str, AnyCamera],
    tip: TipTarget,
) -> tuple[FloatArray, FloatArray, FloatArray] | str:
    """The tip point in {G}, its covariance and the part of it that frames do not average
    (see :class:`CarriedPose`) from each camera's taper (its vertex and axis), or the reasons
    the cameras gave."""
    views, lost = {}, []
    for name, camera in cameras.items():
        got = camera_vertex(frames.get(name) or [], tip, camera)
        if isinstance(got, str):
            lost.append(f"{name}: {got}")
        else:
            views[name] = got
    if len(views) < 2:
        return "; ".join(lost) or "no camera saw the tool"
    point = tip_from_vertices(views, cameras, tip)
    if isinstance(point, str):
        return point
    return point[0], point[1], vertex_model_cov_um2(views, cameras)


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fit_carried(poses: Sequence[CarriedPose]) -> ToolCentre:
    """The tip's offset in the board's frame from the poses measured (see the module).

    Raises
    ------
    DetectionError
        Fewer than two poses with both board and tip; the message gives each failed pose's
        reason (one line).
    """
    ok = [p for p in poses if p.status == "ok"]
    if len(ok) < 2:
        failed: dict[str, list[int]] = {}
        for i, p in enumerate(poses):
            if p.reason:
                failed.setdefault(p.reason, []).append(i + 1)
        why = "; ".join(
            f"pose{'s' if len(at) > 1 else ''} {', '.join(map(str, at))}: {reason}"
            for reason, at in failed.items()
        )
        raise DetectionError(
            f"tool centre: expected two or more poses with both the board and the tip, got "
            f"{len(ok)}" + (f" ({why})" if why else "")
        )
    b = np.array([p.board_um for p in ok])
    t = np.array([p.tip_um for p in ok])
    cb = np.array([p.board_cov_um2 for p in ok])
    ct = np.array([p.tip_cov_um2 for p in ok])
    Rs = np.array([p.R for p in ok])
    R_mean, cov_turn = mean_rotation(Rs)
    turns = [np.arccos(np.clip((np.trace(R_mean.T @ R) - 1) / 2, -1.0, 1.0)) for R in Rs]
    got = [p.tip_model_cov_um2 for p in ok if p.tip_model_cov_um2 is not None]
    model = np.mean(got, axis=0) if got else np.zeros((3, 3))  # not averaged away: added whole
    if max(turns) > TURNING_RAD:
        turning = fit_tool_centre(b, t, board_cov_um2=cb, tip_cov_um2=ct, R=Rs)
        return dataclasses.replace(turning, cov_um2=turning.cov_um2 + R_mean.T @ model @ R_mean)
    in_g = fit_tool_centre(b, t, board_cov_um2=cb, tip_cov_um2=ct)
    cov_g = in_g.cov_um2 + model
    o = R_mean.T @ in_g.offset_um
    cov = R_mean.T @ cov_g @ R_mean
    if np.all(np.isfinite(cov_turn)):
        # o = R^T g; the mean's small turn w (R -> R (I + [w]x)) moves o by o x w
        S = _skew(o)
        cov = cov + S @ cov_turn @ S.T
    return ToolCentre(o, cov, in_g.rms_um, in_g.poses, R_mean, cov_g_um2=cov_g)


def tip_calibration(entry: ManipulatorCalibration, tool: ToolCentre) -> ManipulatorCalibration:
    """The board's calibration turned into its tool's tip's: the model's base offset moved by
    the tip's offset in {G} (a board that does not turn), so that prediction and compensator
    serve the tip.

    Raises
    ------
    InputError
        A tool-centre point without the board's orientation (a board that turns), or a model
        without a base offset.
    """
    if tool.board_R is None:
        raise InputError(
            "tool centre: the board turns between poses; its tip is board + R offset with the "
            "board's orientation at each pose, not a fixed shift of the model"
        )
    model = offset_updated(entry.model, tool.offset_g_um)
    extra = {k: v for k, v in entry.extra.items() if k != "tool_centre"}  # applied once only
    return dataclasses.replace(entry, model=model, extra=extra)
