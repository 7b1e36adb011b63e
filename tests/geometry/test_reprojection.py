"""Reprojection error (Eq 3.19) and its summary."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import InputError, project_points, reprojection_error, summarize_errors


def test_error_is_euclidean_not_elementwise(thesis_pair):
    P = thesis_pair[0].P
    p = np.array([[1000.0, 1000.0, 100.0], [2000.0, 500.0, 0.0]])
    q = project_points(P, p) + np.array([[3.0, 4.0], [0.0, -2.0]])
    np.testing.assert_allclose(reprojection_error(P, p, q), [5.0, 2.0], rtol=1e-9)


def test_summary_figures():
    s = summarize_errors(np.array([3.0, 4.0, 0.0, 1.0]))
    assert s.n == 4
    assert s.rms == pytest.approx(np.sqrt(26 / 4))
    assert s.mean == pytest.approx(2.0)
    assert s.std == pytest.approx(np.std([3, 4, 0, 1], ddof=1))
    assert s.median == pytest.approx(2.0)
    assert s.max == 4.0
    assert s.p95 == pytest.approx(np.percentile([3, 4, 0, 1], 95))
    assert s.as_dict("_px")["rms_px"] == s.rms


def test_bad_input():
    with pytest.raises(InputError, match="expected at least one value"):
        summarize_errors(np.array([]))
    with pytest.raises(InputError, match="same number of points, got 2 and 1"):
        reprojection_error(
            np.hstack([np.eye(3), np.ones((3, 1))]), np.ones((2, 3)), np.ones((1, 2))
        )
