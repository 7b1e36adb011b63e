"""A board's pose from its corners in two cameras (Kabsch on the triangulated corners)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microcal.errors import DetectionError
from microcal.thesis.cameras import thesis_cameras
from microcal.vision.board_pose import board_pose, mean_rotation
from microcal.vision.targets import parse_target

BOARD = parse_target("chessboard:4x3:400")


def _corners(R, t, rng, sigma_px=0.05):
    cams = dict(zip(("top", "side"), thesis_cameras(), strict=True))
    p = BOARD.points_um() @ R.T + t
    return cams, {n: c.project(p) + rng.normal(0, sigma_px, (len(p), 2)) for n, c in cams.items()}


@pytest.mark.parametrize("reverse", [False, True])
def test_the_pose_is_found_whichever_way_round_a_camera_lists_the_corners(reverse):
    rng = np.random.default_rng(1)
    R = Rotation.from_rotvec([0.01, -0.02, 0.05]).as_matrix()
    t = np.array([5000.0, 4800.0, 2700.0])
    cams, q = _corners(R, t, rng)
    if reverse:
        q["side"] = q["side"][::-1]
    pose = board_pose(q, cams, BOARD)
    turn = Rotation.from_matrix(pose.R.T @ R).magnitude()
    assert turn < 0.01  # rad: the symmetric board is taken the way nearest {G}'s axes
    np.testing.assert_allclose(pose.centre_um, R @ BOARD.centre_um + t, atol=2.0)
    assert pose.rms_um < 5.0


def test_one_camera_is_not_enough():
    rng = np.random.default_rng(2)
    cams, q = _corners(np.eye(3), np.array([5000.0, 4800.0, 2700.0]), rng)
    with pytest.raises(DetectionError, match="two cameras or more, got 1"):
        board_pose({"top": q["top"]}, cams, BOARD)


def test_the_mean_rotation_and_its_scatter():
    rng = np.random.default_rng(3)
    base = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    Rs = np.array([base @ Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix()
                   for _ in range(50)])  # fmt: skip
    mean, cov = mean_rotation(Rs)
    assert Rotation.from_matrix(mean.T @ base).magnitude() < 0.002
    np.testing.assert_allclose(np.sqrt(np.diagonal(cov)), 0.002 / np.sqrt(50), rtol=0.4)
