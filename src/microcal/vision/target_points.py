"""Where the end-effector's target is in one frame, for the acquisition: a board's corners or
a tool's apex, and the region of the frame worth storing.

A board is found by :func:`~microcal.vision.detect.detect` and stored with a margin of
squares around its corners; a tool's tip by :func:`~microcal.vision.tip.detect_tip`, and
stored from a box around its apex out along its shank to the image's edge, so that a frame
put back together from the region (:func:`~microcal.vision.roi.frames_from_region`) still
shows a tool entering the field from its edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from .lazy_frame import RegionFrame, detect_in, pixels_of
from .targets import Target
from .tip import detect_tip
from .tip_measurement import takes_vertex_path
from .tip_target import TipTarget

__all__ = ["TIP_REGION_HALF_PX", "TargetInFrame", "find_target"]

#: Half the width of the region stored around a tool's apex and along its shank, px.
TIP_REGION_HALF_PX = 64

Box = tuple[int, int, int, int]


@dataclass(frozen=True)
class TargetInFrame:
    """A target found in a frame.

    Attributes
    ----------
    points_px : (n, 2) float
        A board's corners, or a tool's apex (n = 1).
    complete : bool
        Every corner of the board was found (always True for a tip).
    region_px : (x0, y0, x1, y1) int
        The box worth storing (end exclusive), inside the frame.
    """

    points_px: FloatArray
    complete: bool
    region_px: Box


def find_target(
    frame: RegionFrame | NDArray[np.generic],
    target: Target | TipTarget,
    roi: Box | None = None,
    *,
    margin_squares: float = 3.0,
    previous_px: FloatArray | None = None,
) -> TargetInFrame | None:
    """The target in ``frame`` (an array, or a region frame read only where a board is
    searched; searched in ``roi`` when given), or None when not found; ``previous_px``: a
    board's corners in the frame before, followed from there (``vision.detect.detect``)."""
    h, w = frame.shape[:2]
    if isinstance(target, TipTarget):
        image = pixels_of(frame)
        # the method the measurement uses for this tool (its vertex path, the model fit)
        method = "model fit" if takes_vertex_path(target) else None
        tip = (
            detect_tip(image, target, roi=roi, method=method)
            if roi
            else detect_tip(image, target, method=method)
        )
        if not tip.found:
            return None
        spread = math.tan(math.radians(tip.half_angle_deg))
        region = _along_shank(tip.apex_px, tip.axis, spread if math.isfinite(spread) else 0.5,
                              (w, h))  # fmt: skip
        return TargetInFrame(tip.apex_px.reshape(1, 2), True, region)
    det = detect_in(frame, target, roi if roi else None, previous_px)
    if not det.found:
        return None
    q = det.q_px
    complete = len(det.ids) == target.pattern_size[0] * target.pattern_size[1]
    square = float(np.median(np.linalg.norm(np.diff(q, axis=0), axis=1)))
    lo = np.floor(q.min(axis=0) - margin_squares * square).astype(int)
    hi = np.ceil(q.max(axis=0) + margin_squares * square).astype(int)
    box = (max(int(lo[0]), 0), max(int(lo[1]), 0), min(int(hi[0]), w), min(int(hi[1]), h))
    return TargetInFrame(q, complete, box)


def _along_shank(
    apex_px: FloatArray, axis: FloatArray, spread: float, size: tuple[int, int]
) -> Box:
    """A box around the apex and the shank from it to the image's edge (along ``axis``), the
    shank as wide as it grows there (``spread``: half its width per pixel along it)."""
    w, h = size
    a = np.asarray(axis, dtype=np.float64)
    reach = []
    for c, d, top in ((apex_px[0], a[0], w - 1), (apex_px[1], a[1], h - 1)):
        if d > 1e-9:
            reach.append((top - c) / d)
        elif d < -1e-9:
            reach.append(-c / d)
    length = min(reach) if reach else 0.0
    end = apex_px + a * length
    half = TIP_REGION_HALF_PX
    wide = half + abs(spread) * length  # the shank's half-width at the edge, and a margin
    lo = np.minimum(apex_px - half, end - wide)
    hi = np.maximum(apex_px + half, end + wide)
    x0, y0 = max(int(np.floor(lo[0])), 0), max(int(np.floor(lo[1])), 0)
    x1, y1 = min(int(np.ceil(hi[0])) + 1, w), min(int(np.ceil(hi[1])) + 1, h)
    return x0, y0, x1, y1
