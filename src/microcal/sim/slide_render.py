"""Rendering a calibration slide with hollow marker dots (a slide that overfills the field).

A dot grid whose spec names ``markers=`` is drawn by :func:`~microcal.sim.render.render_placement`
as a grid of solid dots, and each marker's hole is then added: the hole is rendered as a
one-dot grid of its own (the same box-filtered edge over each subsample's footprint, so its
coverage is exact to the same order), and its coverage takes the dot's material back to the
ground's. Rendering is linear in coverage, so the result equals a render of the ring.

The hole's diameter is :data:`HOLE_FRACTION` of the dot's.

A chessboard whose spec names ``markers=`` is drawn the same way: the board, then a circle
in each marked square (:data:`CIRCLE_FRACTION` of a square across, centred in it) that takes
the square's colour to the other one (light in a dark square, dark in a light one).
"""

from __future__ import annotations

import numpy as np

from .._validation import FloatArray
from ..geometry.camera_kinds import AnyCamera
from ..vision.targets import Target
from .render import Placement, Reflectance, render_placement, roi_of

__all__ = ["CIRCLE_FRACTION", "HOLE_FRACTION", "hole_radius_um", "render_slide"]

#: A marker's hole diameter over its dot's (the DICe plate's is about a third; a half stays
#: resolved through the thesis cameras' 1.7 px blur).
HOLE_FRACTION = 0.5


#: A chessboard's marker circle's diameter over the square's (OpenCV's pattern generator
#: draws them half a square across).
CIRCLE_FRACTION = 0.5


def hole_radius_um(target: Target) -> float:
    """Radius of a marker dot's hole, µm."""
    return 0.5 * HOLE_FRACTION * target.feature_um


def render_slide(
    camera: AnyCamera,
    placement: Placement,
    roi: tuple[int, int, int, int],
    *,
    supersample: int = 4,
    offset_px: FloatArray | None = None,
    reflectance: Reflectance | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Reflectance and coverage of a placed dot grid with hollow marker dots, or of a
    chessboard with marker circles, over a pixel box.

    Parameters and returns as :func:`~microcal.sim.render.render_placement` (which it calls
    for a target without markers).
    """
    refl = reflectance or Reflectance()
    value, alpha = render_placement(camera, placement, roi, supersample=supersample,
                                    offset_px=offset_px, reflectance=refl)  # fmt: skip
    t = placement.target
    if t.kind not in ("dotgrid", "chessboard") or not t.markers:
        return value, alpha
    p = t.pitch_um
    chess = t.kind == "chessboard"
    size = CIRCLE_FRACTION * p if chess else 2.0 * hole_radius_um(t)
    hole = Target("dotgrid", 1, 1, p, size)
    coverage = Reflectance(glass=0.0, chrome=1.0)
    x0, y0, x1, y1 = roi
    for c, r in t.markers:
        # a dot's hole takes the dot back to the glass; a circle takes its square to the
        # other colour (square (c, r) lies between inner corners (c - 1, r - 1) and (c, r))
        at = ((c - 0.5) * p, (r - 0.5) * p) if chess else (c * p, r * p)
        dark = (c + r) % 2 == 0
        change = ((refl.white - refl.black) if dark else (refl.black - refl.white)) if chess \
            else refl.glass - refl.chrome  # fmt: skip
        centre = placement.R @ np.array([*at, 0.0]) + placement.t_um
        one = Placement(hole, placement.R, centre, margin_um=0.0)
        box = roi_of(camera, one, 2.0, offset_px)
        if box is None:
            continue
        bx0, by0 = max(box[0], x0), max(box[1], y0)
        bx1, by1 = min(box[2], x1), min(box[3], y1)
        if bx1 <= bx0 or by1 <= by0:
            continue
        cover, _ = render_placement(camera, one, (bx0, by0, bx1, by1), supersample=supersample,
                                    offset_px=offset_px, reflectance=coverage)  # fmt: skip
        region = value[by0 - y0 : by1 - y0, bx0 - x0 : bx1 - x0]
        region += np.nan_to_num(cover) * change
    return value, alpha
