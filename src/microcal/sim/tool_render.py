"""A tool on the end-effector in a simulated camera's frames (what :class:`SimCamera` renders
for a tip target instead of a board).

The tool's outline (:mod:`microcal.sim.tools`: the taper's edges, its rounded end or opening,
a pipette's glass) is rendered over the pixel box it covers in the image, up to the image's
edge along its shank, in the camera's own subsamples, shifted by the frame's vibration. The
answer is a blend over what lies behind: the tool lets ``transmission`` of it through (a
value of 0 with an opacity of ``1 - transmission``), so that the camera's blur by depth, its
vignetting and noise apply to the tool as they do to a board.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..geometry.camera_kinds import AnyCamera
from .tools import ToolPlacement, _darkness, _silhouette, um_per_px

__all__ = ["SHANK_REACH_UM", "render_tool_region", "tool_roi"]

#: How far along its axis from the tip a tool is followed for its pixel box, µm.
SHANK_REACH_UM = 60000.0

Box = tuple[int, int, int, int]


def tool_roi(
    camera: AnyCamera, placement: ToolPlacement, pad_px: float, offset_px: FloatArray | None = None
) -> Box | None:
    """Pixel box (x0, y0, x1, y1), end exclusive, covering the tool within the image; None
    when no part of it is in view.

    The axis is followed from the tip to :data:`SHANK_REACH_UM` and every point of it within
    the image (widened by the tool's half-width there, in pixels at the tip, and ``pad_px``)
    counts.
    """
    tool = placement.tool
    s = np.concatenate([[0.0], np.geomspace(1.0, SHANK_REACH_UM, 240)])
    pts = placement.tip_um + s[:, None] * placement.axis
    q = camera.project(pts)
    if offset_px is not None:
        q = q + offset_px
    pitch = um_per_px(camera, placement.tip_um)
    half = (tool.end_radius_um + s * math.tan(tool.half_angle_rad)) / pitch + pad_px
    w, h = camera.image_size_px
    ok = np.all(np.isfinite(q), axis=1)
    ok &= (q[:, 0] + half >= 0) & (q[:, 0] - half <= w) & (q[:, 1] + half >= 0)
    ok &= q[:, 1] - half <= h
    if not np.any(ok):
        return None
    q, half = q[ok], half[ok]
    x0 = max(int(np.floor(np.min(q[:, 0] - half))), 0)
    x1 = min(int(np.ceil(np.max(q[:, 0] + half))) + 1, w)
    y0 = max(int(np.floor(np.min(q[:, 1] - half))), 0)
    y1 = min(int(np.ceil(np.max(q[:, 1] + half))) + 1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def render_tool_region(
    camera: AnyCamera,
    placement: ToolPlacement,
    roi: Box,
    *,
    supersample: int = 2,
    offset_px: FloatArray | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The tool over ``roi`` as (value, opacity), each (h, w) float32, not blurred.

    ``value`` is 0 and ``opacity`` the light the tool takes away (``1 - transmission``,
    averaged over ``supersample`` x ``supersample`` subsamples per pixel), so that blending
    them over the background multiplies it by the tool's transmission.
    """
    x0, y0, x1, y1 = roi
    h, w = y1 - y0, x1 - x0
    value = np.zeros((h, w), dtype=np.float32)
    sil = _silhouette(camera, placement)
    if sil is None:  # seen end-on: nothing of an outline to draw
        return value, np.zeros((h, w), dtype=np.float32)
    dark, _, _ = _darkness(camera, placement, sil, roi, supersample, offset_px)
    return value, dark.astype(np.float32)
