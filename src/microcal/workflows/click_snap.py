"""The second click of a target, placed on the epipolar line of the first.

A click in a second view is meant to lie on the first click's epipolar curve there. Where the
rig's target (the board's virtual point, a tool's tip) is found in that view within a few
pixels of the curve and near the click, the click is taken to be on it: the feature's pixel,
with the detection's uncertainty, replaces the click. Otherwise the click is projected onto
the curve (its nearest point), so that the two rays meet. Either way the page is told which.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array

__all__ = ["SNAP_LINE_PX", "SnappedClick", "nearest_on_curve", "snap_click"]

#: A feature this close to the epipolar curve (full-resolution px) can be the clicked point.
SNAP_LINE_PX = 4.0
#: ... when it is also this close to the click, in click standard deviations (and at least
#: :data:`SNAP_MIN_RADIUS_PX` full-resolution px).
SNAP_RADIUS_STD = 12.0
SNAP_MIN_RADIUS_PX = 12.0


@dataclass(frozen=True)
class SnappedClick:
    """Where a second click was taken to be.

    Attributes
    ----------
    q_px : (2,) float
        The pixel used (full resolution, distortion included).
    std_px : float
        Its standard deviation, px.
    how : str
        ``feature`` (the target found near the line) or ``line`` (the click projected onto it).
    moved_px : float
        From the click to the pixel used, px.
    line_px : float
        From the pixel used to the epipolar curve, px (0 for ``line``; NaN for ``click``, the
        curve not in this view: None in :meth:`as_dict`).
    """

    q_px: FloatArray
    std_px: float
    how: str
    moved_px: float
    line_px: float

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        line = self.line_px if np.isfinite(self.line_px) else None
        return {"q_px": self.q_px.tolist(), "std_px": self.std_px, "how": self.how,
                "moved_px": self.moved_px, "line_px": line}  # fmt: skip


def nearest_on_curve(curve_px: ArrayLike, q_px: ArrayLike) -> tuple[FloatArray, float]:
    """The point of a polyline (M, 2) nearest to ``q_px`` (2,), and its distance (px)."""
    c = as_array(curve_px, "curve_px", (None, 2))
    q = as_array(q_px, "q_px", (2,))
    if len(c) == 1:
        return c[0].copy(), float(np.linalg.norm(q - c[0]))
    a, b = c[:-1], c[1:]
    ab = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    t = np.clip(np.einsum("ij,ij->i", q - a, ab) / length2, 0.0, 1.0)
    foot = a + t[:, None] * ab
    dist = np.linalg.norm(foot - q, axis=1)
    k = int(np.argmin(dist))
    return foot[k], float(dist[k])


def snap_click(
    curve_px: ArrayLike,
    q_px: ArrayLike,
    std_px: float,
    feature_px: ArrayLike | None,
    feature_std_px: float,
) -> SnappedClick:
    """A second click ``q_px`` (2,) with its standard deviation, taken onto the epipolar
    curve (M, 2): onto ``feature_px`` (2,) (the target found in that view, None when none was)
    when it lies within :data:`SNAP_LINE_PX` of the curve and near the click, else onto the
    curve's nearest point. Without a curve (it does not cross the view) the click is kept."""
    q = as_array(q_px, "q_px", (2,))
    curve = np.asarray(curve_px, dtype=np.float64).reshape(-1, 2)
    if len(curve) == 0:
        return SnappedClick(q, float(std_px), "click", 0.0, float("nan"))
    if feature_px is not None:
        f = as_array(feature_px, "feature_px", (2,))
        _, off_line = nearest_on_curve(curve, f)
        radius = max(SNAP_RADIUS_STD * float(std_px), SNAP_MIN_RADIUS_PX)
        moved = float(np.linalg.norm(f - q))
        if off_line <= SNAP_LINE_PX and moved <= radius:
            return SnappedClick(f, float(feature_std_px), "feature", moved, off_line)
    foot, moved = nearest_on_curve(curve, q)
    return SnappedClick(foot, float(std_px), "line", moved, 0.0)
