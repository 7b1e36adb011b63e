"""Consistent corner numbering across cameras: resolve the turns of symmetric boards.

Two cameras that see the board in the same view must number its corners alike, or the
stereo solve joins corners from opposite ends of the board. A board that looks the same
turned (see :mod:`microcal.vision.board_symmetry`) gives no clue in one picture, but the
stereo geometry does: the pose of camera B relative to camera A is one rigid motion, the same
in every view. Each view's board pose from each camera's own calibration gives one estimate
of it for each way camera B's numbering could be turned; only the right turn agrees with the
other views, because a wrong one composes the true relative pose with a turn about that
view's board normal, which differs from view to view.

:func:`resolve_turns` takes the hypothesis (one view, one turn) that most views agree with
within :data:`AGREEMENT_DEG`, preferring on a tie the one whose relative translations agree
best (a wrong turn about each view's board centre moves it from view to view), then the one
that keeps most numberings as detected, and gives for every view the turn that agrees with
it, or the reason the view agrees under none. When the board's tilt hardly varies, a wrong
turn changes the relative rotation by little; the result then says so.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from .._validation import FloatArray
from .board_symmetry import ambiguous_turns, turn_transform
from .targets import Target

__all__ = [
    "AGREEMENT_DEG",
    "TurnResolution",
    "normal_spread_deg",
    "relative_rotation",
    "resolve_turns",
    "rotation_angle_deg",
]

#: Relative rotations within this angle (degrees) agree; turns of a board differ by >= 90.
AGREEMENT_DEG = 15.0


def _rotation(rvec: FloatArray) -> FloatArray:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return np.asarray(R, dtype=np.float64)


def rotation_angle_deg(Ra: FloatArray, Rb: FloatArray) -> float:
    """Angle of the rotation between two rotation matrices (of ``Ra Rb^T``), degrees."""
    c = (np.trace(Ra @ Rb.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def relative_rotation(
    rvec_a: FloatArray, rvec_b: FloatArray, target: Target, turn_deg: int = 0
) -> FloatArray:
    """Rotation from camera A's frame to camera B's implied by one view, (3, 3).

    Parameters
    ----------
    rvec_a, rvec_b : (3,) float
        The board's pose (Rodrigues) in each camera, as each camera numbered its corners.
    turn_deg : int
        Renumber camera B's corners by this turn of the board first.
    """
    Rs, _ = turn_transform(target, turn_deg)
    Rb = _rotation(rvec_b) @ Rs.T
    out: FloatArray = Rb @ _rotation(rvec_a).T
    return out


@dataclass
class TurnResolution:
    """The numbering of camera B's views that agrees with camera A's.

    Attributes
    ----------
    turns : dict view -> int
        The turn (degrees) to apply to camera B's numbering in each agreeing view (0 keeps
        it as detected).
    disagree : dict view -> str
        Views whose relative pose agrees under no turn, with the reason.
    rotation : (3, 3) float
        The agreed rotation from camera A's frame to camera B's.
    note : str
        A warning when the views' tilts vary too little for the rotation alone to decide.
    """

    turns: dict[int, int]
    disagree: dict[int, str]
    rotation: FloatArray
    note: str = ""

    @property
    def turned(self) -> list[int]:
        """Views whose numbering in camera B was turned."""
        return sorted(v for v, t in self.turns.items() if t != 0)


def _relative_translation(
    pose_a: tuple[FloatArray, FloatArray],
    pose_b: tuple[FloatArray, FloatArray],
    target: Target,
    turn_deg: int,
) -> FloatArray:
    """Translation from camera A's frame to camera B's implied by one view, (3,), µm."""
    Rs, ts = turn_transform(target, turn_deg)
    Ra, Rb = _rotation(pose_a[0]), _rotation(pose_b[0]) @ Rs.T
    tb = np.ravel(pose_b[1]) - Rb @ ts
    out: FloatArray = tb - Rb @ Ra.T @ np.ravel(pose_a[1])
    return out


def normal_spread_deg(poses_a: Mapping[int, FloatArray]) -> float:
    """Largest angle between two views' board normals in camera A, degrees."""
    normals = np.array([_rotation(r)[:, 2] for r in poses_a.values()])
    if len(normals) < 2:
        return 0.0
    cos = np.clip(normals @ normals.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


def resolve_turns(
    target: Target,
    poses_a: Mapping[int, FloatArray],
    poses_b: Mapping[int, FloatArray],
    translations: tuple[Mapping[int, FloatArray], Mapping[int, FloatArray]] | None = None,
) -> TurnResolution:
    """Find the turn of camera B's numbering in each view that agrees with all the others.

    Parameters
    ----------
    target : Target
    poses_a, poses_b : dict view -> (3,) float
        The board's rotation (Rodrigues vector) in each camera's frame, per view, from each
        camera's own calibration. Views missing in either are left out.
    translations : (dict view -> (3,) float, same), optional
        The board's translation in each camera, µm. A wrong turn moves the relative
        translation from view to view even when the board's tilts hardly vary (then a wrong
        turn changes the relative rotation by little): hypotheses that agree on the rotation
        equally are told apart by the spread of the relative translations.

    Returns
    -------
    TurnResolution
    """
    views = sorted(set(poses_a) & set(poses_b))
    turns = ambiguous_turns(target)
    rel = {
        (v, t): relative_rotation(poses_a[v], poses_b[v], target, t) for v in views for t in turns
    }
    best: tuple[tuple[int, float, int], FloatArray] | None = None
    for hyp in rel.values():
        assigned = {}
        for w in views:
            angles = {u: rotation_angle_deg(rel[(w, u)], hyp) for u in turns}
            u = min(angles, key=lambda k: angles[k])
            if angles[u] < AGREEMENT_DEG:
                assigned[w] = u
        spread = 0.0
        if translations is not None and len(assigned) > 1:
            ta, tb = translations
            t = np.array([
                _relative_translation((poses_a[w], ta[w]), (poses_b[w], tb[w]), target, u)
                for w, u in assigned.items()
            ])  # fmt: skip
            spread = float(np.median(np.linalg.norm(t - np.median(t, axis=0), axis=1)))
        kept = sum(u == 0 for u in assigned.values())
        score = (len(assigned), -spread, kept)
        if best is None or score > best[0]:
            best = (score, hyp)
    if best is None:
        return TurnResolution({}, {}, np.eye(3))
    hyp = best[1]
    out: dict[int, int] = {}
    disagree: dict[int, str] = {}
    for w in views:
        angles = {u: rotation_angle_deg(rel[(w, u)], hyp) for u in turns}
        u = min(angles, key=lambda k: angles[k])
        if angles[u] < AGREEMENT_DEG:
            out[w] = u
        else:
            disagree[w] = (
                f"the cameras' relative rotation in this view is {angles[u]:.1f} deg from the "
                f"other views' (more than {AGREEMENT_DEG:g}): a mis-detected or moved target"
            )
    note = ""
    spread_deg = normal_spread_deg({v: poses_a[v] for v in views})
    if len(turns) > 1 and spread_deg < 2 * AGREEMENT_DEG:
        note = (
            f"the board's tilt varies by only {spread_deg:.0f} deg over the views, so its turns "
            "were told apart "
            + ("by the relative translation" if translations is not None else "weakly")
            + ": tilt it more between views, or use an odd x even chessboard"
        )
    return TurnResolution(out, disagree, hyp, note)
