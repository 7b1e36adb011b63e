"""The tool-centre point: where a tool's tip sits in the frame of a board the tool also carries.

A gripper carries a board (measured well: its virtual point, Eq 4.13) and does its work with
its tip. From a few poses where both are measured, the tip's fixed offset ``o`` in the
board's frame is the weighted least-squares solution of

    tip_i = board_i + R_i o        (R_i: the board's orientation in {G}; I when it only moves)

with the weights the inverse covariances of ``tip_i - board_i``. Its covariance is
``(sum R_i^T W_i R_i)^-1``, scaled up by the reduced chi-square when the residuals are larger
than the covariances say (what the model leaves out then counts too). Applied, a board's
calibration serves the tip; a changed tool (a new pipette) needs only this offset again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..errors import InputError

__all__ = ["ToolCentre", "fit_tool_centre"]


@dataclass(frozen=True)
class ToolCentre:
    """The tip's offset in the board's frame.

    Attributes
    ----------
    offset_um : (3,) float
    cov_um2 : (3, 3) float
    rms_um : float
        RMS of the poses' residuals.
    poses : int
    board_R : (3, 3) float or None
        The board's orientation in {G} (its axes as columns) when it does not turn (a
        manipulator that only translates): the tip is then ``board + board_R @ offset_um``
        at every pose. None: the identity (or a board that turns: give its orientation).
    cov_g_um2 : (3, 3) float or None
        The covariance of :attr:`offset_g_um`, the offset applied in {G} to a board that
        does not turn: without the uncertainty of the board's mean orientation, which
        ``cov_um2`` carries over the lever of the offset. None: ``cov_um2`` turned into {G}.
    """

    offset_um: FloatArray
    cov_um2: FloatArray
    rms_um: float
    poses: int
    board_R: FloatArray | None = None  # noqa: N815 (R, as in the thesis and Placement)
    cov_g_um2: FloatArray | None = None

    @property
    def offset_g_um(self) -> FloatArray:
        """The offset in {G}'s axes for a board that does not turn, (3,) µm."""
        out: FloatArray = self.offset_um if self.board_R is None else self.board_R @ self.offset_um
        return out

    @property
    def offset_g_cov_um2(self) -> FloatArray:
        """The covariance of :attr:`offset_g_um`, (3, 3) µm²."""
        if self.cov_g_um2 is not None:
            return self.cov_g_um2
        R = np.eye(3) if self.board_R is None else self.board_R
        out: FloatArray = R @ self.cov_um2 @ R.T
        return out

    def apply(self, board_um: ArrayLike, R: ArrayLike | None = None) -> FloatArray:
        """The tip in {G} for board positions (N, 3) (and orientations (N, 3, 3); without
        them, :attr:`board_R`)."""
        b = np.atleast_2d(np.asarray(board_um, dtype=np.float64))
        if R is None:
            return b + self.offset_g_um
        out: FloatArray = b + np.einsum("nij,j->ni", np.asarray(R, dtype=np.float64),
                                        self.offset_um)  # fmt: skip
        return out

    def to_json(self) -> dict[str, object]:
        """The calibration file's ``tool_centre`` entry (``docs/formats.md``)."""
        out: dict[str, object] = {"offset_um": self.offset_um.tolist(),
                                  "cov_um2": self.cov_um2.tolist(), "rms_um": self.rms_um,
                                  "poses": self.poses}  # fmt: skip
        if self.board_R is not None:
            out["board_R"] = self.board_R.tolist()
        if self.cov_g_um2 is not None:
            out["cov_g_um2"] = self.cov_g_um2.tolist()
        return out


def fit_tool_centre(
    board_um: ArrayLike,
    tip_um: ArrayLike,
    *,
    board_cov_um2: ArrayLike | None = None,
    tip_cov_um2: ArrayLike | None = None,
    R: ArrayLike | None = None,
) -> ToolCentre:
    """The tip's offset in the board's frame from poses where both were measured.

    Parameters
    ----------
    board_um, tip_um : (N, 3) float
        The board's point and the tip in {G}, µm.
    board_cov_um2, tip_cov_um2 : (N, 3, 3) float, optional
        Their covariances (identity when not given: equal weights).
    R : (N, 3, 3) float, optional
        The board's orientation in {G} at each pose (identity: it only translates).

    Raises
    ------
    InputError
        Fewer than two poses, or arrays that do not match.
    """
    b = np.asarray(board_um, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(tip_um, dtype=np.float64).reshape(-1, 3)
    n = len(b)
    if n < 2 or t.shape != b.shape:
        raise InputError(
            f"tool centre: expected two or more poses of board and tip alike, got {n} and {len(t)}"
        )
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    Rs = eye if R is None else np.asarray(R, dtype=np.float64).reshape(n, 3, 3)
    cov = np.zeros((n, 3, 3))
    given = False
    for c in (board_cov_um2, tip_cov_um2):
        if c is not None:
            cov += np.asarray(c, dtype=np.float64).reshape(n, 3, 3)
            given = True
    if not given:
        cov = eye.copy()
    ok = np.all(np.isfinite(b), axis=1) & np.all(np.isfinite(t), axis=1)
    if ok.sum() < 2:
        raise InputError(f"tool centre: expected two or more poses measured, got {ok.sum()}")
    W = np.linalg.inv(cov[ok])
    A = np.einsum("nji,njk,nkl->il", Rs[ok], W, Rs[ok])
    y = np.einsum("nji,njk,nk->i", Rs[ok], W, t[ok] - b[ok])
    offset = np.linalg.solve(A, y)
    resid = t[ok] - b[ok] - np.einsum("nij,j->ni", Rs[ok], offset)
    chi2 = float(np.einsum("ni,nij,nj->", resid, W, resid))
    dof = 3 * int(ok.sum()) - 3
    scale = max(chi2 / dof, 1.0) if dof > 0 and given else (chi2 / dof if dof > 0 else 1.0)
    out_cov = np.linalg.inv(A) * scale
    rms = float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))
    return ToolCentre(offset, out_cov, rms, int(ok.sum()))
