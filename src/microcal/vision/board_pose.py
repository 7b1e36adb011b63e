"""A board's pose in {G} from its corners seen by two or more calibrated cameras.

Each corner is triangulated from the cameras' undistorted corners (the same corner in every
camera: a board seen turned by its symmetry in one camera is matched in the order that
triangulates best), and the board's model points are fitted to them as a rigid body (Kabsch):
``p_G = R p_board + t``. The board's frame has its origin at the inner-corner centroid (the
virtual point of Eq 4.13), so the pose's point is ``t + R centre``. A board with a symmetry
(a 4 x 3 chessboard turned by 180 degrees looks the same) gives two orientations that fit
alike; the one nearest ``near`` (the identity by default: {G}'s axes) is taken.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import DetectionError
from ..geometry import AnyCamera, triangulate_views
from .targets import Target

__all__ = ["BoardPose", "board_pose", "mean_rotation"]


@dataclass(frozen=True)
class BoardPose:
    """A board's pose in {G}.

    Attributes
    ----------
    R : (3, 3) float
        The board's axes in {G} (columns).
    centre_um : (3,) float
        The board's inner-corner centroid in {G}, µm.
    rms_um : float
        RMS distance of the triangulated corners from the fitted board, µm.
    """

    R: FloatArray
    centre_um: FloatArray
    rms_um: float


def _kabsch(model: FloatArray, seen: FloatArray) -> tuple[FloatArray, FloatArray]:
    """R, t with ``seen ~ model @ R.T + t``."""
    mc, sc = model.mean(axis=0), seen.mean(axis=0)
    U, _, Vt = np.linalg.svd((model - mc).T @ (seen - sc))
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(Vt.T @ U.T)))])
    R: FloatArray = Vt.T @ D @ U.T
    return R, sc - R @ mc


def board_pose(
    corners_px: Mapping[str, FloatArray],
    cameras: Mapping[str, AnyCamera],
    target: Target,
    *,
    near: FloatArray | None = None,
    sigma_px: float = 0.1,
) -> BoardPose:
    """The board's pose from its corners in each camera's image.

    Parameters
    ----------
    corners_px : mapping of camera name -> (N, 2) float
        The board's corners as detected (distorted pixels), in the detector's order.
    cameras : mapping of camera name -> camera model
        The calibrated cameras.
    target : Target
        The board.
    near : (3, 3) float, optional
        The orientation to stay nearest among those the board's symmetry allows.
    sigma_px : float
        The corners' noise, px (weights only).

    Raises
    ------
    DetectionError
        Fewer than two cameras with the whole board.
    """
    model = target.points_um()
    names = [n for n in cameras if n in corners_px and len(corners_px[n]) == len(model)]
    if len(names) < 2:
        raise DetectionError(
            f"board pose: expected the whole board in two cameras or more, got {len(names)}"
        )
    undist = [cameras[n].undistort_px(corners_px[n]) for n in names]
    # the first camera's order is the reference; each other's is taken as it is or reversed
    # (a symmetric board seen turned by 180 degrees), whichever triangulates closer
    for k in range(1, len(names)):
        best = None
        for cand in (undist[k], undist[k][::-1]):
            p, _, _ = triangulate_views([cameras[names[0]], cameras[names[k]]],
                                        [undist[0], cand], [sigma_px, sigma_px])  # fmt: skip
            q = cameras[names[k]].project(p, distort=False)
            err = float(np.nanmean(np.sum((q - cand) ** 2, axis=1)))
            if best is None or err < best[0]:
                best = (err, cand)
        assert best is not None
        undist[k] = best[1]
    p, _, _ = triangulate_views([cameras[n] for n in names], undist, [sigma_px] * len(names))
    ok = np.all(np.isfinite(p), axis=1)
    if ok.sum() < 3:
        raise DetectionError("board pose: fewer than three corners triangulated")
    ref = np.eye(3) if near is None else np.asarray(near, dtype=np.float64)
    fits = []
    for order in (model, model[::-1]):
        R, t = _kabsch(order[ok], p[ok])
        rms = float(np.sqrt(np.mean(np.sum((order[ok] @ R.T + t - p[ok]) ** 2, axis=1))))
        turn = float(np.arccos(np.clip((np.trace(ref.T @ R) - 1) / 2, -1.0, 1.0)))
        fits.append((rms, turn, R, t))
    least = min(f[0] for f in fits)
    rms, _, R, t = min((f for f in fits if f[0] <= 1.5 * least + 1e-9), key=lambda f: f[1])
    return BoardPose(R, t + R @ target.centre_um, rms)


def mean_rotation(Rs: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The mean of rotations (n, 3, 3) (the nearest rotation to their sum) and the covariance
    (3, 3) rad² of the mean's small turn about its own axes, from the rotations' scatter
    (NaN with fewer than two)."""
    R_all = np.asarray(Rs, dtype=np.float64).reshape(-1, 3, 3)
    U, _, Vt = np.linalg.svd(R_all.sum(axis=0))
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    mean: FloatArray = U @ D @ Vt
    if len(R_all) < 2:
        return mean, np.full((3, 3), np.nan)
    # each rotation's small turn from the mean, about the mean's axes: R_i = mean (I + [w]x)
    d = np.einsum("ji,njk->nik", mean, R_all)
    w = 0.5 * np.stack(
        [d[:, 2, 1] - d[:, 1, 2], d[:, 0, 2] - d[:, 2, 0], d[:, 1, 0] - d[:, 0, 1]], axis=1
    )
    cov: FloatArray = np.cov(w.T, ddof=1) / len(R_all)
    return mean, cov
