"""Reprojection error (thesis Eq 3.19) and its summary figures.

The error of one point is the Euclidean distance in pixels between where it was observed
and where the camera model puts it. (The thesis's appendix code took element-wise absolute
values, not the distance; this is the distance.)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows
from ..errors import InputError
from .projection_matrix import project_points

__all__ = ["ReprojectionSummary", "reprojection_error", "summarize_errors"]


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


@dataclass(frozen=True)
class ReprojectionSummary:
    """Summary figures of a set of per-point errors (same unit as the errors)."""

    n: int
    rms: float
    mean: float
    median: float
    p95: float
    max: float

    def as_dict(self) -> dict[str, float | int]:
        """The figures as a plain dict (for JSON)."""
        return asdict(self)


def summarize_errors(errors: ArrayLike) -> ReprojectionSummary:
    """RMS, mean, median, 95th percentile and maximum of per-point errors.

    Parameters
    ----------
    errors : (N,) float
        Non-negative errors, N >= 1.
    """
    e = as_array(errors, "errors", (None,))
    if e.size == 0:
        raise InputError("errors: expected at least one value, got none")
    return ReprojectionSummary(
        n=int(e.size),
        rms=float(np.sqrt(np.mean(e**2))),
        mean=float(e.mean()),
        median=float(np.median(e)),
        p95=float(np.percentile(e, 95)),
        max=float(e.max()),
    )
