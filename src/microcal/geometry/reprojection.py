"""Reprojection error (thesis Eq 3.19) and its summary figures.

The error of one point is the Euclidean distance in pixels between where it was observed
and where the camera model puts it. (The thesis's appendix code took element-wise absolute
values, not the distance; this is the distance.)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_rows
from ..errors import InputError
from ..metrics.error_summary import ErrorSummary, summarize_errors
from .projection_matrix import project_points

__all__ = ["ErrorSummary", "reprojection_error", "summarize_errors"]


def reprojection_error(P: ArrayLike, p_um: ArrayLike, q_px: ArrayLike) -> FloatArray:
    """Euclidean reprojection error of each point (thesis Eq 3.19).

    Parameters
    ----------
    P : (3, 4) float
        Projection matrix (world in µm).
    p_um : (N, 3) or (3,) float
        World points, µm.
    q_px : (N, 2) or (2,) float
        Their observed (undistorted) pixels.

    Returns
    -------
    error_px : (N,) float
    """
    p = as_rows(p_um, "p_um", 3)
    q = as_rows(q_px, "q_px", 2)
    if p.shape[0] != q.shape[0]:
        raise InputError(
            f"p_um and q_px: expected the same number of points, got {p.shape[0]} and {q.shape[0]}"
        )
    out: FloatArray = np.linalg.norm(project_points(P, p) - q, axis=1)
    return out
