"""The tool-centre point: the tip's offset in the board's frame, with a covariance that covers it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microcal.errors import InputError
from microcal.vision.tool_centre import fit_tool_centre

TRUTH = np.array([35.0, -12.0, 120.0])


@pytest.mark.parametrize("rotating", [False, True])
def test_the_offset_is_recovered_within_half_a_micrometre_and_its_covariance_covers_it(rotating):
    rng = np.random.default_rng(2)
    misses, errors = [], []
    for _ in range(200):
        n = 12
        board = rng.uniform(0, 8000, (n, 3))
        R = Rotation.random(n, random_state=rng).as_matrix() if rotating else None
        tip = board + (TRUTH if R is None else R @ TRUTH)
        cov_b = np.broadcast_to(np.diag([0.2, 0.2, 0.5]) ** 2, (n, 3, 3))
        cov_t = np.broadcast_to(np.diag([0.3, 0.3, 0.6]) ** 2, (n, 3, 3))
        board_seen = board + rng.normal(0, 1, (n, 3)) * [0.2, 0.2, 0.5]
        tip_seen = tip + rng.normal(0, 1, (n, 3)) * [0.3, 0.3, 0.6]
        fit = fit_tool_centre(board_seen, tip_seen, board_cov_um2=cov_b, tip_cov_um2=cov_t, R=R)
        e = fit.offset_um - TRUTH
        errors.append(float(np.linalg.norm(e)))
        misses.append(float(e @ np.linalg.solve(fit.cov_um2, e)))
    assert np.mean(np.array(errors) < 0.5) > 0.95  # µm
    # chi-square with 3 degrees of freedom: 95 % below 7.81
    assert 0.9 < np.mean(np.array(misses) < 7.81) <= 1.0
    assert np.allclose(fit.apply(board, R), board + (TRUTH if R is None else R @ TRUTH),
                       atol=1.0)  # fmt: skip


def test_a_new_tool_needs_only_its_offset_again():
    rng = np.random.default_rng(5)
    board = rng.uniform(0, 8000, (6, 3))
    new = TRUTH + [20.0, 30.0, -25.0]  # a new pipette, its tip 20-50 µm elsewhere
    fit = fit_tool_centre(board, board + new + rng.normal(0, 0.2, (6, 3)))
    assert np.linalg.norm(fit.offset_um - new) < 0.5
    assert fit.to_json()["poses"] == 6


def test_too_few_poses_is_one_line():
    with pytest.raises(InputError, match="two or more poses"):
        fit_tool_centre(np.zeros((1, 3)), np.zeros((1, 3)))
